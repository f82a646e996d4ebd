//! The simulator's stereo camera against geometry, measured with the camera board's own
//! Edge-FS: facing a wall, the per-column disparity matches f*b/Z and the obstacle distance
//! matches Z; moving towards it, the forward velocity is recovered.

use protocol::STEREO_FRAME_BYTES;
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
            out = Some(ef.process(&frame, k * 40_000, None));
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
        let o = ef.process(&frame, k * 40_000, None);
        if k >= 15 && o.flags.0 & !protocol::EstimateFlags::NO_GYRO.0 == 0 {
            est.push(o.forward_mps);
        }
    }
    assert!(est.len() > 10, "{} valid estimates", est.len());
    let m = median(est);
    println!("forward 0.3 m/s: median estimate {m:.3} m/s");
    assert!((m - 0.3).abs() < 0.1, "median forward estimate {m}");
}
