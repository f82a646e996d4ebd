//! The shape of a board's task table.
//!
//! Each board library names its tasks in an enum (the task's identifier) and declares them in
//! one `TASKS` table of [`TaskSpec`]s (identifier, name, priority, what starts it, deadline),
//! in the enum's order; its RTIC app mirrors the table (a test keeps the two in agreement) and
//! `sim-host` schedules from it on a virtual clock and dispatches on the identifier with an
//! exhaustive match. This crate holds only the types, so that both boards and the simulator
//! share one definition.
#![no_std]
#![warn(missing_docs)]

pub use timebase::Duration;

/// What starts a task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trigger {
    /// Runs every `period`.
    Periodic {
        /// Period.
        period: Duration,
    },
    /// Runs on the named hardware event.
    Event(&'static str),
}

impl Trigger {
    /// The period of a periodic task (`None` for an event-driven one).
    pub const fn period(&self) -> Option<Duration> {
        match *self {
            Trigger::Periodic { period } => Some(period),
            Trigger::Event(_) => None,
        }
    }
}

/// One entry of a board's task table; `Id` is the board's task enum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskSpec<Id: 'static> {
    /// The task's identifier.
    pub id: Id,
    /// Task name (the RTIC task's function has the same).
    pub name: &'static str,
    /// Priority, higher preempts lower (RTIC priority).
    pub priority: u8,
    /// What starts it.
    pub trigger: Trigger,
    /// Deadline from release to completion.
    pub deadline: Duration,
}

/// A board's task enum: every variant has its entry in the board's table, at its own index.
pub trait TaskId: Copy + 'static {
    /// Every task, in table order.
    const ALL: &'static [Self];
    /// The board's task table.
    const TABLE: &'static [TaskSpec<Self>];

    /// The task's index in [`TaskId::TABLE`] (`self as usize` for a plain enum).
    fn index(self) -> usize;

    /// The task's entry in the table.
    fn spec(self) -> &'static TaskSpec<Self> {
        &Self::TABLE[self.index()]
    }

    /// The task's name (its RTIC task's).
    fn name(self) -> &'static str {
        self.spec().name
    }
}

/// Looks a task up by name in `table`.
pub fn find<Id>(table: &'static [TaskSpec<Id>], name: &str) -> Option<&'static TaskSpec<Id>> {
    table.iter().find(|t| t.name == name)
}

/// Whether `table` lists every identifier of `all` once, each at its own index (so a task's
/// entry is `table[id as usize]`).
pub fn is_indexed_by<Id: PartialEq>(table: &[TaskSpec<Id>], all: &[Id]) -> bool {
    table.len() == all.len() && table.iter().zip(all).all(|(t, id)| t.id == *id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Task {
        Rx,
        Status,
    }

    const TABLE: &[TaskSpec<Task>] = &[
        TaskSpec {
            id: Task::Rx,
            name: "rx",
            priority: 3,
            trigger: Trigger::Event("UART"),
            deadline: Duration::from_millis(2),
        },
        TaskSpec {
            id: Task::Status,
            name: "status",
            priority: 1,
            trigger: Trigger::Periodic {
                period: Duration::from_millis(1),
            },
            deadline: Duration::from_micros(100),
        },
    ];

    #[test]
    fn finds_tasks_by_name_and_reads_periods() {
        assert_eq!(find(TABLE, "status").map(|t| t.priority), Some(1));
        assert!(find(TABLE, "missing").is_none());
        assert_eq!(TABLE[0].trigger.period(), None);
        assert_eq!(TABLE[1].trigger.period(), Some(Duration::from_millis(1)));
        assert!(is_indexed_by(TABLE, &[Task::Rx, Task::Status]));
        assert!(!is_indexed_by(TABLE, &[Task::Status, Task::Rx]));
        assert!(!is_indexed_by(TABLE, &[Task::Rx]));
    }
}
