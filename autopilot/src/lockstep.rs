//! World time for the hardware-in-the-loop flavours (`hil`, `qemu`): lockstep with the host.
//!
//! In HIL the IMU samples come from the host's world simulation, each stamped with the world
//! time. The autopilot uses that time as its library clock ([`WorldClock`]) instead of its
//! SysTick, and releases its periodic tasks (guidance, gyro to the camera board, telemetry)
//! when the world clock passes their next release time ([`WorldTimers`]) instead of on SysTick
//! timers. The host advances the world by one IMU period only after the motor command for the
//! previous sample came back, so the world runs as fast as the link allows (slower than real
//! time in QEMU, real time on a fast serial link) and the flight logic, which is the same code
//! as on hardware, sees consistent time.
//!
//! Only the time source changes: the task bodies call the same [`crate::Autopilot`] methods as
//! the real flavour, at the periods of [`crate::TASKS`].

use crate::tasks::{GUIDANCE_PERIOD, GYRO_TX_PERIOD, TELEMETRY_PERIOD};
use timebase::{Duration, Instant, WireTime, WorldTime, WrapExtender};

/// The world clock: the host's wrapping `u32` microsecond sample timestamps extended onto a
/// monotonic `u64` timeline (by [`timebase::WrapExtender`]: a decrease of more than half the
/// `u32` range is a wrap; a smaller decrease is an out-of-order sample and does not move the
/// clock back).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WorldClock(WrapExtender<WorldTime>);

impl WorldClock {
    /// A clock at zero that has seen no sample.
    pub const fn new() -> Self {
        Self(WrapExtender::new())
    }

    /// Takes a host timestamp and returns the world time it stands for. The clock itself
    /// never goes back: [`WorldClock::now`] is the latest.
    pub fn observe(&mut self, wire: WireTime) -> WorldTime {
        self.0.extend(wire)
    }

    /// The latest world time seen (the epoch before the first sample).
    pub fn now(&self) -> WorldTime {
        self.0.latest()
    }

    /// True once a sample has set the clock.
    pub fn started(&self) -> bool {
        self.0.started()
    }
}

/// Which periodic tasks are due at one world instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Due {
    /// `guidance` (every [`GUIDANCE_PERIOD`]).
    pub guidance: bool,
    /// `gyro_tx` (every [`GYRO_TX_PERIOD`]).
    pub gyro_tx: bool,
    /// `telemetry` (every [`TELEMETRY_PERIOD`]).
    pub telemetry: bool,
}

/// Release times of the periodic tasks on the library clock the world drives (the world
/// time of the samples, [`WorldTime::as_flight_clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WorldTimers {
    next: [Option<Instant>; 3],
}

/// Periods of the tasks in [`Due`] order.
const PERIODS: [Duration; 3] = [GUIDANCE_PERIOD, GYRO_TX_PERIOD, TELEMETRY_PERIOD];

impl WorldTimers {
    /// No task released yet: each is due at the first instant it is asked about.
    pub const fn new() -> Self {
        Self { next: [None; 3] }
    }

    /// The tasks due at library time `now` (call once per IMU sample, after the control
    /// step). Releases keep their phase (`next += period`); after a gap longer than a period
    /// (the host paused the world, a lost sample) a task runs once and is rescheduled from
    /// `now`, never in a burst.
    pub fn due(&mut self, now: Instant) -> Due {
        let mut out = [false; 3];
        for ((next, period), due) in self.next.iter_mut().zip(PERIODS).zip(out.iter_mut()) {
            let period = period.max(Duration::from_micros(1));
            match *next {
                Some(t) if now < t => {}
                Some(t) => {
                    *due = true;
                    let after = t + period;
                    *next = Some(if after <= now { now + period } else { after });
                }
                None => {
                    *due = true;
                    *next = Some(now + period);
                }
            }
        }
        let [guidance, gyro_tx, telemetry] = out;
        Due {
            guidance,
            gyro_tx,
            telemetry,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tasks::IMU_PERIOD;

    #[test]
    fn clock_extends_wraps_and_never_goes_back() {
        let mut c = WorldClock::new();
        assert!(!c.started());
        assert_eq!(c.observe(WireTime(10)).as_micros(), 10);
        assert_eq!(
            c.observe(WireTime(u32::MAX - 5)).as_micros(),
            u64::from(u32::MAX - 5)
        );
        // Wrap.
        assert_eq!(c.observe(WireTime(3)).as_micros(), (1u64 << 32) | 3);
        assert_eq!(c.now().as_micros(), (1u64 << 32) | 3);
        // A late sample: reported at its own time, the clock stays.
        assert_eq!(c.observe(WireTime(1)).as_micros(), (1u64 << 32) | 1);
        assert_eq!(c.now().as_micros(), (1u64 << 32) | 3);
    }

    #[test]
    fn tasks_run_at_their_periods_on_the_world_clock() {
        let mut timers = WorldTimers::new();
        let mut counts = [0u32; 3];
        // 10 s of samples at 512 Hz.
        let mut t = 0u64;
        while t < 10_000_000 {
            let d = timers.due(Instant::from_micros(t));
            counts[0] += u32::from(d.guidance);
            counts[1] += u32::from(d.gyro_tx);
            counts[2] += u32::from(d.telemetry);
            t += IMU_PERIOD.as_micros();
        }
        // 50 Hz, 128 Hz, 10 Hz within one release (sample-period quantisation).
        assert!((500..=501).contains(&counts[0]), "{counts:?}");
        assert!((1279..=1281).contains(&counts[1]), "{counts:?}");
        assert!((100..=101).contains(&counts[2]), "{counts:?}");
    }

    #[test]
    fn a_pause_gives_one_release_not_a_burst() {
        let mut timers = WorldTimers::new();
        assert!(timers.due(Instant::from_micros(0)).guidance);
        assert!(!timers.due(Instant::from_micros(1_000)).guidance);
        // The world jumps 1 s ahead: one release, then the period again.
        assert!(timers.due(Instant::from_micros(1_000_000)).guidance);
        assert!(!timers.due(Instant::from_micros(1_001_953)).guidance);
        assert!(timers.due(Instant::from_micros(1_020_000)).guidance);
    }
}
