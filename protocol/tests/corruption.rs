//! The board-to-board link under corruption: bit errors, garbage bursts, truncated, oversized
//! and empty frames. What a user relies on: a corrupted frame is never delivered as a message,
//! intact frames after damage are, and every rejection is counted.

use protocol::*;
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_f32(rng: &mut ChaCha8Rng) -> f32 {
    // Mostly plausible values, sometimes arbitrary bit patterns (NaN, inf, subnormals).
    if rng.random_bool(0.9) {
        rng.random_range(-50.0f32..50.0)
    } else {
        f32::from_bits(rng.next_u32())
    }
}

fn random_vec3(rng: &mut ChaCha8Rng) -> [f32; 3] {
    [random_f32(rng), random_f32(rng), random_f32(rng)]
}

fn random_estimate(rng: &mut ChaCha8Rng) -> Estimate {
    Estimate {
        seq: rng.random(),
        capture_us: WireTime(rng.random()),
        forward_mps: random_f32(rng),
        sideways_mps: random_f32(rng),
        obstacle_m: rng.random_bool(0.5).then(|| random_f32(rng)),
        quality: rng.random(),
        flags: EstimateFlags(rng.random()),
        processing_us: rng.random(),
        depth_coverage: rng.random(),
        near_columns: rng.random(),
        fit: rng.random_bool(0.5).then(|| FrameFit {
            forward_mps: random_f32(rng),
            sideways_mps: random_f32(rng),
            quality: rng.random(),
        }),
        up_mps: random_f32(rng),
        up_flags: EstimateFlags(rng.random()),
        fit_r2: rng.random(),
        divergence: rng.random_bool(0.5).then(|| Divergence {
            rate_hz: random_f32(rng),
            sigma_hz: random_f32(rng),
        }),
    }
}

fn random_stereo_to_autopilot(rng: &mut ChaCha8Rng) -> StereoToAutopilot {
    match rng.random_range(0..10) {
        0 => StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, rng.random())),
        1 => StereoToAutopilot::Status(StereoStatus {
            uptime_ms: rng.random(),
            frame_rate_hz: random_f32(rng),
            frames_processed: rng.random(),
            frames_dropped: rng.random(),
            link_errors: LinkErrorCounts {
                crc: rng.random(),
                cobs: rng.random(),
                too_long: rng.random(),
                too_short: rng.random(),
                unknown_message: rng.random(),
                malformed: rng.random(),
                version_mismatch: rng.random(),
            },
            max_processing_us: rng.random(),
            capture: CaptureCounts {
                frames_complete: rng.random(),
                frames_torn: rng.random(),
                dcmi_overruns: rng.random(),
                dcmi_sync_errors: rng.random(),
                dma_errors: rng.random(),
                rearms: rng.random(),
                frames_overwritten: rng.random(),
            },
            camera_stopped: rng.random(),
        }),
        _ => StereoToAutopilot::Estimate(random_estimate(rng)),
    }
}

fn random_host_to_board(rng: &mut ChaCha8Rng) -> HostToBoard {
    match rng.random_range(0..5) {
        0 => HostToBoard::Heartbeat(Heartbeat::new(Node::Host, rng.random())),
        1 => {
            let len = rng.random_range(0..=FRAME_CHUNK_BYTES);
            let mut data = heapless::Vec::new();
            for _ in 0..len {
                let _ = data.push(rng.random::<u8>());
            }
            HostToBoard::FrameChunk(FrameChunk {
                frame_id: rng.random(),
                capture_us: WireTime(rng.random()),
                offset: rng.random(),
                data,
            })
        }
        2 => HostToBoard::Imu(ImuSample {
            timestamp_us: WireTime(rng.random()),
            gyro_radps: random_vec3(rng),
            accel_mps2: random_vec3(rng),
        }),
        3 => HostToBoard::ExternalPosition(ExternalPosition {
            timestamp_us: WireTime(rng.random()),
            position_m: random_vec3(rng),
        }),
        _ => HostToBoard::Command(PilotCommand::Kill),
    }
}

/// Sends `count` random messages as one byte stream, flips each bit with probability `ber`,
/// decodes the stream and checks that exactly the undamaged frames come out, unchanged.
/// Returns (frames sent, frames delivered, errors counted).
fn corrupted_stream<M: Message + Clone + PartialEq + core::fmt::Debug, const N: usize>(
    seed: u64,
    count: usize,
    ber: f64,
    mut random_message: impl FnMut(&mut ChaCha8Rng) -> M,
) -> (usize, usize, u32) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut stream = Vec::new();
    let mut frames = Vec::with_capacity(count); // (start, end incl. delimiter, encoded bytes)
    let mut wire = vec![0u8; 2048];
    for _ in 0..count {
        let msg = random_message(&mut rng);
        let n = encode(&msg, &mut wire).expect("encode");
        let start = stream.len();
        stream.extend_from_slice(&wire[..n]);
        frames.push((start, stream.len(), wire[..n].to_vec()));
    }
    // Flip bits: geometric gaps between flipped bits give an exact Bernoulli(ber) per bit.
    let mut flipped = vec![false; stream.len()];
    let total_bits = stream.len() * 8;
    let mut bit = 0usize;
    loop {
        let u: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
        bit += (u.ln() / (1.0 - ber).ln()).floor() as usize;
        if bit >= total_bits {
            break;
        }
        stream[bit / 8] ^= 1 << (bit % 8);
        flipped[bit / 8] = true;
        bit += 1;
    }
    // A frame must come out iff its own bytes (delimiter included) and the previous frame's
    // delimiter are undamaged.
    let mut expected = Vec::new();
    for (i, (start, end, bytes)) in frames.iter().enumerate() {
        let own_ok = !flipped[*start..*end].iter().any(|&f| f);
        let prev_delimiter_ok = i == 0 || !flipped[*start - 1];
        if own_ok && prev_delimiter_ok {
            expected.push(bytes.clone());
        }
    }
    let mut decoder = Decoder::<M, N>::new();
    let mut delivered = Vec::new();
    decoder.feed(&stream, |msg| {
        let n = encode(&msg, &mut wire).expect("re-encode");
        delivered.push(wire[..n].to_vec());
    });
    assert_eq!(
        delivered.len(),
        expected.len(),
        "delivered {} frames, expected exactly the {} undamaged ones",
        delivered.len(),
        expected.len()
    );
    for (k, (got, want)) in delivered.iter().zip(&expected).enumerate() {
        assert_eq!(
            got, want,
            "delivered frame {k} differs from the undamaged frame sent"
        );
    }
    (count, delivered.len(), decoder.errors().total())
}

#[test]
fn no_corrupted_message_is_accepted_at_ber_1e_3() {
    // 100,000 short board-to-board messages (CRC-16 frames) ...
    let (sent, delivered, errors) = corrupted_stream::<
        StereoToAutopilot,
        { StereoToAutopilot::MAX_FRAME_BYTES },
    >(0x5EED_0001, 100_000, 1e-3, random_stereo_to_autopilot);
    eprintln!("board link: sent {sent}, delivered {delivered}, rejected {errors}");
    assert!(
        delivered > sent * 6 / 10 && errors > 1000,
        "the test must exercise both paths"
    );
    // ... and 20,000 HIL messages, many of them long CRC-32 frames.
    let (sent, delivered, errors) = corrupted_stream::<HostToBoard, { HostToBoard::MAX_FRAME_BYTES }>(
        0x5EED_0002,
        20_000,
        1e-3,
        random_host_to_board,
    );
    eprintln!("HIL link: sent {sent}, delivered {delivered}, rejected {errors}");
    assert!(delivered > 1000 && errors > 1000);
}

#[test]
fn decoder_delivers_the_next_intact_frame_after_garbage() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut wire = [0u8; 64];
    for burst_len in [1usize, 3, 17, 95, 96, 97, 500, 5000] {
        let mut decoder = StereoToAutopilotDecoder::new();
        let mut garbage = vec![0u8; burst_len];
        rng.fill_bytes(&mut garbage);
        let msg = StereoToAutopilot::Estimate(random_estimate(&mut rng));
        let n = encode(&msg, &mut wire).unwrap();
        // Garbage, then a delimiter (what a receiver sees after a line glitch), then the frame.
        let mut out = Vec::new();
        decoder.feed(&garbage, |m| out.push(m));
        decoder.feed(&[DELIMITER], |m| out.push(m));
        out.clear();
        decoder.feed(&wire[..n], |m| out.push(m));
        assert_eq!(
            out.len(),
            1,
            "burst of {burst_len}: the next intact frame must come out"
        );
        assert_eq!(
            encode(&out[0], &mut [0u8; 64]).ok(),
            Some(n),
            "and unchanged"
        );
    }
}

#[test]
fn truncated_oversized_and_empty_frames_are_rejected_and_counted() {
    let mut wire = [0u8; 64];
    let msg = StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, 42));
    let n = encode(&msg, &mut wire).unwrap();

    // Truncated: every proper prefix of the frame, terminated by a delimiter, is rejected.
    let mut decoder = StereoToAutopilotDecoder::new();
    let mut accepted = 0;
    for cut in 0..n - 1 {
        decoder.feed(&wire[..cut], |_| accepted += 1);
        decoder.feed(&[DELIMITER], |_| accepted += 1);
    }
    assert_eq!(accepted, 0);
    let errors = decoder.errors();
    assert_eq!(errors.total() as usize, n - 1);
    assert!(
        errors.too_short >= 2,
        "empty and tiny prefixes count as too short: {errors:?}"
    );

    // Oversized: a run longer than the receive buffer is counted once, then the link recovers.
    let mut decoder = StereoToAutopilotDecoder::new();
    let long = [0x55u8; 3 * StereoToAutopilot::MAX_FRAME_BYTES];
    let mut out = Vec::new();
    decoder.feed(&long, |m| out.push(m));
    decoder.feed(&[DELIMITER], |m| out.push(m));
    assert_eq!(decoder.errors().too_long, 1);
    decoder.feed(&wire[..n], |m| out.push(m));
    assert_eq!(out, vec![msg.clone()]);

    // Empty: back-to-back delimiters are empty frames, rejected and counted as too short.
    let mut decoder = StereoToAutopilotDecoder::new();
    decoder.feed(&[DELIMITER, DELIMITER, DELIMITER], |_| {
        panic!("nothing to deliver")
    });
    assert_eq!(decoder.errors().too_short, 3);

    // Unknown message: a valid frame of another direction's larger tag space.
    let mut decoder = AutopilotToStereoDecoder::new();
    let foreign = encode(
        &StereoToAutopilot::Param(ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Saved,
        }),
        &mut wire,
    )
    .unwrap();
    decoder.feed(&wire[..foreign], |_| {
        panic!("tag 3 is unknown to AutopilotToStereo")
    });
    assert_eq!(decoder.errors().unknown_message, 1);
}

#[test]
fn a_decoder_joining_mid_stream_drops_the_partial_first_frame_uncounted() {
    let mut wire = [0u8; 64];
    let msg = StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, 7));
    let n = encode(&msg, &mut wire).unwrap();
    let frame = &wire[..n];

    // Joined in the middle of a frame: its tail is dropped silently, the next frame decodes,
    // and from then on every rejection counts.
    let mut decoder = StereoToAutopilotDecoder::new_mid_stream();
    let mut out = Vec::new();
    decoder.feed(&frame[n / 2..], |m| out.push(m));
    assert_eq!(decoder.errors().total(), 0);
    decoder.feed(frame, |m| out.push(m));
    assert_eq!(out, vec![msg.clone()]);
    decoder.feed(&frame[n / 2..], |m| out.push(m));
    assert_eq!(
        decoder.errors().total(),
        1,
        "only the first frame is excused"
    );

    // Joined exactly at a frame boundary: the first frame is delivered, not lost.
    let mut decoder = StereoToAutopilotDecoder::new_mid_stream();
    let mut out = Vec::new();
    decoder.feed(frame, |m| out.push(m));
    assert_eq!(out, vec![msg.clone()]);
    assert_eq!(decoder.frames_ok(), 1);

    // A decoder for a stream known to start at a boundary counts the same tail.
    let mut strict = StereoToAutopilotDecoder::new();
    strict.feed(&frame[n / 2..], |_| panic!("a tail is not a message"));
    assert_eq!(strict.errors().total(), 1);

    // After an overrun the rest of the interrupted frame is not counted either.
    let mut decoder = StereoToAutopilotDecoder::new();
    let mut out = Vec::new();
    decoder.feed(&frame[..n / 2], |m| out.push(m));
    decoder.reset_frame();
    decoder.feed(&frame[n / 2 + 1..], |m| out.push(m));
    decoder.feed(frame, |m| out.push(m));
    assert_eq!(decoder.errors().total(), 0);
    assert_eq!(out, vec![msg]);
}

/// The tag postcard gives `msg`: its variant's index, one byte below 128.
fn encoded_tag(msg: &impl serde::Serialize) -> u32 {
    let mut raw = [0u8; 600];
    u32::from(postcard::to_slice(msg, &mut raw).expect("encodes")[0])
}

/// A decoder refuses as unknown exactly the tags past its type's variants, so each type's
/// `VARIANT_COUNT` is one past its last variant's tag. The matches are exhaustive: a variant
/// added or removed does not compile here until its tag and the count are looked at.
#[test]
fn every_variant_count_matches_its_type() {
    let answer = ParamResponse {
        board: Node::Autopilot,
        reply: ParamReply::Saved,
    };
    let request = ParamRequest {
        board: Node::Autopilot,
        op: ParamOp::Save,
    };
    let s2a = |m: &StereoToAutopilot| match m {
        StereoToAutopilot::Heartbeat(_) => 0,
        StereoToAutopilot::Estimate(_) => 1,
        StereoToAutopilot::Status(_) => 2,
        StereoToAutopilot::Param(_) => 3,
    };
    let last = StereoToAutopilot::Param(answer.clone());
    assert_eq!(
        (encoded_tag(&last), StereoToAutopilot::VARIANT_COUNT),
        (s2a(&last), s2a(&last) + 1)
    );

    let a2s = |m: &AutopilotToStereo| match m {
        AutopilotToStereo::Heartbeat(_) => 0,
        AutopilotToStereo::GyroAttitude(_) => 1,
        AutopilotToStereo::Param(_) => 2,
    };
    let last = AutopilotToStereo::Param(request);
    assert_eq!(
        (encoded_tag(&last), AutopilotToStereo::VARIANT_COUNT),
        (a2s(&last), a2s(&last) + 1)
    );

    let h2b = |m: &HostToBoard| match m {
        HostToBoard::Heartbeat(_) => 0,
        HostToBoard::FrameChunk(_) => 1,
        HostToBoard::Imu(_) => 2,
        HostToBoard::ExternalPosition(_) => 3,
        HostToBoard::Command(_) => 4,
        HostToBoard::Param(_) => 5,
        HostToBoard::Signed(_) => 6,
        HostToBoard::SetKey(_) => 7,
    };
    let last = HostToBoard::SetKey(signing::LinkKey([1; 32]));
    assert_eq!(
        (encoded_tag(&last), HostToBoard::VARIANT_COUNT),
        (h2b(&last), h2b(&last) + 1)
    );

    let b2h = |m: &BoardToHost| match m {
        BoardToHost::Heartbeat(_) => 0,
        BoardToHost::Motors(_) => 1,
        BoardToHost::Telemetry(_) => 2,
        BoardToHost::Estimate(_) => 3,
        BoardToHost::Param(_) => 4,
    };
    let last = BoardToHost::Param(answer);
    assert_eq!(
        (encoded_tag(&last), BoardToHost::VARIANT_COUNT),
        (b2h(&last), b2h(&last) + 1)
    );
}
