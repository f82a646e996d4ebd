//! Shared helpers for the cross-crate integration tests in `tests/tests/integration/`.

use autopilot::fsm::FsmVariant;
use protocol::{GyroAttitude, WireTime, STEREO_FRAME_BYTES};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim_host::sim::camera::{CameraParams, Motion, StereoCamera};
use sim_host::sim::flight::{run_flight, FlightConfig, FlightResult};
use sim_host::sim::math::{Quat, V3};
use sim_host::sim::scene::Scene;
use std::path::PathBuf;
use stereo_board::edge_fs::{EdgeFs, EdgeFsOutput, EdgeFsParams};

/// Path of the shared recorded data set used by tests and CI (`../shared/data/stereoboard_testing`
/// beside the checkout). The product itself never assumes this path.
pub fn shared_dataset_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/stereoboard_testing")
}

/// A camera flying straight at a constant velocity and heading (no rotation), each frame
/// rendered by the simulator's camera and processed by the camera board's Edge-FS with a level
/// gyro and attitude sample, at 25 fps.
pub struct StraightFlight {
    camera: StereoCamera,
    rng: ChaCha8Rng,
    frame: Box<[u8; STEREO_FRAME_BYTES]>,
    edge_fs: Box<EdgeFs>,
    yaw_rad: f64,
    velocity: V3,
}

impl StraightFlight {
    /// Frame period, µs (25 fps).
    pub const FRAME_US: u64 = 40_000;

    /// A flight of `camera` along the heading `yaw_rad` at `velocity` (world frame, m/s), its
    /// noise from `seed`, processed with `params`.
    pub fn new(
        camera: CameraParams,
        params: EdgeFsParams,
        yaw_rad: f64,
        velocity: V3,
        seed: u64,
    ) -> Self {
        Self {
            camera: StereoCamera::new(camera),
            rng: ChaCha8Rng::seed_from_u64(seed),
            frame: Box::new([0; STEREO_FRAME_BYTES]),
            edge_fs: Box::new(EdgeFs::new(params)),
            yaw_rad,
            velocity,
        }
    }

    /// Frame `k` (at `k` frame periods), taken at `pos`: Edge-FS's output.
    pub fn frame(&mut self, scene: &Scene, pos: V3, k: u64) -> EdgeFsOutput {
        let motion = Motion {
            vel: self.velocity,
            rates: V3::new(0.0, 0.0, 0.0),
        };
        let att = Quat::from_euler(0.0, 0.0, self.yaw_rad);
        self.camera
            .render_moving(scene, pos, att, motion, &mut self.rng, &mut self.frame);
        let t_us = k * Self::FRAME_US;
        let gyro = GyroAttitude {
            timestamp_us: WireTime(t_us as u32),
            rates_radps: [0.0; 3],
            attitude_rad: [0.0, 0.0, self.yaw_rad as f32],
        };
        self.edge_fs.process(
            &self.frame,
            timebase::Instant::from_micros(t_us),
            Some(&gyro),
        )
    }
}

/// Flies every configuration, each on a thread of its own, and returns the results in the
/// configurations' order. A flight depends only on its configuration and seed, so flying them
/// side by side gives the results flying them one after the other gives, on every core there is.
pub fn fly_all(configs: &[FlightConfig]) -> Vec<FlightResult> {
    std::thread::scope(|scope| {
        let flights: Vec<_> = configs
            .iter()
            .map(|cfg| scope.spawn(move || run_flight(cfg, &mut |_| {}).expect("flight runs")))
            .collect();
        flights
            .into_iter()
            .map(|flight| flight.join().expect("a flight does not panic"))
            .collect()
    })
}

/// Flies `base(seed)` for every seed of `seeds` with each avoidance FSM (the paper's, then
/// turn until clear), side by side ([`fly_all`]); returns each flight's FSM, seed and result.
pub fn fly_both_fsms(
    seeds: impl Iterator<Item = u64> + Clone,
    base: impl Fn(u64) -> FlightConfig,
) -> Vec<(FsmVariant, u64, FlightResult)> {
    let flights: Vec<(FsmVariant, u64)> = [FsmVariant::Paper, FsmVariant::TurnUntilClear]
        .into_iter()
        .flat_map(|fsm| seeds.clone().map(move |seed| (fsm, seed)))
        .collect();
    let configs: Vec<FlightConfig> = flights
        .iter()
        .map(|&(fsm, seed)| {
            let mut cfg = base(seed);
            cfg.autopilot.fsm.variant = fsm;
            cfg
        })
        .collect();
    flights
        .into_iter()
        .zip(fly_all(&configs))
        .map(|((fsm, seed), r)| (fsm, seed, r))
        .collect()
}
