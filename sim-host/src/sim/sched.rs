//! Virtual-clock scheduler: releases each board's periodic tasks from the boards' own task
//! tables, in priority order when several fall due at the same instant; and the world's own
//! events (camera, height fixes, barometer, the host's heartbeat), [`SensorSchedule`]. Board
//! code runs in zero virtual time; the camera board's processing time is modelled separately
//! (its output is held back by the processing delay, see `flight`).

use task_table::TaskId as _;

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
    /// Period, µs; `None` for event-triggered tasks (run by the simulator when the event
    /// happens: a frame, UART bytes).
    pub period_us: Option<u32>,
}

/// A released task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Release {
    /// The task.
    pub task: BoardTask,
    /// Release time, µs.
    pub at_us: u64,
}

/// Periodic release generator over a set of tasks.
#[derive(Debug, Clone)]
pub struct Scheduler {
    tasks: Vec<SimTask>,
    next_us: Vec<u64>,
}

impl Scheduler {
    /// A scheduler over `tasks`; every periodic task is first released at t = 0 (simultaneous
    /// releases run highest priority first).
    pub fn new(tasks: Vec<SimTask>) -> Self {
        let next_us = tasks.iter().map(|_| 0).collect();
        Self { tasks, next_us }
    }

    /// The tasks.
    pub fn tasks(&self) -> &[SimTask] {
        &self.tasks
    }

    /// Earliest next release of any periodic task, µs.
    pub fn next_release_us(&self) -> Option<u64> {
        self.tasks
            .iter()
            .zip(&self.next_us)
            .filter(|(t, _)| t.period_us.is_some())
            .map(|(_, &n)| n)
            .min()
    }

    /// Pops every release due at or before `now_us` into `out`, ordered by time, then priority
    /// (highest first), then table order.
    pub fn due(&mut self, now_us: u64, out: &mut Vec<Release>) {
        let start = out.len();
        let mut keyed: Vec<(u64, u8, usize, Release)> = Vec::new();
        for (i, t) in self.tasks.iter().enumerate() {
            let Some(p) = t.period_us else { continue };
            while self.next_us[i] <= now_us {
                keyed.push((
                    self.next_us[i],
                    t.priority,
                    i,
                    Release {
                        task: t.task,
                        at_us: self.next_us[i],
                    },
                ));
                self.next_us[i] += p.max(1) as u64;
            }
        }
        keyed.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.cmp(&a.1)).then(a.2.cmp(&b.2)));
        out.extend(keyed.into_iter().map(|k| k.3));
        debug_assert!(out.len() >= start);
    }
}

/// A world event that repeats: due first at its first time, then every period, µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Periodic {
    next_us: u64,
    period_us: u64,
}

impl Periodic {
    /// Due at `first_us`, then every `period_us`.
    pub fn every(period_us: u64, first_us: u64) -> Self {
        Self {
            next_us: first_us,
            period_us,
        }
    }

    /// Never due.
    pub fn never() -> Self {
        Self {
            next_us: u64::MAX,
            period_us: 0,
        }
    }

    /// When it is next due, µs (`u64::MAX`: never).
    pub fn next_us(&self) -> u64 {
        self.next_us
    }

    /// Whether it is due at `t_us`; if so, the next one is a period later.
    pub fn due(&mut self, t_us: u64) -> bool {
        let due = t_us >= self.next_us;
        if due {
            self.next_us += self.period_us;
        }
        due
    }
}

/// The first camera exposure, µs after the start of a flight (the boards are up by then).
pub const FIRST_FRAME_US: u64 = 100_000;

/// The world's own events that `fly` and `hil` both run on: camera exposures, the motion
/// capture's height fixes and the host's heartbeat on the host link, barometer readings.
/// (The IMU samples are the autopilot's `imu_indi` task's: `fly` releases it from the task
/// table, `hil` steps the world one IMU period per reply.)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorSchedule {
    /// Camera exposures, from [`FIRST_FRAME_US`].
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
        let period_us = |hz: f64| (super::US_PER_S / hz) as u64;
        let from_zero =
            |hz: Option<f64>| hz.map_or(Periodic::never(), |hz| Periodic::every(period_us(hz), 0));
        Self {
            frame: Periodic::every(period_us(fps), FIRST_FRAME_US),
            height_fix: from_zero(height_rate_hz),
            baro: from_zero(baro_rate_hz),
            host_heartbeat: Periodic::every(u64::from(autopilot::tasks::HEARTBEAT_PERIOD_US), 0),
        }
    }

    /// The earliest next event, µs.
    pub fn next_us(&self) -> u64 {
        self.frame
            .next_us()
            .min(self.height_fix.next_us())
            .min(self.baro.next_us())
            .min(self.host_heartbeat.next_us())
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
                period_us: Some(1000),
            },
            SimTask {
                task: BoardTask::Autopilot(fast),
                priority: 5,
                period_us: Some(250),
            },
            SimTask {
                task: BoardTask::Stereo(stereo_board::app::Task::Frame),
                priority: 9,
                period_us: None,
            },
        ]);
        let mut out = Vec::new();
        s.due(1000, &mut out);
        let (slow, fast) = (slow.name(), fast.name());
        let names: Vec<_> = out.iter().map(|r| (r.task.name(), r.at_us)).collect();
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
        assert_eq!(s.next_release_us(), Some(1250));
    }

    #[test]
    fn periodic_events_fall_due_once_per_period_and_never_ones_never() {
        let mut p = Periodic::every(100, 50);
        let due: Vec<u64> = (0..=400).filter(|&t| p.due(t)).collect();
        assert_eq!(due, [50, 150, 250, 350]);
        let mut never = Periodic::never();
        assert!(!never.due(u64::MAX - 1));
        let s = SensorSchedule::new(25.0, None, Some(50.0));
        assert_eq!(s.frame.next_us(), FIRST_FRAME_US);
        assert_eq!(s.height_fix.next_us(), u64::MAX);
        assert_eq!(s.next_us(), 0);
    }
}
