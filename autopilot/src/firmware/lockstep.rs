//! The lockstep flavours, `hil` and `qemu`: the autopilot in lockstep with a host's world
//! simulation (see [`autopilot::lockstep`]).
//!
//! * IMU samples arrive over the host link; each one runs the control loop at its world time
//!   ([`host_imu`]), and the motor command goes back over the link as well as to the PWM.
//! * The library clock is the world time of those samples ([`Current`]); the loop releases
//!   the periodic tasks when the world clock passes their periods ([`Releases`]).
//! * The board's own IMU and barometer are not read, and the RC receiver is not listened to.
//! * The world clock may stall while the host computes, so the 1 Hz heartbeat (board clock)
//!   feeds the watchdog ([`board_support::watchdog::HEARTBEAT_FED`], 2 s).
//! * The PWM outputs stay at 0 unless the host enabled them
//!   ([`protocol::PilotCommand::HilOutputs`], see [`autopilot::app::Autopilot::hil_outputs`]),
//!   and go to 0 when no host sample arrived for [`SAMPLES_TIMEOUT`] of board time
//!   ([`outputs_live`], checked every [`OUTPUTS_CHECK`]): world time stops with the samples, so
//!   no failsafe of the library fires then.

use core::cell::Cell;
use core::sync::atomic::AtomicU32;
use cortex_m::interrupt::Mutex;
use protocol::ImuSample;
use timebase::{Duration, Instant};

/// The flavour's side of the contract both boards' flavour modules fulfil.
pub struct Current;

impl board_support::flavour::Flavour for Current {
    /// The host sends the sensor data; the board's own sensors stay unused.
    const OWN_SENSORS: bool = false;
    /// The heartbeat-fed timeout both boards share.
    const WATCHDOG: board_support::watchdog::Timeout = board_support::watchdog::HEARTBEAT_FED;

    /// The host's world time, as its IMU samples carry it.
    fn lib_now() -> Instant {
        cortex_m::interrupt::free(|cs| WORLD.borrow(cs).get())
    }
}

/// The heartbeat feeds the watchdog (see [`autopilot::board::WATCHDOG_MS`]).
pub const FEED_WATCHDOG_IN_LOOP: bool = false;
/// Motor commands also go to the host (the simulated drone flies on them).
pub const MOTORS_TO_HOST: bool = true;

/// IMU samples from the host link refused (none are in these flavours).
pub static HOST_SENSOR_REJECTED: AtomicU32 = AtomicU32::new(0);

/// The library clock: the world time of the host link's IMU samples.
static WORLD: Mutex<Cell<Instant>> = Mutex::new(Cell::new(Instant::ZERO));
/// Board time of the last host IMU sample (`None` before the first).
static LAST_SAMPLE_BOARD: Mutex<Cell<Option<Instant>>> = Mutex::new(Cell::new(None));

/// Board time without a host sample after which the PWM outputs go to 0. The host sends 512
/// samples per world second; a world that runs near real time leaves gaps of a few ms.
pub const SAMPLES_TIMEOUT: Duration = Duration::from_millis(50);
/// Period of the board-clock check of [`SAMPLES_TIMEOUT`]: with it, the outputs are at 0 at
/// most 60 ms of board time after the last sample (the 100 ms promise of `docs/hardware.md`,
/// "HIL outputs").
pub const OUTPUTS_CHECK: Duration = Duration::from_millis(10);

/// A host IMU sample: its timestamp moves the world clock; returns the library time (the
/// world's, as the flight clock) to run the control loop at.
pub fn host_imu(
    world: &mut autopilot::lockstep::WorldClock,
    sample: &ImuSample,
) -> Option<Instant> {
    let at = world.observe(sample.timestamp_us).as_flight_clock();
    let now = world.now().as_flight_clock();
    let board_now = super::clock::now();
    cortex_m::interrupt::free(|cs| {
        WORLD.borrow(cs).set(now);
        LAST_SAMPLE_BOARD.borrow(cs).set(Some(board_now));
    });
    Some(at)
}

/// Whether the PWM outputs follow the motor command at board time `board_now`: the host
/// `enabled` them and its last sample is at most [`SAMPLES_TIMEOUT`] old. Otherwise every
/// output is held at 0.
pub fn outputs_live(enabled: bool, board_now: Instant) -> bool {
    let last = cortex_m::interrupt::free(|cs| LAST_SAMPLE_BOARD.borrow(cs).get());
    enabled && last.is_some_and(|t| board_now.since(t) <= SAMPLES_TIMEOUT)
}

/// Release of one periodic task: library times sent by the control loop.
pub struct Tick(rtic_sync::channel::Receiver<'static, Instant, 1>);

impl Tick {
    /// Waits for the next release; returns its library time.
    pub async fn wait(&mut self) -> Instant {
        match self.0.recv().await {
            Ok(t) => t,
            // The sender lives as long as the program; without one, never release again.
            Err(_) => core::future::pending().await,
        }
    }
}

/// The senders the control loop releases the periodic tasks with. A release that finds its
/// task still busy with the previous one is skipped (an overrun, as on hardware).
pub struct Releases {
    guidance: rtic_sync::channel::Sender<'static, Instant, 1>,
    gyro_tx: rtic_sync::channel::Sender<'static, Instant, 1>,
    telemetry: rtic_sync::channel::Sender<'static, Instant, 1>,
    timers: autopilot::lockstep::WorldTimers,
}

impl Releases {
    /// The periodic tasks' ticks (guidance, gyro_tx, telemetry) and the loop's releases.
    pub fn new() -> (Tick, Tick, Tick, Self) {
        let (g_tx, g_rx) = rtic_sync::make_channel!(Instant, 1);
        let (y_tx, y_rx) = rtic_sync::make_channel!(Instant, 1);
        let (t_tx, t_rx) = rtic_sync::make_channel!(Instant, 1);
        (
            Tick(g_rx),
            Tick(y_rx),
            Tick(t_rx),
            Self {
                guidance: g_tx,
                gyro_tx: y_tx,
                telemetry: t_tx,
                timers: autopilot::lockstep::WorldTimers::new(),
            },
        )
    }

    /// Releases what is due at library time `now` (the world's, see [`host_imu`]).
    pub fn release(&mut self, now: Instant) {
        let due = self.timers.due(now);
        if due.guidance {
            let _ = self.guidance.try_send(now);
        }
        if due.gyro_tx {
            let _ = self.gyro_tx.try_send(now);
        }
        if due.telemetry {
            let _ = self.telemetry.try_send(now);
        }
    }
}
