//! Hardware-in-the-loop: the world simulation of [`crate::sim`] flown by the two boards'
//! lockstep firmwares (the `hil` flavour; the `qemu` flavour in QEMU) over byte streams, one
//! per board's host UART.
//!
//! ```text
//!   sim-host hil                  camera board                         autopilot
//!   world: dynamics, IMU, scene  --FrameChunk--> host UART   host UART <--Imu, ExternalPosition, Command--
//!   camera renderer              <--Estimate----             (USART1)  --Motors, Telemetry, Heartbeat-->
//!                                                link UART <-------> link UART
//! ```
//!
//! The same contract, wherever the boards are:
//!
//! * real boards: each host UART on its own USB-serial adapter (`--stereo /dev/ttyUSB0
//!   --autopilot /dev/ttyUSB1`, 921,600 Bd), the link UARTs wired to each other as in the drone;
//! * the virtual boards (`virtual-board/`, `vboard serve hil`): both `hil` images on emulated
//!   STM32F4s, the link UARTs joined on the bench, each host UART on a TCP socket
//!   (`--stereo tcp:127.0.0.1:4011 --autopilot tcp:127.0.0.1:4012`); `docs/virtual-board.md`;
//! * QEMU (the `qemu` flavour): each host UART on a `-chardev socket`, the link UARTs joined
//!   directly or relayed through this host ([`Relay`]).
//!
//! The camera board's host UART is its second UART, USART2 (PA2/PA3; USART2 in QEMU too), its
//! link UART4 (USART1 in QEMU); the autopilot's host UART is its telemetry port USART1, its link
//! USART2.
//!
//! # Timing: lockstep on world time
//!
//! The boards run on the world's clock, not their own (see `autopilot::lockstep` and the
//! camera board firmware's clock module); only the time source and the sensor transport differ
//! from the real flavour, the flight code is the same.
//!
//! * IMU: every IMU period (512 Hz of world time) the host sends one `ImuSample` stamped with
//!   the world time and waits for the autopilot's `Motors` reply carrying the same timestamp;
//!   only then does it integrate the world one IMU period with those motor commands. The
//!   autopilot releases guidance (50 Hz), gyro-to-camera (128 Hz) and telemetry (10 Hz) from
//!   the same world clock. The world therefore runs exactly as fast as the link allows: slower
//!   than real time in QEMU and on the virtual boards, about real time on a fast serial link.
//! * Height: an `ExternalPosition` (truth + noise) at [`HilConfig::height_rate_hz`], sent just
//!   before the IMU sample of the same instant.
//! * Camera: a frame is rendered at world time `t` (its exposure time on the wire) every
//!   `1 / fps` of world time and streamed as `FrameChunk`s by a writer thread while the
//!   lockstep goes on. The camera board mirrors each `Estimate` to the host; the world is not
//!   allowed to pass the next exposure time before the estimate of the previous frame is back
//!   (it waits, holding the lockstep). So the boards always see frames at `fps` of world time
//!   with at most one frame period of latency, however slow the link.
//! * Arming: a `PilotCommand::Arm` at [`HilConfig::arm_at_s`]; a host `Heartbeat` every
//!   second of world time from the start (without it the autopilot refuses to arm, and lands).
//! * PWM outputs: the autopilot's `hil` image holds its motor outputs at 0 and flies on the
//!   commands it sends back (the simulated drone flies, nothing on the bench turns). Only with
//!   `--outputs` ([`HilConfig::outputs`]) does the host send `PilotCommand::HilOutputs(true)`
//!   at world time 0, before the arm: the outputs then follow the commands, and go to 0 within
//!   60 ms of board time once the host's samples stop (`docs/hardware.md`, "HIL outputs").
//! * Parameters (`--params FILE`, [`HilConfig::params`]): after both heartbeats and before the
//!   world starts, every value of the file is set with a parameter request on the autopilot's
//!   host link (a `[camera]` one passed on by the autopilot to the camera board) and read
//!   back; a refusal, silence or another value read back stops the run, naming the key.
//!
//! A reply that does not come within [`HilConfig::reply_timeout`] (a byte lost in the link)
//! is counted and the world goes on with the previous commands.
//!
//! # Link rates
//!
//! The `hil` flavour runs both host UARTs at 921,600 Bd (`board_support::link::HOST_BAUD`) and
//! takes their bytes by DMA. One frame (24,576 pixel bytes in 48 `FrameChunk`s, 25.2 kB
//! framed) takes 0.27 s of it, so the camera link carries 3.6 frames per second of real time:
//! at `--fps 4` (the default) the world runs at about 0.9x real time on the boards, at 25 fps
//! at 0.15x. The autopilot link needs about 70 B x 512 Hz = 36 kB/s of its 92 kB/s. Four frames
//! per second is also the lowest rate at which one invalid estimate (a gap of two frame
//! periods) stays within the autopilot's 0.5 s estimate timeout. Measured on the virtual boards
//! (`virtual-board/tests/vboard/hil.rs`, 2-core machine): 8.5 s of world time at 4 fps in 9.4 s of
//! virtual time (the autopilot's lockstep takes about 1 ms of virtual time per 1.95 ms IMU
//! period; the frames set the pace) and 12 s of wall time. In QEMU 7.2, whose STM32 USART takes
//! one received byte per main-loop iteration (about 11 kB/s into the firmware under `-icount
//! shift=auto`; the `qemu` flavour's host links run at 115,200 Bd), a frame takes about 2.3 s.
//!
//! # The board-to-board UART
//!
//! On hardware the boards are wired to each other, and the bench joins the virtual boards'
//! link UARTs. In QEMU the two firmwares' link UARTs can be joined directly (one QEMU
//! `-chardev socket,server=on`, the other connecting to it), or through this host ([`Relay`]):
//! the relay copies bytes both ways unchanged and decodes them on the way, so the run counts
//! decode errors on the inter-board link too.

mod board_rx;
mod cli;
mod encode;
mod lockstep;
mod recorder;
mod relay;
mod result;
#[cfg(test)]
mod test_boards;

pub use cli::{run_cli, HilArgs};
pub use encode::encode_frame;
pub use lockstep::{run, run_logged};
pub use recorder::{write_log_csv, HilRecorder};
pub use relay::Relay;
pub use result::{HilResult, HilRow};

use crate::param::FileSection;
use crate::sim::flight::FlightConfig;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// Everything that defines a HIL run.
#[derive(Debug, Clone)]
pub struct HilConfig {
    /// World, drone, IMU and camera parameters, scene and seed (the `fly` defaults; the
    /// simulator-only fields such as link faults and processing times are not used).
    pub world: FlightConfig,
    /// Simulated duration, s (world time).
    pub duration_s: f64,
    /// Camera frames per second of world time.
    pub fps: f64,
    /// Height fixes (`ExternalPosition`) per second of world time.
    pub height_rate_hz: f64,
    /// World time of the arm command, s.
    pub arm_at_s: f64,
    /// Longest wait for the autopilot's `Motors` reply to an IMU sample before it counts as
    /// lost, wall time.
    pub reply_timeout: Duration,
    /// Longest wait for the estimate of a frame, from when it was handed to the link (a frame
    /// takes 0.27 s of a 921,600 Bd link, seconds through QEMU's USART), wall time.
    pub frame_timeout: Duration,
    /// Longest wait for both boards' first heartbeat, wall time.
    pub boot_timeout: Duration,
    /// Parameters to send before the flight (`hil --params`): the file's name and its
    /// sections. Each value is set on its board over the autopilot's host link (the camera
    /// board's passed on by the autopilot) and read back; a refusal, silence or a different
    /// read-back ends the run before the world starts, naming the key.
    pub params: Option<(String, Vec<FileSection>)>,
    /// Set (by `hil`'s Ctrl-C handler) to end the flight at the next IMU period; the result
    /// covers the world time flown, so the logs are still written.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Enable the autopilot's PWM outputs (`hil --outputs`): the motors on the bench turn with
    /// the commands. Off by default: the outputs stay at 0, the commands come back over the
    /// link only.
    pub outputs: bool,
    /// The link key (`hil --key FILE`): heartbeats, height fixes, the arm command and
    /// parameter requests to the autopilot are signed with it. IMU samples and frames are not
    /// (see `autopilot::link_auth`).
    pub key: Option<protocol::signing::LinkKey>,
}

impl Default for HilConfig {
    fn default() -> Self {
        Self {
            world: FlightConfig::default(),
            duration_s: 10.0,
            fps: 25.0,
            height_rate_hz: 100.0,
            arm_at_s: 0.5,
            reply_timeout: Duration::from_secs(5),
            frame_timeout: Duration::from_secs(60),
            boot_timeout: Duration::from_secs(60),
            params: None,
            interrupt: None,
            outputs: false,
            key: None,
        }
    }
}
