//! Virtual-clock scheduler: releases each board's periodic tasks from the boards' own task
//! tables, in priority order when several fall due at the same instant; and the world's own
//! events (camera, height fixes, barometer, the host's heartbeat), [`SensorSchedule`]. Board
//! code runs in zero virtual time; the camera board's processing time is modelled separately
//! (its output is held back by the processing delay, see `flight`).

use task_table::TaskId as _;
use timebase::{Duration, WorldTime};

/// A task of either board, by the board's task identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BoardTask {
    /// A task of the stereo camera board.
    Stereo(stereo_board::app::Task),
    /// A task of the autopilot.
    Autopilot(autopilot::tasks::Task),
}

impl BoardTask {
    /// The task's name in its board's table.
    pub fn name(self) -> &'static str {
        match self {
            Self::Stereo(t) => t.name(),
            Self::Autopilot(t) => t.name(),
        }
    }
}

/// One schedulable task, taken from a board's task table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimTask {
    /// The task.
    pub task: BoardTask,
    /// Priority (higher first).
    pub priority: u8,
    /// Period; `None` for event-triggered tasks (run by the simulator when the event
    /// happens: a frame, UART bytes).
    pub period: Option<Duration>,
}

/// A released task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Release {
    /// The task.
    pub task: BoardTask,
    /// Release time.
    pub at: WorldTime,
}

/// Periodic release generator over a set of tasks.
#[derive(Debug, Clone)]
pub struct Scheduler {
    tasks: Vec<SimTask>,
    next: Vec<WorldTime>,
}

impl Scheduler {
    /// A scheduler over `tasks`; every periodic task is first released at t = 0 (simultaneous
    /// releases run highest priority first).
    pub fn new(tasks: Vec<SimTask>) -> Self {
        let next = tasks.iter().map(|_| WorldTime::ZERO).collect();
        Self { tasks, next }
    }

    /// The tasks.
    pub fn tasks(&self) -> &[SimTask] {
        &self.tasks
    }

    /// Earliest next release of any periodic task.
    pub fn next_release(&self) -> Option<WorldTime> {
        self.tasks
            .iter()
            .zip(&self.next)
            .filter(|(t, _)| t.period.is_some())
            .map(|(_, &n)| n)
            .min()
    }

    /// Pops every release due at or before `now` into `out`, ordered by time, then priority
    /// (highest first), then table order.
    pub fn due(&mut self, now: WorldTime, out: &mut Vec<Release>) {
        let start = out.len();
        let mut keyed: Vec<(WorldTime, u8, usize, Release)> = Vec::new();
        for (i, t) in self.tasks.iter().enumerate() {
            let Some(p) = t.period else { continue };
            while self.next[i] <= now {
                keyed.push((
                    self.next[i],
                    t.priority,
                    i,
                    Release {
                        task: t.task,
                        at: self.next[i],
                    },
                ));
                self.next[i] += p.max(Duration::from_micros(1));
            }
        }
        keyed.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.cmp(&a.1)).then(a.2.cmp(&b.2)));
        out.extend(keyed.into_iter().map(|k| k.3));
        debug_assert!(out.len() >= start);
    }
}

/// A world event that repeats: due first at its first time, then every period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Periodic {
    next: WorldTime,
    period: Duration,
}

impl Periodic {
    /// The end of the world's clock: [`Periodic::never`] is next due then.
    pub const NEVER: WorldTime = WorldTime::from_micros(u64::MAX);

    /// Due at `first`, then every `period`.
    pub fn every(period: Duration, first: WorldTime) -> Self {
        Self {
            next: first,
            period,
        }
    }

    /// Never due.
    pub fn never() -> Self {
        Self {
            next: Self::NEVER,
            period: Duration::ZERO,
        }
    }

    /// When it is next due ([`Periodic::NEVER`]: never).
    pub fn next(&self) -> WorldTime {
        self.next
    }

    /// Whether it is due at `t`; if so, the next one is a period later.
    pub fn due(&mut self, t: WorldTime) -> bool {
        let due = t >= self.next;
        if due {
            self.next += self.period;
        }
        due
    }
}

/// The time of the `k`-th IMU sample of the world, at the IMU's rate
/// ([`autopilot::board::LOOP_RATE_HZ`], not rounded to a microsecond period): what `hil` steps
/// the world to, one sample per `Motors` reply. (`fly` releases the autopilot's `imu_indi`
/// task from its task table instead, every `autopilot::tasks::IMU_PERIOD`, as the firmware's
/// timer does.)
pub fn imu_sample_time(k: u64) -> WorldTime {
    WorldTime::from_micros(k * 1_000_000 / u64::from(autopilot::board::LOOP_RATE_HZ))
}

/// The first camera exposure after the start of a flight (the boards are up by then).
pub const FIRST_FRAME: WorldTime = WorldTime::from_micros(100_000);

/// The world's own events that `fly` and `hil` both run on: camera exposures, the motion
/// capture's height fixes and the host's heartbeat on the host link, barometer readings.
/// (The IMU samples are the autopilot's `imu_indi` task's: `fly` releases it from the task
/// table, `hil` steps the world one IMU period per reply.)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorSchedule {
    /// Camera exposures, from [`FIRST_FRAME`].
    pub frame: Periodic,
    /// Height fixes (never without motion capture).
    pub height_fix: Periodic,
    /// Barometer readings (never where the board reads its own).
    pub baro: Periodic,
    /// The host's heartbeat.
    pub host_heartbeat: Periodic,
}

impl SensorSchedule {
    /// Frames at `fps`, height fixes at `height_rate_hz` and barometer readings at
    /// `baro_rate_hz` (each `None`: never), all but the frames from time 0.
    pub fn new(fps: f64, height_rate_hz: Option<f64>, baro_rate_hz: Option<f64>) -> Self {
        // Rounded down to a microsecond.
        let period = |hz: f64| Duration::from_micros((1e6 / hz) as u64);
        let from_zero = |hz: Option<f64>| {
            hz.map_or(Periodic::never(), |hz| {
                Periodic::every(period(hz), WorldTime::ZERO)
            })
        };
        Self {
            frame: Periodic::every(period(fps), FIRST_FRAME),
            height_fix: from_zero(height_rate_hz),
            baro: from_zero(baro_rate_hz),
            host_heartbeat: Periodic::every(autopilot::tasks::HEARTBEAT_PERIOD, WorldTime::ZERO),
        }
    }

    /// The earliest next event.
    pub fn next(&self) -> WorldTime {
        self.frame
            .next()
            .min(self.height_fix.next())
            .min(self.baro.next())
            .min(self.host_heartbeat.next())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use autopilot::tasks::Task;

    #[test]
    fn releases_in_time_then_priority_order() {
        let (slow, fast) = (Task::Telemetry, Task::ImuIndi);
        let mut s = Scheduler::new(vec![
            SimTask {
                task: BoardTask::Autopilot(slow),
                priority: 1,
                period: Some(Duration::from_micros(1000)),
            },
            SimTask {
                task: BoardTask::Autopilot(fast),
                priority: 5,
                period: Some(Duration::from_micros(250)),
            },
            SimTask {
                task: BoardTask::Stereo(stereo_board::app::Task::Frame),
                priority: 9,
                period: None,
            },
        ]);
        let mut out = Vec::new();
        s.due(WorldTime::from_micros(1000), &mut out);
        let (slow, fast) = (slow.name(), fast.name());
        let names: Vec<_> = out
            .iter()
            .map(|r| (r.task.name(), r.at.as_micros()))
            .collect();
        assert_eq!(
            names,
            [
                (fast, 0),
                (slow, 0),
                (fast, 250),
                (fast, 500),
                (fast, 750),
                (fast, 1000),
                (slow, 1000)
            ]
        );
        assert_eq!(s.next_release(), Some(WorldTime::from_micros(1250)));
    }

    #[test]
    fn periodic_events_fall_due_once_per_period_and_never_ones_never() {
        let mut p = Periodic::every(Duration::from_micros(100), WorldTime::from_micros(50));
        let due: Vec<u64> = (0..=400)
            .filter(|&t| p.due(WorldTime::from_micros(t)))
            .collect();
        assert_eq!(due, [50, 150, 250, 350]);
        let mut never = Periodic::never();
        assert!(!never.due(WorldTime::from_micros(u64::MAX - 1)));
        let s = SensorSchedule::new(25.0, None, Some(50.0));
        assert_eq!(s.frame.next(), FIRST_FRAME);
        assert_eq!(s.height_fix.next(), Periodic::NEVER);
        assert_eq!(s.next(), WorldTime::ZERO);
    }
}
