//! Benchmark firmware for `cargo xtask insns` (thumbv7em-none-eabihf, QEMU `netduinoplus2`).
//!
//! Runs the camera board's and the autopilot's per-frame / per-sample work on real embedded
//! frames, each call bracketed by the marker functions `insns_begin` and `insns_end`. The
//! project's QEMU plugin (xtask/qemu-plugin/insn_markers.c) counts the instructions executed
//! between the two markers; this firmware prints, over semihosting and in the same order, the
//! name of each measurement (`measure NAME`). `cargo xtask insns` pairs the two streams.
//!
//! On the host this is a stub.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("insns-firmware only builds for thumbv7em-none-eabihf (run `cargo xtask insns`)");
    std::process::exit(2);
}

#[cfg(target_os = "none")]
mod bench {
    use autopilot::app::Autopilot;
    use autopilot::AutopilotConfig;
    use core::hint::black_box;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    use protocol::{
        AutopilotToStereoDecoder, Estimate, EstimateFlags, GyroAttitude, ImuSample,
        StereoToAutopilot, STEREO_FRAME_BYTES,
    };
    use stereo_board::edge_fs::{
        edge_histograms, flow_match, flow_row, flow_row_within, line_fit, robust_line_fit,
        row_histogram, stereo_match, stereo_row, EdgeFs, EdgeFsParams, EdgeHistogram,
    };
    use stm32f4xx_hal as _;

    /// Frames embedded by build.rs (interleaved 128x96 stereo frames, back to back).
    static FRAMES: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/frames.bin"));

    // Large state lives in statics, as on the board (not on the small QEMU stack).
    static mut EDGE_FS_DEFAULT: EdgeFs = EdgeFs::new(EdgeFsParams::default_config());
    static mut EDGE_FS_PAPER: EdgeFs = EdgeFs::new(EdgeFsParams::paper());
    /// The default configuration with the vertical flow on (issue 34's candidate default).
    static mut EDGE_FS_VERTICAL: EdgeFs = EdgeFs::new(EdgeFsParams {
        vertical_search_px: EdgeFsParams::VERTICAL_SEARCH_PX,
        ..EdgeFsParams::default_config()
    });

    /// Marker: the plugin notes the instruction count when this runs.
    #[no_mangle]
    #[inline(never)]
    pub extern "C" fn insns_begin() {
        // Distinct bodies so that the linker cannot fold the two markers into one address.
        // SAFETY: `nop`s touch no memory, stack or flags.
        unsafe { core::arch::asm!("nop", "nop", options(nomem, nostack)) }
    }

    /// Marker: the plugin prints the instructions executed since [`insns_begin`].
    #[no_mangle]
    #[inline(never)]
    pub extern "C" fn insns_end() {
        // SAFETY: a `nop` touches no memory, stack or flags.
        unsafe { core::arch::asm!("nop", options(nomem, nostack)) }
    }

    /// Announces `name`, then runs `f` between the markers.
    #[inline(never)]
    fn measure<R>(name: &str, f: impl FnOnce() -> R) -> R {
        hprintln!("measure {}", name);
        insns_begin();
        let r = f();
        insns_end();
        black_box(r)
    }

    fn frame(k: usize) -> Option<&'static [u8; STEREO_FRAME_BYTES]> {
        FRAMES
            .get(k * STEREO_FRAME_BYTES..(k + 1) * STEREO_FRAME_BYTES)
            .and_then(|s| s.try_into().ok())
    }

    fn gyro(k: usize) -> GyroAttitude {
        GyroAttitude {
            timestamp_us: protocol::WireTime((k as u32) * 40_000),
            rates_radps: [0.01, -0.02, 0.05],
            attitude_rad: [0.0, 0.0, 0.002 * k as f32],
        }
    }

    /// One record of the worst-frame file: a flag byte (1: the first frame of a sequence, the
    /// Edge-FS history starts afresh) and an interleaved stereo frame.
    const RECORD_BYTES: usize = 1 + STEREO_FRAME_BYTES;

    /// The record being processed (large: a static, as the frames are on the board).
    static mut RECORD: [u8; RECORD_BYTES] = [0; RECORD_BYTES];

    /// Every frame of the host file `INSNS_WORST_FRAMES` names (every frame of every shipped take
    /// and the adversarial sequences `cargo xtask insns` writes), read over semihosting one
    /// record at a time outside the markers, each measured as `edge_fs_frame_worst` in default
    /// mode. Without the variable, nothing.
    fn worst_frames(edge_fs: &mut EdgeFs) {
        let Some(path) = option_env!("INSNS_WORST_FRAMES") else {
            return;
        };
        let mut name = [0u8; 512];
        let Some(slot) = name.get_mut(..path.len()) else {
            hprintln!("error: worst-frame path too long: {}", path);
            debug::exit(debug::EXIT_FAILURE);
            return;
        };
        slot.copy_from_slice(path.as_bytes());
        // SAFETY: semihosting OPEN of a NUL-terminated name in `name` (the length excludes
        // the NUL); QEMU's host reads it, nothing else touches the buffer meanwhile.
        let fd = unsafe {
            cortex_m_semihosting::syscall!(
                OPEN,
                name.as_ptr(),
                cortex_m_semihosting::nr::open::R_BINARY,
                path.len()
            )
        } as isize;
        if fd < 0 {
            hprintln!("error: cannot open {}", path);
            debug::exit(debug::EXIT_FAILURE);
            return;
        }
        // SAFETY: single-threaded benchmark; this is the only reference to the static.
        let record = unsafe { &mut *core::ptr::addr_of_mut!(RECORD) };
        let mut k = 0usize;
        loop {
            // SAFETY: semihosting READ into `record`, `RECORD_BYTES` long; it answers how many
            // bytes it did not read.
            let unread = unsafe {
                cortex_m_semihosting::syscall!(READ, fd, record.as_mut_ptr(), RECORD_BYTES)
            };
            if unread == RECORD_BYTES {
                break;
            }
            if unread != 0 {
                hprintln!("error: a truncated record in {}", path);
                debug::exit(debug::EXIT_FAILURE);
                return;
            }
            if record[0] == 1 {
                edge_fs.reset();
                k = 0;
            }
            let Ok(f) = <&[u8; STEREO_FRAME_BYTES]>::try_from(&record[1..]) else {
                return;
            };
            let t = 40_000 * k as u64;
            let g = gyro(k);
            measure("edge_fs_frame_worst", || {
                edge_fs.process(f, timebase::Instant::from_micros(t), Some(&g))
            });
            k += 1;
        }
        // SAFETY: semihosting CLOSE of the handle OPEN gave.
        unsafe { cortex_m_semihosting::syscall!(CLOSE, fd) };
    }

    #[entry]
    fn main() -> ! {
        let frames = FRAMES.len() / STEREO_FRAME_BYTES;
        if frames < 2 {
            hprintln!("error: no frames embedded (build with cargo xtask insns)");
            debug::exit(debug::EXIT_FAILURE);
        }
        hprintln!("frames {}", frames);
        measure("baseline", || ());

        // Whole Edge-FS frames; the first frames fill the history, xtask takes the median of
        // the frames measured after it is full.
        // SAFETY: single-threaded benchmark, no interrupts touch these statics.
        let (default, paper, vertical) = unsafe {
            (
                &mut *core::ptr::addr_of_mut!(EDGE_FS_DEFAULT),
                &mut *core::ptr::addr_of_mut!(EDGE_FS_PAPER),
                &mut *core::ptr::addr_of_mut!(EDGE_FS_VERTICAL),
            )
        };
        for k in 0..frames {
            let Some(f) = frame(k) else { break };
            let t = 40_000 * k as u64;
            let g = gyro(k);
            measure("edge_fs_frame_default", || {
                default.process(f, timebase::Instant::from_micros(t), Some(&g))
            });
        }
        for k in 0..frames {
            let Some(f) = frame(k) else { break };
            let t = 40_000 * k as u64;
            let g = gyro(k);
            measure("edge_fs_frame_vertical", || {
                vertical.process(f, timebase::Instant::from_micros(t), Some(&g))
            });
        }
        for k in 0..frames {
            let Some(f) = frame(k) else { break };
            let t = 40_000 * k as u64;
            let g = gyro(k);
            measure("edge_fs_frame_paper", || {
                paper.process(f, timebase::Instant::from_micros(t), Some(&g))
            });
        }

        worst_frames(default);

        // The building blocks on the last two frames.
        let (mut left, mut right): (EdgeHistogram, EdgeHistogram) = ([0; 128], [0; 128]);
        let (mut old_left, mut old_right): (EdgeHistogram, EdgeHistogram) = ([0; 128], [0; 128]);
        if let (Some(a), Some(b)) = (frame(frames - 2), frame(frames - 1)) {
            edge_histograms(a, &mut old_left, &mut old_right);
            measure("edge_histograms", || {
                edge_histograms(b, &mut left, &mut right)
            });
            let (mut old_rows, mut rows): (EdgeHistogram, EdgeHistogram) = ([0; 128], [0; 128]);
            row_histogram(a, &mut old_rows);
            measure("row_histogram", || row_histogram(b, &mut rows));
            let dp = EdgeFsParams::default_config();
            measure("flow_row_vertical", || {
                let mut sum = 0u32;
                let w = usize::from(dp.half_window);
                let d = usize::from(EdgeFsParams::VERTICAL_SEARCH_PX);
                flow_row_within(&old_rows, &rows, d, 0, w, 1, 94, |_, m| {
                    sum = sum.wrapping_add(m.best as u32);
                });
                sum
            });
        }
        let (w, d) = (8usize, 15usize);
        measure("stereo_match", || {
            let mut sum = 0u32;
            for c in w + d..128 - w - d {
                if let Some(m) = stereo_match(&left, &right, c, d, 0, w) {
                    sum = sum.wrapping_add(m.best as u32);
                }
            }
            sum
        });
        measure("flow_match", || {
            let mut sum = 0u32;
            for c in w + d..128 - w - d {
                if let Some(m) = flow_match(&old_left, &left, c, d, 0, w) {
                    sum = sum.wrapping_add(m.best as u32);
                }
            }
            sum
        });
        // What the default-mode frame runs: whole-row matching (running-sum SAD + best match per
        // column) with the default parameters, on histograms with the border bins dropped.
        let dp = EdgeFsParams::default_config();
        let (w, d, ds) = (
            usize::from(dp.half_window),
            usize::from(dp.search_range),
            usize::from(dp.stereo_range),
        );
        for h in [&mut left, &mut right, &mut old_right] {
            h[0] = 0;
            h[127] = 0;
        }
        measure("stereo_row", || {
            let mut sum = 0u32;
            stereo_row(&left, &right, ds, dp.stereo_shift_px, w, |_, m| {
                sum = sum.wrapping_add(m.best as u32);
            });
            sum
        });
        measure("flow_row", || {
            let mut sum = 0u32;
            flow_row(&old_right, &right, d, 0, w, |_, m| {
                sum = sum.wrapping_add(m.best as u32);
            });
            sum
        });
        // The default mode's fit: robust (4 Huber rounds, k = 1), f32, 80 columns with a few
        // outliers. The paper mode's f64 least squares is `line_fit_paper`.
        let mut pts: [(f32, f32, f32); 80] = core::array::from_fn(|i| {
            let x = i as f32 - 40.0;
            let noise = ((i * 37) % 11) as f32 * 0.01 - 0.05;
            let outlier = if i % 13 == 5 { 3.0 } else { 0.0 };
            (x, 0.4 * x + 2.0 + noise + outlier, 1.0)
        });
        let (mut prior, mut scratch) = ([0.0f32; 80], [0.0f32; 80]);
        measure("line_fit", || {
            robust_line_fit(black_box(&mut pts), &mut prior, &mut scratch, 4, dp.huber_k)
        });
        let points: [(f64, f64); 80] =
            core::array::from_fn(|i| (i as f64 + 24.0, 0.01 * i as f64 - 0.3));
        measure("line_fit_paper", || {
            line_fit(black_box(&points).iter().copied())
        });

        // The autopilot's 512 Hz step and its guidance + FSM step, in flight.
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let mut t = 0u64;
        for k in 0..3072u32 {
            t = u64::from(k) * 1_953;
            // The host's heartbeat (the autopilot neither arms nor stays in flight without).
            if k % 256 == 0 {
                ap.on_host_heartbeat(timebase::Instant::from_micros(t));
            }
            // Arm once the attitude estimate has settled (the autopilot refuses earlier).
            if k == 512 {
                ap.on_command(
                    protocol::PilotCommand::Arm,
                    timebase::Instant::from_micros(t),
                );
            }
            // Tilted as in forward flight (roll 0.08 rad, pitch -0.06 rad: the specific force
            // of that attitude), so that the trigonometry runs its general path, not the
            // small-angle shortcuts a level attitude would take.
            let imu = ImuSample {
                timestamp_us: protocol::WireTime(t as u32),
                gyro_radps: [0.01, 0.0, -0.01],
                accel_mps2: [-0.5883, -0.7818, -9.7610],
            };
            if k % 10 == 0 {
                ap.on_estimate(&estimate(k as u16, t), timebase::Instant::from_micros(t));
                ap.on_external_position(
                    &protocol::ExternalPosition {
                        timestamp_us: protocol::WireTime(t as u32),
                        position_m: [0.0, 0.0, -1.0],
                    },
                    timebase::Instant::from_micros(t),
                );
                ap.guidance_step(timebase::Instant::from_micros(t));
            }
            if k >= 3064 {
                measure("indi_step", || {
                    ap.on_imu(&imu, timebase::Instant::from_micros(t))
                });
            } else {
                ap.on_imu(&imu, timebase::Instant::from_micros(t));
            }
        }
        t += 20_000;
        ap.on_estimate(&estimate(999, t), timebase::Instant::from_micros(t));
        measure("guidance_fsm_step", || {
            ap.guidance_step(timebase::Instant::from_micros(t))
        });
        // The measurement is only meaningful in flight: say which mode it ran in.
        hprintln!("autopilot mode {:?}", ap.mode());

        // Wire format of the per-frame message.
        let msg = StereoToAutopilot::Estimate(estimate(7, 123_456));
        let mut wire = [0u8; 64];
        let n = measure("estimate_encode", || {
            protocol::encode(&msg, &mut wire).unwrap_or(0)
        });
        let mut decoder = protocol::StereoToAutopilotDecoder::new();
        measure("estimate_decode", || {
            let mut got = 0u32;
            decoder.feed(&wire[..n], |_| got += 1);
            got
        });
        // The camera board's RX path: one gyro/attitude message (128 Hz, so about five per
        // 25 fps frame) decoded by the streaming decoder.
        let msg = protocol::AutopilotToStereo::GyroAttitude(gyro(5));
        let n = protocol::encode(&msg, &mut wire).unwrap_or(0);
        let mut decoder = AutopilotToStereoDecoder::new();
        measure("gyro_decode", || {
            let mut got = 0u32;
            decoder.feed(&wire[..n], |_| got += 1);
            got
        });

        hprintln!("done");
        debug::exit(debug::EXIT_SUCCESS);
        #[allow(clippy::empty_loop)]
        loop {}
    }

    fn estimate(seq: u16, t: u64) -> Estimate {
        Estimate {
            seq,
            capture_us: protocol::WireTime(t as u32),
            forward_mps: 0.3,
            sideways_mps: -0.02,
            obstacle_m: Some(1.5),
            quality: 180,
            flags: EstimateFlags::NONE,
            processing_us: 1_200,
            depth_coverage: 255,
            near_columns: 0,
            fit: Some(protocol::FrameFit {
                forward_mps: 0.31,
                sideways_mps: -0.03,
                quality: 170,
            }),
            up_mps: 0.0,
            up_flags: EstimateFlags::NO_FLOW_MATCH,
            fit_r2: 0,
            divergence: None,
        }
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        hprintln!("panic: {}", info);
        debug::exit(debug::EXIT_FAILURE);
        #[allow(clippy::empty_loop)]
        loop {}
    }
}
