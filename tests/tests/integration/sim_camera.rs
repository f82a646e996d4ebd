//! The simulator's stereo camera against geometry, measured with the camera board's own
//! Edge-FS: facing a wall, the per-column disparity matches f*b/Z and the obstacle distance
//! matches Z; moving towards it, the forward velocity is recovered, also where stripes alias
//! the flow search.

use integration_tests::StraightFlight;
use protocol::{GyroAttitude, WireTime, STEREO_FRAME_BYTES};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim_host::sim::camera::{CameraParams, StereoCamera};
use sim_host::sim::math::{Quat, V3};
use sim_host::sim::scene::Scene;
use stereo_board::edge_fs::{EdgeFs, EdgeFsParams};

fn median(mut v: Vec<f32>) -> f32 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

#[test]
fn facing_a_wall_edge_fs_disparity_matches_geometry() {
    let scene = Scene::preset("room", 4).unwrap();
    let params = CameraParams::default();
    let mut cam = StereoCamera::new(params.clone());
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    for z in [1.0f64, 1.5, 2.0] {
        let mut ef = Box::new(EdgeFs::new(EdgeFsParams::default_config()));
        // Camera z metres from the north wall (x = 4), level, facing north.
        let x = 4.0 - z - params.forward_offset_m as f64;
        let mut out = None;
        // A few identical frames at 25 Hz so the estimator's history is full.
        for k in 0..8u64 {
            cam.render(
                &scene,
                V3::new(x, 2.0, -1.0),
                Quat::IDENTITY,
                &mut rng,
                &mut frame,
            );
            out = Some(ef.process(&frame, timebase::Instant::from_micros(k * 40_000), None));
        }
        let d = ef.diagnostics();
        let disp: Vec<f32> = d
            .disparity_px
            .iter()
            .zip(&d.confidence)
            .filter(|(_, c)| **c > 0.0)
            .map(|(d, _)| *d)
            .collect();
        assert!(disp.len() > 30, "z {z}: {} confident columns", disp.len());
        let expect = params.focal_px() * params.baseline_m / z as f32;
        let got = median(disp);
        println!("wall at {z} m: median disparity {got:.2} px, f*b/Z {expect:.2} px");
        assert!((got - expect).abs() < 0.5, "z {z}: {got} vs {expect}");
        let obstacle = out.and_then(|o| o.obstacle_m).expect("a wall in view");
        assert!(
            (obstacle as f64 - z).abs() < 0.2 * z,
            "z {z}: obstacle {obstacle}"
        );
    }
}

#[test]
fn moving_towards_a_wall_gives_forward_velocity() {
    let scene = Scene::preset("room", 5).unwrap();
    let mut cam = StereoCamera::new(CameraParams::default());
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    let mut ef = Box::new(EdgeFs::new(EdgeFsParams::default_config()));
    let v = 0.3; // m/s towards the north wall
    let mut est = Vec::new();
    for k in 0..40u64 {
        let t = k as f64 * 0.04;
        let pos = V3::new(1.0 + v * t, 2.0, -1.0);
        cam.render(&scene, pos, Quat::IDENTITY, &mut rng, &mut frame);
        let o = ef.process(&frame, timebase::Instant::from_micros(k * 40_000), None);
        if k >= 15 && o.flags.0 & !protocol::EstimateFlags::NO_GYRO.0 == 0 {
            est.push(o.forward_mps);
        }
    }
    assert!(est.len() > 10, "{} valid estimates", est.len());
    let m = median(est);
    println!("forward 0.3 m/s: median estimate {m:.3} m/s");
    assert!((m - 0.3).abs() < 0.1, "median forward estimate {m}");
}

/// RMS error of the valid per-frame fits (not the temporal filter's output) while the camera
/// flies at 0.4 m/s from the room's centre to 0.55 m from the wall ahead, heading `yaw_deg`,
/// in the paper's room with texture seed `seed` (bar-code posters whose stripe period in the
/// image is close to the motion over the flow horizon).
fn approach_fit_rms(seed: u64, yaw_deg: f64, params: EdgeFsParams) -> f64 {
    let scene = Scene::preset("room", seed).unwrap();
    // The ideal camera: these approaches were found to alias with it (with the calibrated
    // camera's fixed patterns and vignetting the same approach at seed 903 no longer aliases:
    // fit RMS 0.011 m/s unguided).
    let (v, yaw) = (0.4, yaw_deg.to_radians());
    let dir = V3::new(yaw.cos(), yaw.sin(), 0.0);
    let mut flight = StraightFlight::new(CameraParams::ideal(), params, yaw, dir * v, 1);
    let (mut sq, mut n) = (0.0, 0);
    for k in 0..200u64 {
        let pos = V3::new(2.0, 2.0, -1.0) + dir * (v * k as f64 * 0.04);
        let (_, ahead) = scene.trace(
            [pos.x as f32, pos.y as f32, -1.0],
            [dir.x as f32, dir.y as f32, 0.0],
        );
        if ahead < 0.55 {
            break;
        }
        let o = flight.frame(&scene, pos, k);
        if let (Some(fit), true) = (o.fit, o.flags.is_valid()) {
            sq += (f64::from(fit.forward_mps) - v).powi(2);
            n += 1;
        }
    }
    assert!(n > 60, "{n} valid fits");
    (sq / n as f64).sqrt()
}

/// Periodic stripes alias the flow search (a match one stripe off), and a block of such
/// columns on one side of the image tilts the fit: unguided, some frame fits read 0 or below
/// while the drone flies at 0.4 m/s. Guided by the temporal filter's velocity, the fits stay
/// on it.
#[test]
fn approaching_bar_code_stripes_the_guided_flow_search_does_not_alias() {
    for (seed, yaw_deg) in [(903, 0.0), (5, -30.0)] {
        let guided = approach_fit_rms(seed, yaw_deg, EdgeFsParams::default_config());
        let unguided = approach_fit_rms(
            seed,
            yaw_deg,
            EdgeFsParams {
                prior_window_px: 0.0,
                ..EdgeFsParams::default_config()
            },
        );
        println!("seed {seed}, heading {yaw_deg} deg: fit RMS {guided:.3} m/s guided, {unguided:.3} unguided");
        // Measured: 0.029 / 0.071 and 0.041 / 0.114 m/s.
        assert!(unguided > 0.06, "the scene no longer aliases: {unguided}");
        assert!(
            guided < 0.06 && guided < 0.5 * unguided,
            "guided fit RMS {guided} m/s, unguided {unguided}"
        );
    }
}

/// Valid estimates in 100 frames (4 s) of a camera drifting along its heading `yaw_deg` at
/// `speed_mps` (negative: backwards) from `start`.
fn valid_frames_drifting(
    scene: &Scene,
    start: [f32; 2],
    yaw_deg: f64,
    speed_mps: f64,
    params: EdgeFsParams,
) -> usize {
    let yaw = yaw_deg.to_radians();
    let dir = V3::new(yaw.cos(), yaw.sin(), 0.0);
    let vel = dir * speed_mps;
    let mut flight = StraightFlight::new(CameraParams::default(), params, yaw, vel, 3);
    let start = V3::new(f64::from(start[0]), f64::from(start[1]), -1.0);
    let mut valid = 0;
    for k in 0..100u64 {
        let pos = start + dir * (speed_mps * k as f64 * 0.04);
        valid += usize::from(flight.frame(scene, pos, k).flags.is_valid());
    }
    valid
}

/// A plain room in dim light (the room suite's room 78 of seed 9001, featureless walls and
/// floor at light 0.44, where the failure was found): sensor noise sums to more than
/// `min_texture` per column window, and its matches gave "valid" velocities near zero while
/// the drone drifted into a wall. The noise gate (`noise_texture_ratio`) leaves the room's
/// lone corner no velocity to claim, and leaves the paper's textured room its estimates.
#[test]
fn a_dim_plain_room_gives_no_valid_velocity_and_a_textured_room_does() {
    let room = sim_host::sim::suite::room(9001, 78);
    let dim_plain = Scene::build(&room.spec, room.seed).unwrap();
    let gate = EdgeFsParams::default_config();
    let start = room.spec.start_xy;
    let plain = valid_frames_drifting(&dim_plain, start, -47.0, -0.2, gate);
    let ungated = valid_frames_drifting(
        &dim_plain,
        start,
        -47.0,
        -0.2,
        EdgeFsParams {
            noise_texture_ratio: 0.0,
            ..gate
        },
    );
    let paper_room = Scene::preset("room", 6).unwrap();
    let textured = valid_frames_drifting(&paper_room, [2.0, 2.0], 40.0, -0.2, gate);
    println!(
        "valid estimates in 100 frames: dim plain room {plain} ({ungated} without the gate), \
         paper room {textured}"
    );
    assert!(
        ungated > 20,
        "the plain room no longer fools the estimator: {ungated}"
    );
    assert!(plain <= 10, "dim plain room: {plain} valid estimates");
    assert!(textured >= 80, "paper room: {textured} valid estimates");
}

/// A faint, fine texture is not noise: the wood-grain wall of the room suite's room 95 (seed
/// 9001, light 1.67) sums only 1.5 times the noise's edge sum per window, so a gate on the
/// edge sum alone read it as a plain wall, and the drone landed 10 s into the flight. Its
/// histograms have shape that noise does not give (`noise_structure_ratio`), and Edge-FS keeps
/// its estimates. (This pose is where the failure was found and the ratio chosen.)
#[test]
fn a_faint_wood_grain_wall_is_texture_not_noise() {
    let room = sim_host::sim::suite::room(9001, 95);
    let scene = Scene::build(&room.spec, room.seed).unwrap();
    let gate = EdgeFsParams::default_config();
    let gated = valid_frames_drifting(&scene, [2.5, 3.6], -169.5, 0.2, gate);
    let level_only = valid_frames_drifting(
        &scene,
        [2.5, 3.6],
        -169.5,
        0.2,
        EdgeFsParams {
            noise_structure_ratio: 0.0,
            ..gate
        },
    );
    let ungated = valid_frames_drifting(
        &scene,
        [2.5, 3.6],
        -169.5,
        0.2,
        EdgeFsParams {
            noise_texture_ratio: 0.0,
            ..gate
        },
    );
    println!(
        "valid estimates in 100 frames facing wood grain: {gated} ({level_only} with the edge-sum \
         gate alone, {ungated} without a gate)"
    );
    assert!(
        level_only < 50,
        "the edge-sum gate alone no longer drops this wall: {level_only}"
    );
    assert!(
        gated + 5 >= ungated && gated >= 70,
        "wood grain: {gated} valid estimates ({ungated} without a gate)"
    );
}

/// The auto-exposure settling over the first frames steps the brightness by a quarter between
/// two frames; their fit read -60 m/s on the ground in the room suite's room 35 (seed 9001),
/// and when the temporal filter's guess then guided the flow search, the search found the
/// matches the guess predicted and kept it for seconds (the drone landed at take-off). A
/// filter track guides the search only once a second measurement confirmed it.
#[test]
fn a_brightness_step_does_not_lock_the_guided_flow_search() {
    let room = sim_host::sim::suite::room(9001, 35);
    let scene = Scene::build(&room.spec, room.seed).unwrap();
    let mut cam = StereoCamera::new(CameraParams::default());
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    let mut ef = Box::new(EdgeFs::new(EdgeFsParams::default_config()));
    let yaw = 2.7932f64;
    let att = Quat::from_euler(0.0, 0.0, yaw);
    let mut worst_late = 0.0f32;
    for k in 0..25u64 {
        cam.render(
            &scene,
            V3::new(2.3908, 2.9586, 0.0),
            att,
            &mut rng,
            &mut frame,
        );
        if k == 0 {
            // The first frame a quarter darker than the rest (the exposure still settling).
            for p in frame.iter_mut() {
                *p = (f32::from(*p) * 0.8) as u8;
            }
        }
        let gyro = GyroAttitude {
            timestamp_us: WireTime((k * 40_000) as u32),
            rates_radps: [0.0; 3],
            attitude_rad: [0.0, 0.0, yaw as f32],
        };
        let out = ef.process(
            &frame,
            timebase::Instant::from_micros(k * 40_000),
            Some(&gyro),
        );
        if k >= 12 {
            worst_late = worst_late.max(out.forward_mps.abs().max(out.sideways_mps.abs()));
        }
    }
    println!("largest velocity output over frames 12-24, standing still: {worst_late:.3} m/s");
    assert!(
        worst_late < 0.1,
        "standing still, Edge-FS says {worst_late} m/s"
    );
}
