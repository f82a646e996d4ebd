//! Edge-FS's time to contact (the divergence of the flow) on the simulator's calibrated camera,
//! against the geometry: approaching a textured wall it matches distance over speed, also where
//! the wall is nearer than the stereo search reaches; flying along a wall it reports no
//! approach.

use integration_tests::StraightFlight;
use protocol::Divergence;
use sim_host::sim::camera::CameraParams;
use sim_host::sim::math::V3;
use sim_host::sim::scene::Scene;
use stereo_board::edge_fs::{EdgeFsOutput, EdgeFsParams};

/// One frame of a straight flight: the camera's true distance to the surface straight ahead,
/// m, and Edge-FS's output.
struct Sample {
    ahead_m: f32,
    out: EdgeFsOutput,
}

/// Flies the camera from `start` along the heading `yaw_deg` with velocity `vel` (world frame,
/// m/s) for up to `frames` frames at 25 fps, stopping `stop_m` before the surface ahead.
fn fly(scene: &Scene, start: V3, yaw_deg: f64, vel: V3, frames: u64, stop_m: f32) -> Vec<Sample> {
    let camera = CameraParams::default();
    let lens_offset = camera.forward_offset_m;
    let yaw = yaw_deg.to_radians();
    let mut flight = StraightFlight::new(camera, EdgeFsParams::default_config(), yaw, vel, 7);
    let dir = [yaw.cos() as f32, yaw.sin() as f32, 0.0];
    let mut samples = Vec::new();
    for k in 0..frames {
        let pos = start + vel * (k as f64 * 0.04);
        let lens = [
            pos.x as f32 + dir[0] * lens_offset,
            pos.y as f32 + dir[1] * lens_offset,
            pos.z as f32,
        ];
        let (_, ahead_m) = scene.trace(lens, dir);
        if ahead_m < stop_m {
            break;
        }
        let out = flight.frame(scene, pos, k);
        samples.push(Sample { ahead_m, out });
    }
    samples
}

fn median(mut v: Vec<f32>) -> f32 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// The relative errors of the time to contact against `ahead / speed` over the samples with
/// a divergence whose surface ahead lies in `range` (m).
fn ttc_errors(samples: &[Sample], speed: f32, range: std::ops::Range<f32>) -> (Vec<f32>, usize) {
    let in_range: Vec<&Sample> = samples
        .iter()
        .skip(10) // the flow history fills
        .filter(|s| range.contains(&s.ahead_m))
        .collect();
    let errors = in_range
        .iter()
        .filter_map(|s| {
            let t = s.out.divergence.and_then(|d| d.time_to_contact_s())?;
            Some(t / (s.ahead_m / speed) - 1.0)
        })
        .collect();
    (errors, in_range.len())
}

#[test]
fn approaching_a_wall_the_time_to_contact_is_distance_over_speed() {
    let speed = 0.4f32;
    for seed in [4u64, 11] {
        let scene = Scene::preset("room", seed).unwrap();
        // From the room's centre towards the north wall (x = 4 m) at 1 m height.
        let samples = fly(
            &scene,
            V3::new(1.2, 2.0, -1.0),
            0.0,
            V3::new(f64::from(speed), 0.0, 0.0),
            200,
            0.25,
        );
        let (far, far_frames) = ttc_errors(&samples, speed, 0.8..2.4);
        // Nearer than the stereo search reaches (about 0.5 m): the obstacle distance is
        // missing or wrong, the time to contact is not.
        let near_range = 0.34..0.48;
        let (near, near_frames) = ttc_errors(&samples, speed, near_range.clone());
        let near_without_stereo = samples
            .iter()
            .filter(|s| near_range.contains(&s.ahead_m) && s.out.divergence.is_some())
            .filter(|s| s.out.obstacle_m.is_none_or(|d| d > 1.2 * s.ahead_m))
            .count();
        let (mf, mn) = (median(far.clone()), median(near.clone()));
        println!(
            "seed {seed}: 0.8-2.4 m: {}/{far_frames} frames with a time to contact, median error \
             {:+.0} %; 0.34-0.48 m: {}/{near_frames}, median error {:+.0} %, {near_without_stereo} \
             of them without a stereo distance to the wall",
            far.len(),
            100.0 * mf,
            near.len(),
            100.0 * mn
        );
        // Measured (texture seeds 4 and 11, not used to choose anything): every frame, median
        // errors 0 % and 0 % at 0.8-2.4 m; +4 % and +30 % at 0.34-0.48 m, where the outer
        // columns' flow starts to leave the search and the time reads long.
        assert!(
            far.len() * 10 >= far_frames * 9,
            "{}/{far_frames}",
            far.len()
        );
        assert!(mf.abs() < 0.2, "median relative error {mf} at 0.8-2.4 m");
        assert!(
            near.len() * 10 >= near_frames * 8,
            "{}/{near_frames}",
            near.len()
        );
        assert!(mn.abs() < 0.4, "median relative error {mn} at 0.34-0.48 m");
        assert!(
            near_without_stereo * 2 >= near_frames,
            "{near_without_stereo}/{near_frames} near frames without a stereo distance"
        );
    }
}

#[test]
fn flying_along_a_wall_there_is_no_approach() {
    let scene = Scene::preset("room", 4).unwrap();
    // Facing the north wall 1.5 m away, sliding east at 0.4 m/s.
    let samples = fly(
        &scene,
        V3::new(2.5, 0.8, -1.0),
        0.0,
        V3::new(0.0, 0.4, 0.0),
        60,
        0.0,
    );
    let rates: Vec<Divergence> = samples
        .iter()
        .skip(10)
        .filter_map(|s| s.out.divergence)
        .collect();
    assert!(rates.len() > 40, "{} frames with a divergence", rates.len());
    let m = median(rates.iter().map(|d| d.rate_hz).collect());
    let approaching = rates
        .iter()
        .filter(|d| d.time_to_contact_within_s(-3.0).is_some_and(|t| t < 5.0))
        .count();
    println!(
        "sliding along a wall: median divergence {m:+.3} 1/s, {approaching}/{} frames confidently \
         under 5 s to contact",
        rates.len()
    );
    // Approaching the wall at 0.4 m/s from 1.5 m would be 0.27 1/s.
    assert!(m.abs() < 0.05, "median divergence {m}");
    assert!(approaching * 20 <= rates.len(), "{approaching} frames");
}
