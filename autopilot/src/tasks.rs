//! The autopilot's tasks: their periods and the task table the firmware's RTIC app mirrors
//! and the simulator schedules from.

pub use task_table::{TaskId, TaskSpec, Trigger};
use timebase::Duration;

/// IMU / INDI period: 512 Hz (rounded down to a microsecond).
pub const IMU_PERIOD: Duration = Duration::from_hz(512);
/// Guidance (FSM, force field, velocity and height loops) period: 50 Hz.
pub const GUIDANCE_PERIOD: Duration = Duration::from_hz(50);
/// Gyro/attitude message to the camera board: 128 Hz (every 4th IMU sample).
pub const GYRO_TX_PERIOD: Duration = Duration::from_hz(128);
/// Telemetry period: 10 Hz.
pub const TELEMETRY_PERIOD: Duration = Duration::from_hz(10);
/// Heartbeat period: 1 Hz.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_hz(1);

/// The autopilot's tasks, in [`TASKS`]'s order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Task {
    /// 512 Hz: IMU sample, attitude, INDI, mixer.
    ImuIndi,
    /// Bytes from the camera board.
    StereoRx,
    /// Bytes from the host (telemetry link).
    HostRx,
    /// 50 Hz: failsafes, avoidance, velocity and height loops.
    Guidance,
    /// 128 Hz: gyro and attitude to the camera board.
    GyroTx,
    /// 10 Hz: battery voltage, telemetry to the host.
    Telemetry,
    /// 1 Hz: heartbeats to both links.
    Heartbeat,
}

impl TaskId for Task {
    const ALL: &'static [Task] = &[
        Task::ImuIndi,
        Task::StereoRx,
        Task::HostRx,
        Task::Guidance,
        Task::GyroTx,
        Task::Telemetry,
        Task::Heartbeat,
    ];
    const TABLE: &'static [TaskSpec<Task>] = TASKS;

    fn index(self) -> usize {
        self as usize
    }
}

/// The autopilot's task table. The firmware's RTIC app mirrors it; `sim-host` schedules from it.
///
/// | task | calls |
/// |---|---|
/// | `imu_indi` | [`crate::Autopilot::on_imu`], motors written from its result |
/// | `stereo_rx` | [`crate::Autopilot::on_estimate`] for each decoded estimate |
/// | `host_rx` | [`crate::Autopilot::on_host_message`] (HIL: then `on_imu` on the samples it hands back) |
/// | `guidance` | [`crate::Autopilot::guidance_step`], then [`crate::Autopilot::motor_safety`] |
/// | `gyro_tx` | [`crate::Autopilot::gyro_attitude`] encoded to the camera board |
/// | `telemetry` | [`crate::Autopilot::telemetry_task`] (battery voltage in, telemetry encoded to the host) |
/// | `heartbeat` | a `protocol::Heartbeat` to both links |
pub const TASKS: &[TaskSpec<Task>] = &[
    TaskSpec {
        id: Task::ImuIndi,
        name: "imu_indi",
        priority: 5,
        trigger: Trigger::Periodic { period: IMU_PERIOD },
        deadline: Duration::from_micros(500),
    },
    TaskSpec {
        id: Task::StereoRx,
        name: "stereo_rx",
        priority: 4,
        trigger: Trigger::Event("bytes from the camera-board link (USART2), RXNE"),
        deadline: Duration::from_millis(1),
    },
    TaskSpec {
        id: Task::HostRx,
        name: "host_rx",
        priority: 4,
        trigger: Trigger::Event("bytes from the telemetry / host link (USART1), RXNE"),
        deadline: Duration::from_millis(1),
    },
    TaskSpec {
        id: Task::Guidance,
        name: "guidance",
        priority: 3,
        trigger: Trigger::Periodic {
            period: GUIDANCE_PERIOD,
        },
        deadline: Duration::from_millis(5),
    },
    TaskSpec {
        id: Task::GyroTx,
        name: "gyro_tx",
        priority: 2,
        trigger: Trigger::Periodic {
            period: GYRO_TX_PERIOD,
        },
        deadline: GYRO_TX_PERIOD,
    },
    TaskSpec {
        id: Task::Telemetry,
        name: "telemetry",
        priority: 1,
        trigger: Trigger::Periodic {
            period: TELEMETRY_PERIOD,
        },
        deadline: TELEMETRY_PERIOD,
    },
    TaskSpec {
        id: Task::Heartbeat,
        name: "heartbeat",
        priority: 1,
        trigger: Trigger::Periodic {
            period: HEARTBEAT_PERIOD,
        },
        deadline: HEARTBEAT_PERIOD,
    },
];
