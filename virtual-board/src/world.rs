//! The simulator's world on the virtual boards: sim-host's [`World`] (its 6-DOF dynamics, motors,
//! barometer, scene and stereo renderer, the same one `fly` and `hil` fly in) stepped in
//! virtual time in lockstep with the emulated boards.
//!
//! * [`Plant`] is the world as the autopilot board feels it. At every bench stop of the
//!   autopilot it integrates the world from the previous stop to this one with the four motor
//!   duties the PWM outputs showed at the previous stop (zero-order hold over one quantum,
//!   RK4 in steps of at most [`FlightConfig::physics_dt`]), then puts the new state on the
//!   chips: the true body rates and specific force on the MPU-6000
//!   ([`Autopilot::set_body_rate`], [`Autopilot::set_body_specific_force`]: the board's axis
//!   map and mounting, the chip's own scaling, noise and offset), the pressure of sim-host's
//!   barometer model (ISA, noise, drift, rotor wash) on the MS5611 (whole pascals, as the
//!   model takes it), and reads the duties for the next quantum. Duties are the throttles the
//!   dynamics take: the firmware writes `throttle * ARR` to each channel.
//! * [`Poses`] carries the drone's state from the autopilot's thread to the camera board's:
//!   one entry per quantum, published before the autopilot waits at that quantum's barrier.
//! * [`Rendered`] is the camera board's [`FrameSource`]: sim-host's renderer (its own copy of
//!   the scene and camera, its own noise generator) seen from the pose of the quantum before
//!   the one a frame starts in, the newest the lockstep guarantees is published, so the same
//!   run renders the same frames whatever the threads do (at most two quanta old).
//! * [`TruthCamera`] is the host playing the camera board for autopilot-only runs: it sends
//!   over the link what the camera board sends (a 1 Hz heartbeat, an estimate per frame), the
//!   estimates made from the world's true body velocity plus noise, not from images.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use protocol::{Estimate, EstimateFlags, FrameFit, Heartbeat, Message, Node, StereoToAutopilot};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::SeedableRng;
use sim_host::sim::camera::{Motion, StereoCamera};
use sim_host::sim::dynamics::DroneState;
use sim_host::sim::imu::gauss;
use sim_host::sim::math::V3;
use sim_host::sim::scene::Scene;
use sim_host::sim::world::World;
use timebase::WorldTime;

pub use sim_host::sim::flight::FlightConfig;

use crate::boards::autopilot::Autopilot;
use crate::frames::{FrameSource, STEREO_BYTES, StereoImage};
use crate::link::Line;
use crate::pilot::{Every, MS};

/// One sample of the world's truth, taken at a bench stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Virtual time, ns.
    pub at_ns: u64,
    /// The drone's state then.
    pub state: DroneState,
    /// The motor duties the world flew on up to then (FR, RR, RL, FL), 0..=1.
    pub duties: [f64; 4],
}

impl Truth {
    /// Height above the floor, m.
    #[must_use]
    pub fn height_m(&self) -> f64 {
        -self.state.pos.z
    }

    /// Roll, pitch, yaw, rad.
    #[must_use]
    pub fn euler(&self) -> [f64; 3] {
        let (roll, pitch, yaw) = self.state.att.to_euler();
        [roll, pitch, yaw]
    }

    /// The velocity in body axes (x forward, y right, z down), m/s.
    #[must_use]
    pub fn body_velocity(&self) -> V3 {
        self.state.att.rotate_inv(self.state.vel)
    }
}

/// The world as the autopilot board feels it (see the module docs).
pub struct Plant {
    world: World,
    cfg: FlightConfig,
    duties: [f64; 4],
    last_ns: Option<u64>,
    poses: Poses,
    trace: Vec<Truth>,
    trace_every: Every,
}

impl Plant {
    /// The world `cfg` describes (scene, start pose, drone, barometer, seeds), its poses
    /// published per `quantum_ns` (the bench's lockstep quantum).
    ///
    /// # Errors
    /// The scene cannot be built.
    pub fn new(cfg: &FlightConfig, quantum_ns: u64) -> Result<Self, String> {
        let world = World::new(cfg).map_err(|e| format!("the world: {e:#}"))?;
        let poses = Poses::new(quantum_ns, world.drone.state);
        Ok(Self {
            world,
            cfg: cfg.clone(),
            duties: [0.0; 4],
            last_ns: None,
            poses,
            trace: Vec::new(),
            trace_every: Every::ns(MS),
        })
    }

    /// The world.
    #[must_use]
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The world, mutably (a test moves the drone or the scene).
    pub fn world_mut(&mut self) -> &mut World {
        &mut self.world
    }

    /// Its configuration.
    #[must_use]
    pub fn config(&self) -> &FlightConfig {
        &self.cfg
    }

    /// The duties the world flies on until the next stop (FR, RR, RL, FL), 0..=1.
    #[must_use]
    pub fn duties(&self) -> [f64; 4] {
        self.duties
    }

    /// The pose history the camera board renders from ([`Rendered`]).
    #[must_use]
    pub fn poses(&self) -> Poses {
        self.poses.clone()
    }

    /// The truth at every stop the trace kept (every millisecond at most), oldest first.
    #[must_use]
    pub fn trace(&self) -> &[Truth] {
        &self.trace
    }

    /// The truth now.
    #[must_use]
    pub fn truth(&self, now_ns: u64) -> Truth {
        Truth {
            at_ns: now_ns,
            state: self.world.drone.state,
            duties: self.duties,
        }
    }

    /// The world's renderer seen from the world's start, for a camera board in the same world
    /// (call before the run; the frames follow [`Plant::poses`]).
    #[must_use]
    pub fn rendered(&self) -> Rendered {
        Rendered::new(
            self.world.scene.clone(),
            self.world.camera.clone(),
            self.cfg.seed,
            self.poses(),
        )
    }

    /// At a stop of the autopilot (`now_ns`): the world moves on to `now_ns` with the duties of
    /// the previous stop, the chips get its new state, and the duties are read for the next
    /// quantum. Call at every stop, before the probe reads or sends anything.
    pub fn step(&mut self, now_ns: u64, board: &mut Autopilot) {
        if let Some(last) = self.last_ns {
            let physics_ns = self.cfg.physics_dt.as_micros().max(1) * 1_000;
            let mut t = last;
            while t < now_ns {
                let next = (t + physics_ns).min(now_ns);
                self.world.step(
                    &self.duties,
                    (next - t) as f64 * 1e-9,
                    WorldTime::from_micros(next / 1_000),
                );
                t = next;
            }
        }
        self.last_ns = Some(now_ns);
        let drone = &self.world.drone;
        let rates = drone.state.rates;
        let force = drone.specific_force_body;
        board.set_body_rate([rates.x, rates.y, rates.z]);
        board.set_body_specific_force([force.x, force.y, force.z]);
        let reading = self
            .world
            .baro_reading(WorldTime::from_micros(now_ns / 1_000), &self.duties);
        let baro = board.baro();
        baro.set_pressure(f64::from(reading.pressure_pa).round().max(0.0) as u32);
        baro.set_temperature((f64::from(reading.temperature_c) * 100.0).round() as i32);
        if self.trace_every.due(now_ns) {
            let truth = self.truth(now_ns);
            self.trace.push(truth);
        }
        self.duties = board.duties_in_mixer_order();
        self.poses.publish(now_ns, self.world.drone.state);
    }
}

/// The drone's state per lockstep quantum, shared between the autopilot's thread (which
/// publishes) and the camera board's (which renders).
#[derive(Debug, Clone)]
pub struct Poses(Arc<Mutex<PoseLog>>);

#[derive(Debug)]
struct PoseLog {
    quantum_ns: u64,
    initial: DroneState,
    /// (quantum index, state), oldest first.
    entries: VecDeque<(u64, DroneState)>,
}

/// Quanta of poses kept: the camera board reads one or two quanta back.
const POSES_KEPT: usize = 64;

impl Poses {
    /// Starts at `initial`, one entry per `quantum_ns`.
    #[must_use]
    pub fn new(quantum_ns: u64, initial: DroneState) -> Self {
        Self(Arc::new(Mutex::new(PoseLog {
            quantum_ns: quantum_ns.max(1),
            initial,
            entries: VecDeque::new(),
        })))
    }

    /// The state at the stop at `now_ns` (the last publication in a quantum wins).
    pub fn publish(&self, now_ns: u64, state: DroneState) {
        let mut log = self.0.lock().expect("poses lock");
        let index = now_ns / log.quantum_ns;
        if log.entries.back().is_some_and(|(i, _)| *i == index) {
            log.entries.pop_back();
        }
        log.entries.push_back((index, state));
        while log.entries.len() > POSES_KEPT {
            log.entries.pop_front();
        }
    }

    /// The state a board at `now_ns` may see: the one published in the quantum before the
    /// current one (or the latest before it, or the initial one). The other board has passed
    /// that quantum's barrier, so the answer does not depend on thread timing.
    #[must_use]
    pub fn seen_at(&self, now_ns: u64) -> DroneState {
        let log = self.0.lock().expect("poses lock");
        let Some(wanted) = (now_ns / log.quantum_ns).checked_sub(1) else {
            return log.initial;
        };
        log.entries
            .iter()
            .rev()
            .find(|(index, _)| *index <= wanted)
            .map_or(log.initial, |(_, state)| *state)
    }
}

/// The camera board's frames rendered from the world (see the module docs).
pub struct Rendered {
    scene: Scene,
    camera: StereoCamera,
    rng: ChaCha8Rng,
    poses: Poses,
    rendered: u64,
}

impl std::fmt::Debug for Rendered {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rendered")
            .field("rendered", &self.rendered)
            .finish_non_exhaustive()
    }
}

impl Rendered {
    /// Renders `scene` through `camera` from the poses in `poses`, its noise drawn from `seed`.
    #[must_use]
    pub fn new(scene: Scene, camera: StereoCamera, seed: u64, poses: Poses) -> Self {
        Self {
            scene,
            camera,
            // The world's own camera generator's seed (sim-host `World::new`).
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xca3ea),
            poses,
            rendered: 0,
        }
    }

    /// Frames rendered so far.
    #[must_use]
    pub fn rendered(&self) -> u64 {
        self.rendered
    }
}

impl FrameSource for Rendered {
    fn frame(&mut self, _index: u64, start_ns: u64) -> Option<StereoImage> {
        let state = self.poses.seen_at(start_ns);
        let motion = Motion {
            vel: state.vel,
            rates: state.rates,
        };
        let mut frame = Box::new([0u8; STEREO_BYTES]);
        self.camera.render_moving(
            &self.scene,
            state.pos,
            state.att,
            motion,
            &mut self.rng,
            &mut frame,
        );
        self.rendered += 1;
        Some(StereoImage::from_interleaved(&frame))
    }
}

/// How far the [`TruthCamera`] sees an obstacle, m (within the reach of Edge-FS's stereo).
pub const TRUTH_RANGE_M: f32 = 5.0;

/// The host playing the camera board on an autopilot-only bench, from the world's truth: what
/// the camera board sends over the link (a heartbeat a second, an estimate per frame), each
/// estimate the world's true body velocity averaged over the autopilot's flow horizon before
/// the frame's capture, plus white noise, sent its processing time after the capture; the
/// nearest surface straight ahead (the scene's, along the heading at the drone's height) is
/// the obstacle when it is within [`TRUTH_RANGE_M`], with depth over the whole view. Not
/// Edge-FS: a stand-in, so the autopilot can fly the world without the camera board.
pub struct TruthCamera {
    frames: Every,
    heartbeats: Every,
    noise_mps: f64,
    processing_ns: u64,
    horizon_ns: u64,
    rng: ChaCha8Rng,
    seq: u16,
    pending: VecDeque<(u64, Estimate)>,
    sent: u32,
}

impl TruthCamera {
    /// Estimates at `fps` with `noise_mps` of white noise (1 sigma, each axis), each leaving
    /// `processing_ms` after its capture, averaged over `horizon_us` (the autopilot's
    /// `estimate_horizon`), noise drawn from `seed`.
    #[must_use]
    pub fn new(fps: f64, noise_mps: f64, processing_ms: u64, horizon_us: u64, seed: u64) -> Self {
        Self {
            frames: Every::ns((1e9 / fps.max(1e-3)) as u64),
            heartbeats: Every::ns(1_000 * MS),
            noise_mps,
            processing_ns: processing_ms * MS,
            horizon_ns: horizon_us * 1_000,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x7c4a),
            seq: 0,
            pending: VecDeque::new(),
            sent: 0,
        }
    }

    /// Estimates sent so far.
    #[must_use]
    pub fn sent(&self) -> u32 {
        self.sent
    }

    /// At every stop: captures a frame when one is due (from `plant`'s truth) and sends on
    /// `link` (the line the autopilot hears) what is due.
    pub fn step(&mut self, now_ns: u64, plant: &Plant, link: &Line) {
        let mut buffer = [0u8; StereoToAutopilot::MAX_FRAME_BYTES];
        let mut send = |message: &StereoToAutopilot| {
            if let Ok(n) = protocol::encode(message, &mut buffer) {
                link.send_at(now_ns, &buffer[..n]);
            }
        };
        if self.heartbeats.due(now_ns) {
            send(&StereoToAutopilot::Heartbeat(Heartbeat::new(
                Node::StereoBoard,
                (now_ns / MS) as u32,
            )));
        }
        if self.frames.due(now_ns) {
            let from = now_ns.saturating_sub(self.horizon_ns);
            let window: Vec<V3> = plant
                .trace()
                .iter()
                .rev()
                .take_while(|t| t.at_ns >= from)
                .map(Truth::body_velocity)
                .collect();
            let n = window.len().max(1) as f64;
            let mean = window.iter().fold(V3::ZERO, |a, &v| a + v) * (1.0 / n);
            self.seq = self.seq.wrapping_add(1);
            let forward_mps = (mean.x + gauss(&mut self.rng) * self.noise_mps) as f32;
            let sideways_mps = (mean.y + gauss(&mut self.rng) * self.noise_mps) as f32;
            let world = plant.world();
            let state = world.drone.state;
            let (_, _, yaw) = state.att.to_euler();
            let ahead = [yaw.cos() as f32, yaw.sin() as f32, 0.0];
            let (distance_m, _) = world.scene.intersect(state.pos.to_f32(), ahead);
            let estimate = Estimate {
                seq: self.seq,
                capture_us: protocol::WireTime((now_ns / 1_000) as u32),
                forward_mps,
                sideways_mps,
                obstacle_m: (distance_m <= TRUTH_RANGE_M).then_some(distance_m),
                quality: 200,
                flags: EstimateFlags::NONE,
                processing_us: u16::try_from(self.processing_ns / 1_000).unwrap_or(u16::MAX),
                // Depth over the whole view: what is not an obstacle is known to be clear.
                depth_coverage: u8::MAX,
                near_columns: 0,
                // The labelled mean over the window is this frame's own "fit".
                fit: Some(FrameFit {
                    forward_mps,
                    sideways_mps,
                    quality: 200,
                }),
                up_mps: 0.0,
                up_flags: EstimateFlags::NO_FLOW_MATCH,
                fit_r2: 0,
                divergence: None,
            };
            self.pending
                .push_back((now_ns + self.processing_ns, estimate));
        }
        while self.pending.front().is_some_and(|(at, _)| *at <= now_ns) {
            if let Some((_, estimate)) = self.pending.pop_front() {
                send(&StereoToAutopilot::Estimate(estimate));
                self.sent += 1;
            }
        }
    }
}
