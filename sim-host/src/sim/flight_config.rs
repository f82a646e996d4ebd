//! What defines one closed-loop flight: the room, the seed, the sensors' and the drone's models,
//! the link faults and both boards' configurations.

use super::baro::BaroParams;
use super::battery::BatteryParams;
use super::camera::CameraParams;
use super::dynamics::DroneParams;
use super::imu::ImuParams;
use super::scene_spec::SceneSpec;
use super::uart::LinkFaults;
use autopilot::AutopilotConfig;
use stereo_board::edge_fs::EdgeFsParams;
use timebase::Duration;

/// Everything that defines a flight.
#[derive(Debug, Clone)]
pub struct FlightConfig {
    /// The room (a scene file or a preset, see [`SceneSpec`]).
    pub scene: SceneSpec,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Seed of every random process (textures, start heading, sensor noise, link faults).
    pub seed: u64,
    /// Start heading, rad; `None`: the scene's `start.yaw_deg`, else a heading drawn from the
    /// seed.
    pub start_yaw_rad: Option<f64>,
    /// Start position (x, y), m; `None`: the scene's start.
    pub start_xy: Option<[f64; 2]>,
    /// UART baud rate between the boards, bit/s.
    pub baud: u32,
    /// Faults on the camera-board -> autopilot direction.
    pub faults_s2a: LinkFaults,
    /// Faults on the autopilot -> camera-board direction.
    pub faults_a2s: LinkFaults,
    /// Camera.
    pub camera: CameraParams,
    /// Drone.
    pub drone: DroneParams,
    /// IMU.
    pub imu: ImuParams,
    /// Barometer.
    pub baro: BaroParams,
    /// Flight battery, its voltage read by the autopilot at
    /// the autopilot's telemetry task's rate (`None`: an ideal supply, no
    /// reading; the drone flies on its nominal thrust for ever).
    pub battery: Option<BatteryParams>,
    /// Camera readout time after exposure.
    pub readout: Duration,
    /// Camera-board processing time per frame (Edge-FS on the Cortex-M4): the estimate
    /// leaves this long after the frame is read out; frames arriving while busy are dropped.
    pub processing: Duration,
    /// Physics step (RK4).
    pub physics_dt: Duration,
    /// Motion capture: height fixes to the autopilot (the paper's lab). Without it the
    /// autopilot flies on its barometer and accelerometer.
    pub mocap: bool,
    /// Height measurement (motion capture) rate, Hz, and noise, m.
    pub height_rate_hz: f64,
    /// Height measurement noise (standard deviation), m.
    pub height_noise_m: f64,
    /// The telemetry link (host -> autopilot) is cut at this time, s: from then on nothing of
    /// the host reaches the autopilot (heartbeats, height fixes); `None`: never. The host
    /// sends its heartbeat once a second before that.
    pub host_link_cut_at_s: Option<f64>,
    /// Arm (take off) at this time, s. The autopilot calibrates its gyro on the ground first
    /// (256 still samples, 0.5 s), so this must be later than that.
    pub arm_at_s: f64,
    /// Keep one left camera image every this many frames for the GIF (0: none).
    pub keep_image_every: u32,
    /// Stop at the first collision.
    pub stop_on_collision: bool,
    /// Autopilot configuration (its FSM variant is the avoidance logic the flight flies).
    pub autopilot: AutopilotConfig,
    /// Edge-FS parameters of the camera board.
    pub edge_fs: EdgeFsParams,
}

impl Default for FlightConfig {
    fn default() -> Self {
        Self {
            scene: SceneSpec::preset("room").expect("the room preset"),
            duration_s: 120.0,
            seed: 1,
            start_yaw_rad: None,
            start_xy: None,
            baud: 115_200,
            faults_s2a: LinkFaults::default(),
            faults_a2s: LinkFaults::default(),
            camera: CameraParams::default(),
            drone: DroneParams::pocket_drone(),
            imu: ImuParams::default(),
            baro: BaroParams::default(),
            battery: None,
            readout: Duration::from_millis(8),
            processing: Duration::from_millis(15),
            physics_dt: Duration::from_micros(500),
            mocap: true,
            height_rate_hz: 100.0,
            height_noise_m: 0.003,
            host_link_cut_at_s: None,
            arm_at_s: 1.0,
            keep_image_every: 0,
            stop_on_collision: false,
            autopilot: AutopilotConfig::default(),
            edge_fs: EdgeFsParams::default_config(),
        }
    }
}
