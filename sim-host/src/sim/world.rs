//! The simulated world, built once the same way for `fly`, `hil` and the virtual boards'
//! closed loop: the scene, the drone on the floor at its start pose, its IMU and its stereo
//! camera, its barometer, the random processes seeded from the flight's seed, and the collision model.
//!
//! The caller owns time: it steps the physics between its events ([`World::step`]) and asks
//! the world for sensor data when its boards need them (IMU samples, rendered frames, height
//! fixes).

use super::baro::Barometer;
use super::battery::Battery;
use super::camera::{Motion, StereoCamera};
use super::dynamics::Drone;
use super::flight_config::FlightConfig;
use super::imu::{gauss, Imu, ImuReading};
use super::scene::Scene;
use autopilot::ms5611::BaroReading;
use protocol::{ExternalPosition, STEREO_FRAME_BYTES};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use timebase::WorldTime;

/// Height above which the drone counts as airborne for clearance and distance, m.
pub const AIRBORNE_M: f64 = 0.02;
/// The temperature the simulated barometer reports, °C: a room's.
const ROOM_TEMPERATURE_C: f32 = 24.0;
/// Floor of the hover command the barometer's thrust ratio is taken against, so that a
/// configured hover thrust of 0 does not divide by zero.
const MIN_HOVER_COMMAND: f64 = 0.05;
/// A contact ends once the clearance is back above this, m (so grazing counts once).
const CONTACT_RELEASE_M: f64 = 0.01;

/// The world of one flight.
pub struct World {
    /// The room.
    pub scene: Scene,
    /// The drone (true state).
    pub drone: Drone,
    /// Its IMU.
    pub imu: Imu,
    /// Its stereo camera.
    pub camera: StereoCamera,
    /// Its barometer.
    pub baro: Barometer,
    /// Its flight battery (`None`: an ideal supply at the nominal voltage).
    pub battery: Option<Battery>,
    /// Start position (x, y), m, and heading, rad.
    pub start: [f64; 3],
    /// Wall and obstacle contacts entered (the floor never counts).
    pub collisions: u32,
    /// Time of the first contact, s.
    pub first_contact_s: Option<f64>,
    /// Smallest clearance (to the drone's rotor tips) while airborne, m.
    pub min_clearance_m: f64,
    /// Horizontal distance flown while airborne, m.
    pub distance_m: f64,
    /// Time spent airborne, s.
    pub airborne_s: f64,
    in_contact: bool,
    height_noise_m: f64,
    hover_command: f64,
    rng: ChaCha8Rng,
    cam_rng: ChaCha8Rng,
}

/// The start heading of a flight: the configured one, else the scene's, else one drawn from
/// the seed (a golden-angle sequence, so consecutive seeds look in well-spread directions).
pub fn start_heading(cfg: &FlightConfig, scene: &Scene) -> f64 {
    cfg.start_yaw_rad
        .or(scene.start_yaw_rad.map(f64::from))
        .unwrap_or_else(|| (cfg.seed as f64 * 2.399_963).rem_euclid(std::f64::consts::TAU))
}

impl World {
    /// Builds the world `cfg` describes (scene textures, start heading, sensor noise all from
    /// `cfg.seed`).
    pub fn new(cfg: &FlightConfig) -> anyhow::Result<Self> {
        let scene = Scene::build(&cfg.scene, cfg.seed)?;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let cam_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xca3ea);
        let yaw0 = start_heading(cfg, &scene);
        let [x0, y0] = cfg
            .start_xy
            .unwrap_or([scene.start_xy[0] as f64, scene.start_xy[1] as f64]);
        let drone = Drone::on_floor(cfg.drone.clone(), x0, y0, yaw0);
        let imu = Imu::new(cfg.imu.clone(), &mut rng);
        let camera = StereoCamera::new(cfg.camera.clone());
        let baro = Barometer::new(cfg.baro.clone(), cfg.seed);
        Ok(Self {
            scene,
            drone,
            imu,
            camera,
            baro,
            battery: cfg.battery.map(Battery::new),
            start: [x0, y0, yaw0],
            collisions: 0,
            first_contact_s: None,
            min_clearance_m: f64::INFINITY,
            distance_m: 0.0,
            airborne_s: 0.0,
            in_contact: false,
            height_noise_m: cfg.height_noise_m,
            hover_command: f64::from(cfg.autopilot.height.hover_thrust).max(MIN_HOVER_COMMAND),
            rng,
            cam_rng,
        })
    }

    /// Integrates `dt` s with the motor commands `motors` (0..=1) ending at world time
    /// `t_end`, then resolves wall and obstacle contact: the drone is pushed out to the
    /// surface and loses its velocity into it. Returns whether it is in contact.
    pub fn step(&mut self, motors: &[f64; 4], dt: f64, t_end: WorldTime) -> bool {
        let before = self.drone.state.pos;
        match &mut self.battery {
            Some(battery) => {
                // The duty applies the battery's voltage to the motors.
                let k = battery.speed_factor();
                self.drone.step(&motors.map(|m| m * k), dt);
                battery.step(&self.drone.state.rotor_radps, &self.drone.params, dt);
            }
            None => self.drone.step(motors, dt),
        }
        self.imu.track(&self.drone, dt);
        let after = self.drone.state.pos;
        let h = -after.z;
        let c = self.clearance_m();
        if h > AIRBORNE_M {
            self.distance_m += (after.x - before.x).hypot(after.y - before.y);
            self.min_clearance_m = self.min_clearance_m.min(c);
            self.airborne_s += dt;
        }
        if c < 0.0 {
            if !self.in_contact {
                self.collisions += 1;
                self.first_contact_s.get_or_insert(t_end.as_secs_f64());
            }
            self.in_contact = true;
            let n = self
                .scene
                .push_out_dir(after.x as f32, after.y as f32, h as f32);
            let (nx, ny) = (n[0] as f64, n[1] as f64);
            let s = &mut self.drone.state;
            s.pos.x -= nx * c;
            s.pos.y -= ny * c;
            let vn = s.vel.x * nx + s.vel.y * ny;
            if vn < 0.0 {
                s.vel.x -= vn * nx;
                s.vel.y -= vn * ny;
            }
        } else if c > CONTACT_RELEASE_M {
            self.in_contact = false;
        }
        self.in_contact
    }

    /// Clearance from the drone's rotor tips to the nearest wall or obstacle, m.
    pub fn clearance_m(&self) -> f64 {
        let p = self.drone.state.pos;
        self.scene.clearance(p.x as f32, p.y as f32, -p.z as f32) as f64
            - self.drone.params.radius_m
    }

    /// The IMU's next sample (call at its sample rate).
    pub fn imu_sample(&mut self) -> ImuReading {
        self.imu.sample(&mut self.rng)
    }

    /// Renders the stereo frame exposed now (centred on now, blurred by the drone's motion).
    pub fn render(&mut self, out: &mut [u8; STEREO_FRAME_BYTES]) {
        let s = &self.drone.state;
        let motion = Motion {
            vel: s.vel,
            rates: s.rates,
        };
        self.camera
            .render_moving(&self.scene, s.pos, s.att, motion, &mut self.cam_rng, out);
    }

    /// A barometer reading at `t` with the rotors at `motors` (0..=1).
    pub fn baro_reading(&mut self, t: WorldTime, motors: &[f64; 4]) -> BaroReading {
        let thrust_ratio = motors.iter().sum::<f64>() / 4.0 / self.hover_command;
        let height = -self.drone.state.pos.z;
        BaroReading {
            pressure_pa: self.baro.read(t.as_secs_f64(), height, thrust_ratio) as f32,
            temperature_c: ROOM_TEMPERATURE_C,
        }
    }

    /// A height fix (the motion capture's position, with its noise on z) at `t`.
    pub fn height_fix(&mut self, t: WorldTime) -> ExternalPosition {
        let p = self.drone.state.pos;
        let z = p.z + gauss(&mut self.rng) * self.height_noise_m;
        ExternalPosition {
            timestamp_us: t.to_wire(),
            position_m: [p.x as f32, p.y as f32, z as f32],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene_spec::SceneSpec;

    #[test]
    fn start_heading_from_config_scene_or_seed() {
        let room = FlightConfig::default();
        let a = World::new(&FlightConfig {
            seed: 1,
            ..room.clone()
        })
        .unwrap();
        let b = World::new(&FlightConfig {
            seed: 2,
            ..room.clone()
        })
        .unwrap();
        assert!(
            (a.start[2] - b.start[2]).abs() > 0.1,
            "seeded headings differ"
        );
        let corridor = FlightConfig {
            scene: SceneSpec::preset("corridor").unwrap(),
            ..room.clone()
        };
        assert_eq!(World::new(&corridor).unwrap().start[2], 0.0);
        let fixed = FlightConfig {
            start_yaw_rad: Some(1.0),
            start_xy: Some([1.0, 3.0]),
            ..room
        };
        let w = World::new(&fixed).unwrap();
        assert_eq!(w.start, [1.0, 3.0, 1.0]);
    }

    #[test]
    fn wall_contact_counts_once_and_pushes_out() {
        let mut w = World::new(&FlightConfig::default()).unwrap();
        let r = w.drone.params.radius_m;
        w.drone.state.pos.x = 4.0 - r + 0.05; // 5 cm into the north wall, on the floor
        w.drone.state.vel.x = 1.0;
        let hover = [w.drone.params.hover_throttle(); 4];
        assert!(w.step(&hover, 1e-3, WorldTime::from_micros(1_000)));
        assert!(w.clearance_m() >= -1e-6);
        assert!(
            w.drone.state.vel.x <= 1e-9,
            "velocity into the wall removed"
        );
        assert!(w.step(&hover, 1e-3, WorldTime::from_micros(2_000)));
        assert_eq!(w.collisions, 1);
        assert_eq!(w.first_contact_s, Some(1e-3));
    }
}
