//! The lockstep on world time with the two boards (see the module docs of [`super`]): [`run`]
//! and [`run_logged`] wait for both boards' heartbeats, send the parameter file if any, then
//! step the world one IMU period per `Motors` reply, streaming frames and holding the world
//! for their estimates, and return what the run measured.

use super::board_rx::BoardRx;
use super::encode::{encode_frame, host_signer, push_msg};
use super::recorder::HilRecorder;
use super::relay::Relay;
use super::result::{HilResult, HilRow};
use super::HilConfig;
use crate::log::FlightLog;
use crate::param::{FileSection, LinkClosed, MessageSource, ParamClient};
use crate::sim::sched::{imu_sample_time, SensorSchedule};
use crate::sim::world::World;
use crate::transport::Link;
use anyhow::{anyhow, bail, Context as _};
use protocol::{
    BoardToHost, Estimate, Heartbeat, HostToBoard, ImuSample, Node, PilotCommand, WireTime,
    STEREO_FRAME_BYTES,
};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};
use timebase::WorldTime;

/// Waits for a first heartbeat on a board's host link (the board is up and its USART
/// receives: bytes sent earlier are lost).
fn wait_heartbeat(rx: &BoardRx, name: &str, timeout: Duration) -> anyhow::Result<()> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline
            .checked_duration_since(Instant::now())
            .ok_or_else(|| anyhow!("no heartbeat from the {name} within {timeout:?}"))?;
        match rx.rx.recv_timeout(left) {
            Ok(BoardToHost::Heartbeat(_)) => return Ok(()),
            Ok(_) => {}
            Err(RecvTimeoutError::Timeout) => {
                bail!("no heartbeat from the {name} within {timeout:?}")
            }
            Err(RecvTimeoutError::Disconnected) => bail!("the {name}'s link closed"),
        }
    }
}

/// Runs the world against the two boards' host links (and, optionally, relays their
/// board-to-board UART). `progress` is called with the world time about once per world
/// second.
pub fn run(
    cfg: &HilConfig,
    stereo: Box<dyn Link>,
    autopilot: Box<dyn Link>,
    relay: Option<&Relay>,
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<HilResult> {
    run_logged(cfg, stereo, autopilot, relay, progress, None)
}

/// [`run`], recording the flight into `log` (see [`HilRecorder`] for what goes in). A failed
/// write stops the recording and is reported in [`HilResult::log_error`]; the flight goes on.
pub fn run_logged(
    cfg: &HilConfig,
    stereo: Box<dyn Link>,
    autopilot: Box<dyn Link>,
    relay: Option<&Relay>,
    progress: &mut dyn FnMut(f64),
    log: Option<&mut FlightLog>,
) -> anyhow::Result<HilResult> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(cfg.fps) || !positive(cfg.height_rate_hz) {
        bail!("fps and height rate must be positive");
    }
    let mut world = World::new(&cfg.world)?;
    let start_xy = [world.start[0], world.start[1]];

    let stop = Arc::new(AtomicBool::new(false));
    let ap_rx = BoardRx::start(autopilot.try_clone_link()?, Arc::clone(&stop));
    let cam_rx = BoardRx::start(stereo.try_clone_link()?, Arc::clone(&stop));
    let mut ap_tx = autopilot;
    // Frames are written by their own thread: a frame takes 0.27 s of a 921,600 Bd link.
    let (frame_tx, frame_rx): (Sender<Vec<u8>>, Receiver<Vec<u8>>) = mpsc::channel();
    {
        let mut link = stereo;
        std::thread::spawn(move || {
            while let Ok(bytes) = frame_rx.recv() {
                if link.write_all(&bytes).is_err() {
                    break;
                }
            }
        });
    }
    let result = (|| {
        wait_heartbeat(&ap_rx, "autopilot", cfg.boot_timeout)?;
        wait_heartbeat(&cam_rx, "camera board", cfg.boot_timeout)?;
        if let Some((file, sections)) = &cfg.params {
            send_params(file, sections, &mut ap_tx, &ap_rx, cfg)?;
        }
        let recorder = HilRecorder::new(log, &world);
        lockstep(
            cfg, &mut world, &mut ap_tx, &ap_rx, &cam_rx, &frame_tx, relay, start_xy, progress,
            recorder,
        )
    })();
    stop.store(true, Ordering::Relaxed);
    result
}

/// Sets and reads back every value of `sections` over the autopilot's host link, before the
/// world starts (the boards are disarmed); the first failure is the error.
fn send_params(
    file: &str,
    sections: &[FileSection],
    ap_tx: &mut Box<dyn Link>,
    ap_rx: &BoardRx,
    cfg: &HilConfig,
) -> anyhow::Result<()> {
    let timeout = cfg.reply_timeout;
    for section in sections {
        let source: MessageSource<'_> = Box::new(|wait| match ap_rx.rx.recv_timeout(wait) {
            Ok(m) => Ok(Some(m)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(LinkClosed),
        });
        let mut c =
            ParamClient::with_source(Box::new(&mut **ap_tx), source, section.board, timeout);
        c.sign_with(host_signer(cfg));
        section
            .send_and_verify(&mut c, file)
            .context("not flying: the boards do not run the parameter file")?;
    }
    Ok(())
}

/// The lockstep loop (see the module docs).
#[allow(clippy::too_many_arguments)]
fn lockstep(
    cfg: &HilConfig,
    world: &mut World,
    ap_tx: &mut Box<dyn Link>,
    ap_rx: &BoardRx,
    cam_rx: &BoardRx,
    frame_tx: &Sender<Vec<u8>>,
    relay: Option<&Relay>,
    start_xy: [f64; 2],
    progress: &mut dyn FnMut(f64),
    mut rec: HilRecorder<'_>,
) -> anyhow::Result<HilResult> {
    let wall0 = Instant::now();
    let end = WorldTime::from_micros((cfg.duration_s * 1e6) as u64);
    let arm_at = WorldTime::from_micros((cfg.arm_at_s * 1e6) as u64);
    let physics_dt = cfg.world.physics_dt.max(timebase::Duration::from_micros(1));
    let mut r = HilResult {
        max_height_m: 0.0,
        ..Default::default()
    };
    let mut k = 0u64;
    let mut t = WorldTime::ZERO;
    // The autopilot reads its own barometer (or, in the lockstep images, none).
    let mut sensors = SensorSchedule::new(cfg.fps, Some(cfg.height_rate_hz), None);
    let mut next_log = WorldTime::ZERO;
    let mut next_progress = WorldTime::ZERO + timebase::Duration::from_secs(1);
    let mut armed = false;
    let mut outputs_pending = cfg.outputs;
    let mut motors = [0.0f32; 4];
    let mut frame_id = 0u16;
    let mut signer = host_signer(cfg);
    // Exposure time (wire) of the frame whose estimate is awaited, and when it was sent.
    let mut in_flight: Option<(WireTime, Instant)> = None;
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    let mut out = Vec::new();

    'flight: while t < end {
        if cfg
            .interrupt
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            r.ended_early = Some("interrupted".into());
            break;
        }
        // Camera: hold the world at the exposure time until the previous frame is answered.
        if sensors.frame.due(t) {
            if let Some((_, sent)) = in_flight {
                let held = Instant::now();
                let deadline = sent + cfg.frame_timeout;
                while in_flight.is_some() {
                    let left = deadline.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        r.frame_timeouts += 1;
                        break;
                    }
                    match cam_rx.rx.recv_timeout(left) {
                        Ok(BoardToHost::Estimate(e)) => {
                            rec.estimate(t, &e);
                            on_estimate(&e, &mut r, &mut in_flight)
                        }
                        Ok(_) => {}
                        Err(RecvTimeoutError::Timeout) => {}
                        Err(RecvTimeoutError::Disconnected) => {
                            r.ended_early = Some("the camera board's link closed".into());
                            break 'flight;
                        }
                    }
                }
                r.frame_wait_s += held.elapsed().as_secs_f64();
            }
            world.render(&mut frame);
            let capture = t.to_wire();
            if frame_tx
                .send(encode_frame(&frame, frame_id, capture)?)
                .is_err()
            {
                r.ended_early = Some("the camera board's link closed".into());
                break;
            }
            rec.frame(t, &frame);
            in_flight = Some((capture, Instant::now()));
            frame_id = frame_id.wrapping_add(1);
            r.frames_sent += 1;
        }
        while let Ok(m) = cam_rx.rx.try_recv() {
            if let BoardToHost::Estimate(e) = m {
                rec.estimate(t, &e);
                on_estimate(&e, &mut r, &mut in_flight);
            }
        }

        // Autopilot: the host's heartbeat (the autopilot lands without it), height fix, arm,
        // then the IMU sample of this instant.
        out.clear();
        if sensors.host_heartbeat.due(t) {
            let hb = Heartbeat::new(Node::Host, t.since(WorldTime::ZERO).as_millis() as u32);
            push_msg(&signer.wrap(HostToBoard::Heartbeat(hb))?, &mut out)?;
        }
        if sensors.height_fix.due(t) {
            push_msg(
                &signer.wrap(HostToBoard::ExternalPosition(world.height_fix(t)))?,
                &mut out,
            )?;
        }
        if outputs_pending {
            outputs_pending = false;
            push_msg(
                &signer.wrap(HostToBoard::Command(PilotCommand::HilOutputs(true)))?,
                &mut out,
            )?;
        }
        if !armed && t >= arm_at {
            armed = true;
            push_msg(
                &signer.wrap(HostToBoard::Command(PilotCommand::Arm))?,
                &mut out,
            )?;
        }
        let s = world.imu_sample();
        let stamp = t.to_wire();
        push_msg(
            &HostToBoard::Imu(ImuSample {
                timestamp_us: stamp,
                gyro_radps: s.gyro.to_f32(),
                accel_mps2: s.accel.to_f32(),
            }),
            &mut out,
        )?;
        if let Err(e) = ap_tx.write_all(&out) {
            r.ended_early = Some(format!("writing to the autopilot: {e}"));
            break;
        }
        r.imu_samples += 1;
        let waiting = Instant::now();
        let deadline = waiting + cfg.reply_timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match ap_rx.rx.recv_timeout(left) {
                Ok(BoardToHost::Motors(m)) if m.timestamp_us == stamp => {
                    motors = m.throttle.map(|v| {
                        if v.is_finite() {
                            v.clamp(0.0, 1.0)
                        } else {
                            0.0
                        }
                    });
                    r.motor_replies += 1;
                    rec.motors(t, motors);
                    break;
                }
                Ok(BoardToHost::Telemetry(tel)) => {
                    rec.telemetry(t, &tel, s.gyro.to_f32(), &world.drone, &r, [ap_rx, cam_rx]);
                    r.last_telemetry = Some(tel);
                }
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout) => {
                    r.reply_timeouts += 1;
                    break;
                }
                Err(RecvTimeoutError::Disconnected) => {
                    r.ended_early = Some("the autopilot's link closed".into());
                    break 'flight;
                }
            }
        }
        r.imu_wait_s += waiting.elapsed().as_secs_f64();
        r.max_motor = motors.iter().fold(r.max_motor, |a, &b| a.max(b));

        // World: one IMU period with these motor commands.
        k += 1;
        let t_next = imu_sample_time(k);
        let cmd = motors.map(f64::from);
        while t < t_next {
            let step = physics_dt.min(t_next - t);
            let dt = step.as_secs_f64();
            t += step;
            world.step(&cmd, dt, t);
        }
        r.collisions = world.collisions;
        r.airborne_s = world.airborne_s;
        let p = world.drone.state.pos;
        let h = -p.z;
        r.max_height_m = r.max_height_m.max(h);
        r.final_height_m = h;
        let drift = ((p.x - start_xy[0]).powi(2) + (p.y - start_xy[1]).powi(2)).sqrt();
        r.max_drift_m = r.max_drift_m.max(drift);
        if t >= next_log {
            next_log += timebase::Duration::from_millis(20);
            rec.truth(t, &world.drone, r.collisions);
            r.log.push(HilRow {
                t_s: t.as_secs_f64(),
                pos: [p.x as f32, p.y as f32, h as f32],
                vel: [
                    world.drone.state.vel.x as f32,
                    world.drone.state.vel.y as f32,
                ],
                motors,
                mode: r.last_telemetry.map(|t| t.flight_mode),
            });
        }
        if t >= next_progress {
            progress(t.as_secs_f64());
            next_progress += timebase::Duration::from_secs(1);
        }
    }
    // Late telemetry and estimates.
    while let Ok(m) = ap_rx.rx.try_recv() {
        if let BoardToHost::Telemetry(tel) = m {
            r.last_telemetry = Some(tel);
        }
    }
    while let Ok(m) = cam_rx.rx.try_recv() {
        if let BoardToHost::Estimate(e) = m {
            on_estimate(&e, &mut r, &mut in_flight);
        }
    }
    r.sim_s = t.as_secs_f64();
    r.wall_s = wall0.elapsed().as_secs_f64();
    r.log_error = rec.error.map(|e| format!("{e:#}"));
    r.autopilot_link_errors = ap_rx.errors();
    r.stereo_link_errors = cam_rx.errors();
    if let Some(relay) = relay {
        let (n, e) = relay.counts();
        r.relayed_messages = n;
        r.relay_errors = e;
    }
    Ok(r)
}

/// Counts an estimate mirrored by the camera board; clears the awaited frame if it is its.
fn on_estimate(e: &Estimate, r: &mut HilResult, in_flight: &mut Option<(WireTime, Instant)>) {
    r.estimates += 1;
    r.valid_estimates += u64::from(e.is_valid());
    for (bit, n) in r.flag_counts.iter_mut().enumerate() {
        *n += u64::from(e.flags.0 >> bit & 1);
    }
    if in_flight.is_some_and(|(c, _)| c == e.capture_us) {
        *in_flight = None;
    }
}

#[cfg(test)]
mod tests {
    //! The host side of the lockstep against two software boards on loopback TCP that run the
    //! boards' own libraries the way the lockstep firmwares do (world clock from the IMU
    //! timestamps, `autopilot::lockstep::WorldTimers` releasing the periodic tasks, Edge-FS
    //! at the frames' exposure times). Fast, no firmware: `virtual-board/tests/vboard/hil.rs` flies
    //! the `hil` images on the virtual boards.
    use super::super::recorder::write_log_csv;
    use super::super::test_boards::software_boards;
    use super::*;
    use crate::param::ParamFile;
    use std::net::TcpStream;

    fn fly_with(sections: Vec<FileSection>) -> anyhow::Result<HilResult> {
        let (cam_host, ap_host) = software_boards();
        let cfg = HilConfig {
            duration_s: 0.2,
            fps: 10.0,
            reply_timeout: Duration::from_secs(2),
            params: Some(("p.toml".into(), sections)),
            ..HilConfig::default()
        };
        run(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |_| {},
        )
    }

    #[test]
    fn params_are_set_and_read_back_on_both_boards_before_the_flight() {
        let (_, sections) = ParamFile::parse_sections(
            "[camera]\nstereo_shift = -3\nhalf_window = 5\n[autopilot]\ntarget_height = 0.8\n",
            "p.toml",
        )
        .unwrap();
        let r = fly_with(sections).unwrap();
        assert_eq!(
            r.motor_replies,
            r.imu_samples,
            "the flight ran: {}",
            r.summary()
        );
        assert!(r.imu_samples > 100, "{}", r.summary());

        // A value the board refuses (read-only on the autopilot) stops the run, naming it.
        let refused = vec![FileSection {
            board: Node::Autopilot,
            values: vec![("indi_rate_hz".into(), protocol::ParamValue::F32(512.0))],
        }];
        let e = format!("{:#}", fly_with(refused).unwrap_err());
        assert!(
            e.contains("not flying")
                && e.contains("[autopilot] indi_rate_hz")
                && e.contains("read-only"),
            "{e}"
        );

        // A read-back that differs from the value sent (the key set twice: the board holds the
        // second) stops it too.
        let v = protocol::ParamValue::I32;
        let twice = vec![FileSection {
            board: Node::StereoBoard,
            values: vec![
                ("stereo_shift".into(), v(-3)),
                ("stereo_shift".into(), v(4)),
            ],
        }];
        let e = format!("{:#}", fly_with(twice).unwrap_err());
        assert!(
            e.contains("p.toml: [camera] stereo_shift: set to -3, but the board reads back 4"),
            "{e}"
        );
    }

    /// Flies the software boards for up to 30 s of world time, calling `at_one_second` with
    /// the autopilot's host end once world time passes 1 s; returns the result, the CSV and
    /// the MCAP file's bytes.
    fn fly_until(
        name: &str,
        interrupt: Option<Arc<AtomicBool>>,
        at_one_second: impl FnOnce(&TcpStream),
    ) -> (HilResult, String, Vec<u8>) {
        let (cam_host, ap_host) = software_boards();
        let ap_host_end = ap_host.try_clone().unwrap();
        let cfg = HilConfig {
            duration_s: 30.0,
            fps: 10.0,
            reply_timeout: Duration::from_secs(2),
            interrupt,
            ..HilConfig::default()
        };
        let dir = std::env::temp_dir().join(format!("hil-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut log = FlightLog::create(&dir.join("flight.mcap")).unwrap();
        let mut once = Some(at_one_second);
        let r = run_logged(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |t| {
                if t >= 1.0 {
                    if let Some(f) = once.take() {
                        f(&ap_host_end);
                    }
                }
            },
            Some(&mut log),
        )
        .expect("the flight ends with a result");
        drop(ap_host_end);
        log.finish().expect("the log is finished");
        write_log_csv(&r, &dir.join("hil_log.csv")).unwrap();
        let csv = std::fs::read_to_string(dir.join("hil_log.csv")).unwrap();
        let mcap = std::fs::read(dir.join("flight.mcap")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        (r, csv, mcap)
    }

    /// The CSV's last row is whole (as many fields as the header) and its time is `sim_s`'s.
    fn assert_whole_csv(csv: &str, r: &HilResult) {
        assert!(csv.ends_with('\n'), "{csv}");
        let mut lines = csv.lines();
        let columns = lines.next().unwrap().split(',').count();
        let last = lines.last().expect("rows");
        assert_eq!(last.split(',').count(), columns, "{last}");
        let t: f64 = last.split(',').next().unwrap().parse().unwrap();
        assert!(t <= r.sim_s && t > r.sim_s - 0.05, "{t} {}", r.sim_s);
    }

    /// The MCAP file has its summary and footer, and every message reads.
    fn assert_finished_mcap(bytes: &[u8]) -> usize {
        let summary = mcap::Summary::read(bytes).expect("a summary section");
        assert!(summary.is_some_and(|s| !s.channels.is_empty()));
        let mut n = 0;
        for m in mcap::MessageStream::new(bytes).unwrap() {
            m.expect("a whole message");
            n += 1;
        }
        n
    }

    #[test]
    fn an_interrupt_ends_the_flight_with_its_logs_whole() {
        let flag = Arc::new(AtomicBool::new(false));
        let set = Arc::clone(&flag);
        let (r, csv, mcap) = fly_until("interrupt", Some(flag), move |_| {
            set.store(true, Ordering::SeqCst)
        });
        assert_eq!(
            r.ended_early.as_deref(),
            Some("interrupted"),
            "{}",
            r.summary()
        );
        assert!(r.sim_s >= 1.0 && r.sim_s < 1.1, "{}", r.summary());
        assert!(r.summary().contains("ended early       interrupted"));
        assert_whole_csv(&csv, &r);
        assert!(assert_finished_mcap(&mcap) > 100);
    }

    #[test]
    fn a_closed_link_ends_the_flight_with_its_logs_whole() {
        // The autopilot's host link closed under the flight (a USB adapter unplugged).
        let (r, csv, mcap) = fly_until("closed", None, |autopilot| {
            autopilot.shutdown(std::net::Shutdown::Both).unwrap()
        });
        let why = r.ended_early.clone().unwrap_or_default();
        assert!(why.contains("autopilot"), "{}", r.summary());
        assert!(r.sim_s >= 1.0 && r.sim_s < 1.1, "{}", r.summary());
        assert_whole_csv(&csv, &r);
        assert!(assert_finished_mcap(&mcap) > 100);
    }

    #[test]
    fn lockstep_flies_software_boards_off_the_floor() {
        let (cam_host, ap_host) = software_boards();
        // Armed at 1 s, as a user arms on valid estimates: the 10 fps camera's first valid one
        // comes once its flow history has filled, about 0.9 s in.
        let cfg = HilConfig {
            duration_s: 3.0,
            fps: 10.0,
            arm_at_s: 1.0,
            ..HilConfig::default()
        };
        let mcap_path =
            std::env::temp_dir().join(format!("hil-lockstep-{}.mcap", std::process::id()));
        let mut log = FlightLog::create(&mcap_path).unwrap();
        let r = run_logged(
            &cfg,
            Box::new(cam_host),
            Box::new(ap_host),
            None,
            &mut |_| {},
            Some(&mut log),
        )
        .unwrap();
        let logged = log.finish().unwrap();
        let s = r.summary();
        assert_eq!(r.log_error, None);
        // The log holds what the run saw, channel by channel, in time order.
        let bytes = std::fs::read(&mcap_path).unwrap();
        let _ = std::fs::remove_file(&mcap_path);
        let mut counts = std::collections::BTreeMap::new();
        let mut last_ns = 0;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert!(m.log_time >= last_ns, "{} out of order", m.channel.topic);
            last_ns = m.log_time;
            *counts.entry(m.channel.topic.clone()).or_insert(0u64) += 1;
        }
        let count = |t: &str| counts.get(t).copied().unwrap_or(0);
        assert_eq!(count("/estimate"), r.estimates, "{counts:?}");
        assert_eq!(
            count("/camera/left"),
            15,
            "frames at 0.1 s, 0.3 s ... 2.9 s"
        );
        assert_eq!(count("/camera/right"), 15);
        assert_eq!(count("/truth"), r.log.len() as u64);
        assert!(
            (380..=386).contains(&count("/motors")),
            "128 Hz: {counts:?}"
        );
        assert!(
            (25..=31).contains(&count("/state")),
            "10 Hz telemetry: {counts:?}"
        );
        for t in ["/attitude", "/setpoint", "/velocity", "/height", "/link"] {
            assert_eq!(count(t), count("/state"), "{t}");
        }
        // The host link carries no barometer (heights come as external fixes), so telemetry has
        // no reading to log.
        assert_eq!(count("/baro"), 0, "{counts:?}");
        assert_eq!(
            logged
                .counts
                .iter()
                .map(|(t, n)| (t.to_string(), *n))
                .collect::<Vec<_>>(),
            counts.into_iter().collect::<Vec<_>>()
        );
        assert_eq!(r.imu_samples, 3 * 512, "{s}");
        assert_eq!(r.motor_replies, r.imu_samples, "{s}");
        assert_eq!(r.reply_timeouts + r.frame_timeouts, 0, "{s}");
        assert_eq!(r.frames_sent, 29, "{s}");
        assert!(r.estimates + 1 >= r.frames_sent, "{s}");
        assert!(r.valid_estimates >= 10, "{s}");
        assert_eq!(r.total_link_errors(), 0, "{s}");
        assert!(r.max_height_m > 0.7 && r.max_height_m < 1.4, "{s}");
        assert_eq!(r.collisions, 0, "{s}");
        assert!(r.max_drift_m < 0.5, "{s}");
        assert!(r.last_telemetry.is_some(), "{s}");
    }
}
