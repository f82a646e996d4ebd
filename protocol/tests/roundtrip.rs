//! Property tests: every message of every direction survives encode -> stream decode, worst-case
//! sizes stay inside the declared budgets, and the decoder never panics on arbitrary bytes.

use proptest::prelude::*;
use protocol::signing::{
    LinkKey, SignedMessage, KEY_BYTES, MAC_BYTES, SIGNED_PAYLOAD_MAX, TIMESTAMP_MAX,
};
use protocol::*;

/// Every [`FailsafeReason`], for the telemetry strategies.
const REASONS: [FailsafeReason; 10] = [
    FailsafeReason::Command,
    FailsafeReason::EstimateLost,
    FailsafeReason::HeightLost,
    FailsafeReason::ImuLost,
    FailsafeReason::TelemetryLost,
    FailsafeReason::NoWayFound,
    FailsafeReason::LandTimeout,
    FailsafeReason::BaroFrozen,
    FailsafeReason::BatteryLow,
    FailsafeReason::BatteryCritical,
];

fn finite() -> impl Strategy<Value = f32> {
    -1.0e6f32..1.0e6f32
}
fn vec3() -> impl Strategy<Value = [f32; 3]> {
    [finite(), finite(), finite()]
}

fn node() -> impl Strategy<Value = Node> {
    prop_oneof![
        Just(Node::StereoBoard),
        Just(Node::Autopilot),
        Just(Node::Host)
    ]
}
fn param_value() -> impl Strategy<Value = ParamValue> {
    prop_oneof![
        finite().prop_map(ParamValue::F32),
        any::<u32>().prop_map(ParamValue::U32),
        any::<bool>().prop_map(ParamValue::Bool),
        any::<i32>().prop_map(ParamValue::I32),
    ]
}
fn param_name() -> impl Strategy<Value = ParamName> {
    "[a-z_]{1,24}".prop_map(|s| ParamName::try_from(s.as_str()).unwrap())
}
fn param_request() -> impl Strategy<Value = ParamRequest> {
    (
        node(),
        prop_oneof![
            any::<u16>().prop_map(ParamOp::List),
            param_name().prop_map(ParamOp::Get),
            (param_name(), param_value()).prop_map(|(n, v)| ParamOp::Set(n, v)),
            Just(ParamOp::Save),
        ],
    )
        .prop_map(|(board, op)| ParamRequest { board, op })
}
fn param_response() -> impl Strategy<Value = ParamResponse> {
    let entry = (
        any::<(u16, u16, bool)>(),
        param_name(),
        "[a-z/0-9]{0,8}",
        [param_value(), param_value(), param_value(), param_value()],
    )
        .prop_map(|((index, count, writable), name, unit, v)| {
            ParamReply::Entry(ParamEntry {
                index,
                count,
                name,
                unit: ParamUnit::try_from(unit.as_str()).unwrap(),
                value: v[0],
                default: v[1],
                min: v[2],
                max: v[3],
                writable,
            })
        });
    (
        node(),
        prop_oneof![
            entry,
            Just(ParamReply::Saved),
            Just(ParamReply::Error(ParamError::OutOfBounds)),
        ],
    )
        .prop_map(|(board, reply)| ParamResponse { board, reply })
}
fn heartbeat() -> impl Strategy<Value = Heartbeat> {
    (node(), any::<u8>(), any::<u32>()).prop_map(|(node, protocol_version, uptime_ms)| Heartbeat {
        node,
        protocol_version,
        uptime_ms,
    })
}
fn estimate() -> impl Strategy<Value = Estimate> {
    (
        any::<u16>(),
        any::<u32>(),
        finite(),
        finite(),
        proptest::option::of(finite()),
        any::<u8>(),
        any::<u8>(),
        any::<u16>(),
        any::<[u8; 4]>(),
        proptest::option::of((finite(), finite(), any::<u8>())),
        finite(),
        proptest::option::of((finite(), finite())),
    )
        .prop_map(
            |(
                seq,
                capture_us,
                f,
                s,
                obstacle_m,
                quality,
                flags,
                processing_us,
                [dc, nc, up_flags, fit_r2],
                fit,
                up_mps,
                divergence,
            )| {
                Estimate {
                    seq,
                    capture_us: WireTime(capture_us),
                    forward_mps: f,
                    sideways_mps: s,
                    obstacle_m,
                    quality,
                    flags: EstimateFlags(flags),
                    processing_us,
                    depth_coverage: dc,
                    near_columns: nc,
                    fit: fit.map(|(forward_mps, sideways_mps, quality)| FrameFit {
                        forward_mps,
                        sideways_mps,
                        quality,
                    }),
                    up_mps,
                    up_flags: EstimateFlags(up_flags),
                    fit_r2,
                    divergence: divergence
                        .map(|(rate_hz, sigma_hz)| Divergence { rate_hz, sigma_hz }),
                }
            },
        )
}
fn link_errors() -> impl Strategy<Value = LinkErrorCounts> {
    any::<[u32; 7]>().prop_map(|c| LinkErrorCounts {
        crc: c[0],
        cobs: c[1],
        too_long: c[2],
        too_short: c[3],
        unknown_message: c[4],
        malformed: c[5],
        version_mismatch: c[6],
    })
}
fn capture_counts() -> impl Strategy<Value = CaptureCounts> {
    any::<[u32; 7]>().prop_map(|c| CaptureCounts {
        frames_complete: c[0],
        frames_torn: c[1],
        dcmi_overruns: c[2],
        dcmi_sync_errors: c[3],
        dma_errors: c[4],
        rearms: c[5],
        frames_overwritten: c[6],
    })
}
fn stereo_to_autopilot() -> impl Strategy<Value = StereoToAutopilot> {
    prop_oneof![
        heartbeat().prop_map(StereoToAutopilot::Heartbeat),
        estimate().prop_map(StereoToAutopilot::Estimate),
        (
            any::<u32>(),
            finite(),
            any::<u32>(),
            any::<u32>(),
            link_errors(),
            any::<u32>(),
            capture_counts(),
            any::<bool>()
        )
            .prop_map(
                |(
                    uptime_ms,
                    frame_rate_hz,
                    frames_processed,
                    frames_dropped,
                    link_errors,
                    max_processing_us,
                    capture,
                    camera_stopped,
                )| {
                    StereoToAutopilot::Status(StereoStatus {
                        uptime_ms,
                        frame_rate_hz,
                        frames_processed,
                        frames_dropped,
                        link_errors,
                        max_processing_us,
                        capture,
                        camera_stopped,
                    })
                }
            ),
        param_response().prop_map(StereoToAutopilot::Param),
    ]
}
fn autopilot_to_stereo() -> impl Strategy<Value = AutopilotToStereo> {
    prop_oneof![
        heartbeat().prop_map(AutopilotToStereo::Heartbeat),
        (any::<u32>(), vec3(), vec3()).prop_map(|(timestamp_us, rates_radps, attitude_rad)| {
            AutopilotToStereo::GyroAttitude(GyroAttitude {
                timestamp_us: WireTime(timestamp_us),
                rates_radps,
                attitude_rad,
            })
        }),
        param_request().prop_map(AutopilotToStereo::Param),
    ]
}
fn host_to_board() -> impl Strategy<Value = HostToBoard> {
    prop_oneof![
        heartbeat().prop_map(HostToBoard::Heartbeat),
        (
            any::<u16>(),
            any::<u32>(),
            any::<u16>(),
            proptest::collection::vec(any::<u8>(), 0..=FRAME_CHUNK_BYTES)
        )
            .prop_map(|(frame_id, capture_us, offset, data)| {
                HostToBoard::FrameChunk(FrameChunk {
                    frame_id,
                    capture_us: WireTime(capture_us),
                    offset,
                    data: heapless::Vec::from_slice(&data).unwrap(),
                })
            }),
        (any::<u32>(), vec3(), vec3()).prop_map(|(timestamp_us, gyro_radps, accel_mps2)| {
            HostToBoard::Imu(ImuSample {
                timestamp_us: WireTime(timestamp_us),
                gyro_radps,
                accel_mps2,
            })
        }),
        (any::<u32>(), vec3()).prop_map(|(timestamp_us, position_m)| {
            HostToBoard::ExternalPosition(ExternalPosition {
                timestamp_us: WireTime(timestamp_us),
                position_m,
            })
        }),
        prop_oneof![
            Just(PilotCommand::Arm),
            Just(PilotCommand::Land),
            Just(PilotCommand::Kill)
        ]
        .prop_map(HostToBoard::Command),
        param_request().prop_map(HostToBoard::Param),
        (
            any::<u8>(),
            0..=TIMESTAMP_MAX,
            proptest::collection::vec(any::<u8>(), 0..=SIGNED_PAYLOAD_MAX)
        )
            .prop_map(|(link_id, timestamp, payload)| {
                HostToBoard::Signed(SignedMessage {
                    link_id,
                    timestamp,
                    mac: [link_id; MAC_BYTES],
                    payload: heapless::Vec::from_slice(&payload).unwrap(),
                })
            }),
        any::<[u8; KEY_BYTES]>().prop_map(|k| HostToBoard::SetKey(LinkKey(k))),
    ]
}
fn board_to_host() -> impl Strategy<Value = BoardToHost> {
    prop_oneof![
        heartbeat().prop_map(BoardToHost::Heartbeat),
        (any::<u32>(), [finite(), finite(), finite(), finite()]).prop_map(
            |(timestamp_us, throttle)| BoardToHost::Motors(MotorCommand {
                timestamp_us: WireTime(timestamp_us),
                throttle
            })
        ),
        (
            any::<u32>(),
            proptest::option::of(proptest::sample::select(FsmState::ALL.to_vec())),
            proptest::sample::select(FlightMode::ALL.to_vec()),
            vec3(),
            [finite(), finite()],
            [finite(), finite()],
            proptest::option::of(finite()),
            finite(),
            proptest::option::of((finite(), finite())),
            link_errors(),
            proptest::option::of((
                finite(),
                finite(),
                proptest::sample::select(BatteryState::ALL.to_vec())
            ))
        )
            .prop_map(
                |(
                    timestamp_us,
                    fsm_state,
                    flight_mode,
                    attitude_rad,
                    v,
                    sp,
                    obstacle_m,
                    height_m,
                    baro,
                    link_errors,
                    battery,
                )| {
                    BoardToHost::Telemetry(Telemetry {
                        timestamp_us: WireTime(timestamp_us),
                        fsm_state,
                        flight_mode,
                        attitude_rad,
                        velocity_mps: v,
                        velocity_setpoint_mps: sp,
                        obstacle_m,
                        height_m,
                        baro: baro.map(|(pressure_pa, temperature_c)| BaroTelemetry {
                            pressure_pa,
                            temperature_c,
                        }),
                        link_errors,
                        // Every reason and none, spread over the timestamps.
                        failsafe_reason: REASONS.get(timestamp_us as usize % 11).copied(),
                        battery: battery.map(|(voltage_v, resting_v, state)| BatteryTelemetry {
                            voltage_v,
                            resting_v,
                            state,
                        }),
                        link_auth: LinkAuthTelemetry {
                            keyed: timestamp_us % 2 == 0,
                            accepted: timestamp_us,
                            unsigned: timestamp_us / 3,
                            bad_signature: timestamp_us / 5,
                            replayed: timestamp_us / 7,
                        },
                    })
                }
            ),
        estimate().prop_map(BoardToHost::Estimate),
        param_response().prop_map(BoardToHost::Param),
    ]
}

/// Encodes `msg`, streams the bytes through a fresh decoder and returns what came out.
fn through_the_wire<M: Message + Clone, const N: usize>(
    msg: &M,
) -> (usize, Vec<M>, LinkErrorCounts) {
    let mut wire = [0u8; 1024];
    let n = encode(msg, &mut wire).expect("encode");
    assert!(
        n <= M::MAX_FRAME_BYTES,
        "frame of {n} bytes exceeds MAX_FRAME_BYTES {}",
        M::MAX_FRAME_BYTES
    );
    let mut dec = Decoder::<M, N>::new();
    let mut out = Vec::new();
    dec.feed(&wire[..n], |m| out.push(m));
    (n, out, dec.errors())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn stereo_to_autopilot_round_trips(msg in stereo_to_autopilot()) {
        let (_, out, errors) = through_the_wire::<_, { StereoToAutopilot::MAX_FRAME_BYTES }>(&msg);
        prop_assert_eq!(out, vec![msg]);
        prop_assert_eq!(errors.total(), 0);
    }

    #[test]
    fn autopilot_to_stereo_round_trips(msg in autopilot_to_stereo()) {
        let (_, out, errors) = through_the_wire::<_, { AutopilotToStereo::MAX_FRAME_BYTES }>(&msg);
        prop_assert_eq!(out, vec![msg]);
        prop_assert_eq!(errors.total(), 0);
    }

    #[test]
    fn host_to_board_round_trips(msg in host_to_board()) {
        let (_, out, errors) = through_the_wire::<_, { HostToBoard::MAX_FRAME_BYTES }>(&msg);
        prop_assert_eq!(out, vec![msg]);
        prop_assert_eq!(errors.total(), 0);
    }

    #[test]
    fn board_to_host_round_trips(msg in board_to_host()) {
        let (_, out, errors) = through_the_wire::<_, { BoardToHost::MAX_FRAME_BYTES }>(&msg);
        prop_assert_eq!(out, vec![msg]);
        prop_assert_eq!(errors.total(), 0);
    }

    /// Any f32 bit pattern (NaN payloads included) is carried bit-exactly.
    #[test]
    fn float_bits_are_preserved(bits in any::<[u32; 2]>()) {
        let est = Estimate {
            seq: 1, capture_us: WireTime(2),
            forward_mps: f32::from_bits(bits[0]), sideways_mps: f32::from_bits(bits[1]),
            obstacle_m: None, quality: 0, flags: EstimateFlags::NONE, processing_us: 0,
            depth_coverage: 0, near_columns: 0, fit: None,
            up_mps: 0.0,
            up_flags: EstimateFlags::NO_FLOW_MATCH,
            fit_r2: 0,
            divergence: None,
        };
        let (_, out, _) = through_the_wire::<_, { StereoToAutopilot::MAX_FRAME_BYTES }>(&StereoToAutopilot::Estimate(est));
        match out.as_slice() {
            [StereoToAutopilot::Estimate(e)] => {
                prop_assert_eq!(e.forward_mps.to_bits(), bits[0]);
                prop_assert_eq!(e.sideways_mps.to_bits(), bits[1]);
            }
            other => prop_assert!(false, "unexpected {:?}", other),
        }
    }

    /// Arbitrary bytes never panic any decoder, and every completed frame is either a message
    /// or a counted error.
    #[test]
    fn decoders_never_panic_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let mut a = StereoToAutopilotDecoder::new();
        let mut b = AutopilotToStereoDecoder::new();
        let mut c = HostToBoardDecoder::new();
        let mut d = BoardToHostDecoder::new();
        let (mut na, mut nb, mut nc, mut nd) = (0u32, 0u32, 0u32, 0u32);
        a.feed(&bytes, |_| na += 1);
        b.feed(&bytes, |_| nb += 1);
        c.feed(&bytes, |_| nc += 1);
        d.feed(&bytes, |_| nd += 1);
        let frames = bytes.iter().filter(|&&x| x == 0).count() as u32;
        prop_assert_eq!(na + a.errors().total(), frames);
        prop_assert_eq!(nb + b.errors().total(), frames);
        prop_assert_eq!(nc + c.errors().total(), frames);
        prop_assert_eq!(nd + d.errors().total(), frames);
    }

    /// Encoding into any buffer size either fits or is refused, never panics or overruns.
    #[test]
    fn encode_never_panics_on_short_buffers(msg in host_to_board(), size in 0usize..600) {
        let mut buf = vec![0u8; size];
        if let Ok(n) = encode(&msg, &mut buf) {
            prop_assert!(n <= size);
            let mut dec = HostToBoardDecoder::new();
            let mut out = Vec::new();
            dec.feed(&buf[..n], |m| out.push(m));
            prop_assert_eq!(out, vec![msg]);
        }
    }
}

/// The wire-size budget: an `Estimate` fits in 60 bytes on the wire, whatever its values
/// (1,500 B/s at 25 fps, 13 % of the 115,200 Bd link).
#[test]
fn estimate_worst_case_fits_in_60_bytes() {
    let worst = Estimate {
        seq: u16::MAX,
        capture_us: WireTime(u32::MAX),
        forward_mps: f32::MAX,
        sideways_mps: f32::MIN,
        obstacle_m: Some(f32::MAX),
        quality: u8::MAX,
        flags: EstimateFlags(u8::MAX),
        processing_us: u16::MAX,
        depth_coverage: u8::MAX,
        near_columns: u8::MAX,
        fit: Some(FrameFit {
            forward_mps: f32::MAX,
            sideways_mps: f32::MIN,
            quality: u8::MAX,
        }),
        up_mps: f32::MIN,
        up_flags: EstimateFlags(u8::MAX),
        fit_r2: u8::MAX,
        divergence: Some(Divergence {
            rate_hz: f32::MIN,
            sigma_hz: f32::MAX,
        }),
    };
    let mut wire = [0u8; 64];
    let n = encode(&StereoToAutopilot::Estimate(worst), &mut wire).unwrap();
    assert!(n <= 60, "worst-case Estimate takes {n} bytes on the wire");
    let n = encode(&BoardToHost::Estimate(worst), &mut wire).unwrap();
    assert!(
        n <= 60,
        "worst-case mirrored Estimate takes {n} bytes on the wire"
    );
}

/// Link error counters with every field at its largest value (worst case on the wire).
fn all_counters_at_max() -> LinkErrorCounts {
    LinkErrorCounts {
        crc: u32::MAX,
        cobs: u32::MAX,
        too_long: u32::MAX,
        too_short: u32::MAX,
        unknown_message: u32::MAX,
        malformed: u32::MAX,
        version_mismatch: u32::MAX,
    }
}

/// The declared maximum frame sizes hold for the largest message of each direction.
#[test]
fn declared_maximum_frame_sizes_hold() {
    let mut wire = [0u8; 2048];
    let chunk = HostToBoard::FrameChunk(FrameChunk {
        frame_id: u16::MAX,
        capture_us: WireTime(u32::MAX),
        offset: u16::MAX,
        data: heapless::Vec::from_slice(&[0xAB; FRAME_CHUNK_BYTES]).unwrap(),
    });
    assert!(encode(&chunk, &mut wire).unwrap() <= HostToBoard::MAX_FRAME_BYTES);
    let status = StereoToAutopilot::Status(StereoStatus {
        uptime_ms: u32::MAX,
        frame_rate_hz: f32::MAX,
        frames_processed: u32::MAX,
        frames_dropped: u32::MAX,
        link_errors: all_counters_at_max(),
        max_processing_us: u32::MAX,
        capture: CaptureCounts {
            frames_complete: u32::MAX,
            frames_torn: u32::MAX,
            dcmi_overruns: u32::MAX,
            dcmi_sync_errors: u32::MAX,
            dma_errors: u32::MAX,
            rearms: u32::MAX,
            frames_overwritten: u32::MAX,
        },
        camera_stopped: true,
    });
    assert!(encode(&status, &mut wire).unwrap() <= StereoToAutopilot::MAX_FRAME_BYTES);
    let gyro = AutopilotToStereo::GyroAttitude(GyroAttitude {
        timestamp_us: WireTime(u32::MAX),
        rates_radps: [f32::MAX; 3],
        attitude_rad: [f32::MAX; 3],
    });
    assert!(encode(&gyro, &mut wire).unwrap() <= AutopilotToStereo::MAX_FRAME_BYTES);
    let telemetry = BoardToHost::Telemetry(Telemetry {
        timestamp_us: WireTime(u32::MAX),
        fsm_state: Some(FsmState::Turn),
        flight_mode: FlightMode::ImuFault,
        attitude_rad: [f32::MAX; 3],
        velocity_mps: [f32::MAX; 2],
        velocity_setpoint_mps: [f32::MAX; 2],
        obstacle_m: Some(f32::MAX),
        height_m: f32::MAX,
        baro: Some(BaroTelemetry {
            pressure_pa: f32::MAX,
            temperature_c: f32::MAX,
        }),
        link_errors: all_counters_at_max(),
        failsafe_reason: Some(FailsafeReason::BatteryCritical),
        battery: Some(BatteryTelemetry {
            voltage_v: f32::MAX,
            resting_v: f32::MAX,
            state: BatteryState::Critical,
        }),
        link_auth: LinkAuthTelemetry {
            keyed: true,
            accepted: u32::MAX,
            unsigned: u32::MAX,
            bad_signature: u32::MAX,
            replayed: u32::MAX,
        },
    });
    assert!(encode(&telemetry, &mut wire).unwrap() <= BoardToHost::MAX_FRAME_BYTES);
    // The largest signed envelope: a full payload.
    let signed = HostToBoard::Signed(SignedMessage {
        link_id: u8::MAX,
        timestamp: TIMESTAMP_MAX,
        mac: [0xFF; MAC_BYTES],
        payload: heapless::Vec::from_slice(&[0xFF; SIGNED_PAYLOAD_MAX]).unwrap(),
    });
    assert!(encode(&signed, &mut wire).unwrap() <= HostToBoard::MAX_FRAME_BYTES);
}

#[test]
fn config_validation_accepts_the_paper_setting_and_rejects_out_of_range() {
    let ok = EdgeFsConfig {
        half_window: 8,
        search_range: 15,
        max_horizon: 5,
        stereo_shift: 5,
    };
    assert_eq!(ok.validate(), Ok(()));
    assert_eq!(
        EdgeFsConfig {
            half_window: 0,
            ..ok
        }
        .validate(),
        Err(ConfigError::HalfWindow)
    );
    assert_eq!(
        EdgeFsConfig {
            search_range: 21,
            ..ok
        }
        .validate(),
        Err(ConfigError::SearchRange)
    );
    assert_eq!(
        EdgeFsConfig {
            max_horizon: 10,
            ..ok
        }
        .validate(),
        Err(ConfigError::MaxHorizon)
    );
    assert_eq!(
        EdgeFsConfig {
            stereo_shift: -21,
            ..ok
        }
        .validate(),
        Err(ConfigError::StereoShift)
    );
    let widest = EdgeFsConfig {
        half_window: 12,
        search_range: 20,
        max_horizon: 9,
        stereo_shift: -20,
    };
    assert_eq!(widest.validate(), Ok(()));
}
