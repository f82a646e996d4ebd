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

use crate::tasks::{GUIDANCE_PERIOD_US, GYRO_TX_PERIOD_US, TELEMETRY_PERIOD_US};
use timebase::{WireTime, WorldTime, WrapExtender};

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

    /// Takes a host timestamp and returns the world time it stands for
    /// (µs, `u64`). The clock itself never goes back: [`WorldClock::now_us`] is the latest.
    pub fn observe(&mut self, wire: WireTime) -> u64 {
        self.0.extend(wire).as_micros()
    }

    /// The latest world time seen, µs (0 before the first sample).
    pub fn now_us(&self) -> u64 {
        self.0.latest().as_micros()
    }

    /// True once a sample has set the clock.
    pub fn started(&self) -> bool {
        self.0.started()
    }
}

/// Which periodic tasks are due at one world instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Due {
    /// `guidance` (every [`GUIDANCE_PERIOD_US`]).
    pub guidance: bool,
    /// `gyro_tx` (every [`GYRO_TX_PERIOD_US`]).
    pub gyro_tx: bool,
    /// `telemetry` (every [`TELEMETRY_PERIOD_US`]).
    pub telemetry: bool,
}

/// Release times of the periodic tasks on the world clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WorldTimers {
    next_us: [Option<u64>; 3],
}

/// Periods of the tasks in [`Due`] order, µs.
const PERIODS_US: [u32; 3] = [GUIDANCE_PERIOD_US, GYRO_TX_PERIOD_US, TELEMETRY_PERIOD_US];

impl WorldTimers {
    /// No task released yet: each is due at the first instant it is asked about.
    pub const fn new() -> Self {
        Self { next_us: [None; 3] }
    }

    /// The tasks due at world time `now_us` (call once per IMU sample, after the control
    /// step). Releases keep their phase (`next += period`); after a gap longer than a period
    /// (the host paused the world, a lost sample) a task runs once and is rescheduled from
    /// `now_us`, never in a burst.
    pub fn due(&mut self, now_us: u64) -> Due {
        let mut out = [false; 3];
        for ((next, period), due) in self.next_us.iter_mut().zip(PERIODS_US).zip(out.iter_mut()) {
            let period = u64::from(period.max(1));
            match *next {
                Some(t) if now_us < t => {}
                Some(t) => {
                    *due = true;
                    let after = t.saturating_add(period);
                    *next = Some(if after <= now_us {
                        now_us.saturating_add(period)
                    } else {
                        after
                    });
                }
                None => {
                    *due = true;
                    *next = Some(now_us.saturating_add(period));
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
    use crate::tasks::IMU_PERIOD_US;

    #[test]
    fn clock_extends_wraps_and_never_goes_back() {
        let mut c = WorldClock::new();
        assert!(!c.started());
        assert_eq!(c.observe(WireTime(10)), 10);
        assert_eq!(c.observe(WireTime(u32::MAX - 5)), u64::from(u32::MAX - 5));
        // Wrap.
        assert_eq!(c.observe(WireTime(3)), (1u64 << 32) | 3);
        assert_eq!(c.now_us(), (1u64 << 32) | 3);
        // A late sample: reported at its own time, the clock stays.
        assert_eq!(c.observe(WireTime(1)), (1u64 << 32) | 1);
        assert_eq!(c.now_us(), (1u64 << 32) | 3);
    }

    #[test]
    fn tasks_run_at_their_periods_on_the_world_clock() {
        let mut timers = WorldTimers::new();
        let mut counts = [0u32; 3];
        // 10 s of samples at 512 Hz.
        let mut t = 0u64;
        while t < 10_000_000 {
            let d = timers.due(t);
            counts[0] += u32::from(d.guidance);
            counts[1] += u32::from(d.gyro_tx);
            counts[2] += u32::from(d.telemetry);
            t += u64::from(IMU_PERIOD_US);
        }
        // 50 Hz, 128 Hz, 10 Hz within one release (sample-period quantisation).
        assert!((500..=501).contains(&counts[0]), "{counts:?}");
        assert!((1279..=1281).contains(&counts[1]), "{counts:?}");
        assert!((100..=101).contains(&counts[2]), "{counts:?}");
    }

    #[test]
    fn a_pause_gives_one_release_not_a_burst() {
        let mut timers = WorldTimers::new();
        assert!(timers.due(0).guidance);
        assert!(!timers.due(1_000).guidance);
        // The world jumps 1 s ahead: one release, then the period again.
        assert!(timers.due(1_000_000).guidance);
        assert!(!timers.due(1_001_953).guidance);
        assert!(timers.due(1_020_000).guidance);
    }
}
