//! The `real` flavour: the autopilot on its own sensors.
//!
//! * The control loop runs on TIM2 at [`autopilot::board::LOOP_RATE_HZ`] and reads the IMU
//!   itself; the barometer task and the RC receiver run.
//! * The library clock is the board clock (SysTick); the periodic tasks release themselves on
//!   SysTick periods ([`Tick`]).
//! * Sensor data from the host link is refused and counted ([`host_imu`]): the telemetry port
//!   carries commands and the motion-capture position, never IMU samples.
//! * The 512 Hz control loop feeds the watchdog while the guidance task and the heartbeat run
//!   ([`autopilot::board::WATCHDOG_MS`]).

use super::{clock, Mono};
use core::sync::atomic::{AtomicU32, Ordering};
use protocol::ImuSample;
use rtic_monotonics::Timebase as _;
use timebase::{Duration, Instant};

/// The flavour's side of the contract both boards' flavour modules fulfil.
pub struct Current;

impl board_support::flavour::Flavour for Current {
    /// The board reads its own IMU and barometer and listens to its RC receiver.
    const OWN_SENSORS: bool = true;
    /// The loop-fed timeout of the board's 50 ms bound.
    const WATCHDOG: board_support::watchdog::Timeout = autopilot::board::WATCHDOG;

    /// The board clock.
    fn lib_now() -> Instant {
        clock::now()
    }
}

/// The control loop feeds the watchdog (see [`autopilot::board::WATCHDOG_MS`]).
pub const FEED_WATCHDOG_IN_LOOP: bool = true;
/// Motor commands go to the PWM outputs only.
pub const MOTORS_TO_HOST: bool = false;

/// IMU samples from the host link refused since boot.
pub static HOST_SENSOR_REJECTED: AtomicU32 = AtomicU32::new(0);

/// A host IMU sample: refused and counted (returns no time to run the loop at).
pub fn host_imu(
    _world: &mut autopilot::lockstep::WorldClock,
    _sample: &ImuSample,
) -> Option<Instant> {
    HOST_SENSOR_REJECTED.fetch_add(1, Ordering::Relaxed);
    None
}

/// No board-clock check of the outputs (0): the library's IMU failsafe watches the board's
/// own samples.
pub const OUTPUTS_CHECK: Duration = Duration::ZERO;

/// Whether the PWM outputs follow the motor command: always (the host's
/// [`protocol::PilotCommand::HilOutputs`] gates only the lockstep flavours).
pub fn outputs_live(_enabled: bool, _board_now: Instant) -> bool {
    true
}

/// Release of one periodic task: a SysTick period.
pub struct Tick {
    period: <Mono as rtic_monotonics::Timebase>::Duration,
    next: Option<<Mono as rtic_monotonics::Timebase>::Instant>,
}

impl Tick {
    /// Every `period` (rounded down to the 1 ms SysTick tick, at least one tick); the first
    /// release is immediate.
    pub fn every(period: Duration) -> Self {
        Self {
            period: <Mono as rtic_monotonics::Timebase>::Duration::from_ticks(
                (period.as_millis() as u32).max(1),
            ),
            next: None,
        }
    }

    /// Waits for the next release; returns the library time (the board clock).
    pub async fn wait(&mut self) -> Instant {
        let at = match self.next {
            Some(t) => {
                Mono::delay_until(t).await;
                t
            }
            None => Mono::now(),
        };
        self.next = Some(at + self.period);
        clock::now()
    }
}

/// The periodic tasks' releases: each its own SysTick [`Tick`].
pub struct Releases;

impl Releases {
    /// The periodic tasks' ticks (guidance, gyro_tx, telemetry) and the loop's releases.
    pub fn new() -> (Tick, Tick, Tick, Self) {
        use autopilot::tasks::{GUIDANCE_PERIOD, GYRO_TX_PERIOD, TELEMETRY_PERIOD};
        (
            Tick::every(GUIDANCE_PERIOD),
            Tick::every(GYRO_TX_PERIOD),
            Tick::every(TELEMETRY_PERIOD),
            Self,
        )
    }

    /// Nothing to release: SysTick releases the periodic tasks.
    pub fn release(&mut self, _now: Instant) {}
}
