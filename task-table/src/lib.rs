//! The shape of a board's task table.
//!
//! Each board library declares its tasks in one `TASKS` table of [`TaskSpec`]s (name,
//! priority, what starts it, deadline); its RTIC app mirrors the table (a test keeps the two in
//! agreement) and `sim-host` schedules from it on a virtual clock. This crate holds only the
//! types, so that both boards and the simulator share one definition.
#![no_std]
#![warn(missing_docs)]

/// What starts a task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trigger {
    /// Runs every `period_us` µs.
    Periodic {
        /// Period, µs.
        period_us: u32,
    },
    /// Runs on the named hardware event.
    Event(&'static str),
}

impl Trigger {
    /// The period of a periodic task, µs (`None` for an event-driven one).
    pub const fn period_us(&self) -> Option<u32> {
        match *self {
            Trigger::Periodic { period_us } => Some(period_us),
            Trigger::Event(_) => None,
        }
    }
}

/// One entry of a board's task table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskSpec {
    /// Task name (the RTIC task and the simulator's scheduler use the same).
    pub name: &'static str,
    /// Priority, higher preempts lower (RTIC priority).
    pub priority: u8,
    /// What starts it.
    pub trigger: Trigger,
    /// Deadline from release to completion, µs.
    pub deadline_us: u32,
}

/// Looks a task up by name in `table`.
pub fn find(table: &'static [TaskSpec], name: &str) -> Option<&'static TaskSpec> {
    table.iter().find(|t| t.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TABLE: &[TaskSpec] = &[
        TaskSpec {
            name: "rx",
            priority: 3,
            trigger: Trigger::Event("UART"),
            deadline_us: 2_000,
        },
        TaskSpec {
            name: "status",
            priority: 1,
            trigger: Trigger::Periodic { period_us: 1_000 },
            deadline_us: 100,
        },
    ];

    #[test]
    fn finds_tasks_by_name_and_reads_periods() {
        assert_eq!(find(TABLE, "status").map(|t| t.priority), Some(1));
        assert!(find(TABLE, "missing").is_none());
        assert_eq!(TABLE[0].trigger.period_us(), None);
        assert_eq!(TABLE[1].trigger.period_us(), Some(1_000));
    }
}
