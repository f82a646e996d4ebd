//! The two boards as the simulator runs them: each board's own task table turned into
//! scheduler tasks. The task bodies are the boards' own libraries, called by `flight`:
//!
//! * Autopilot: `autopilot::app::Autopilot` with `autopilot::tasks::TASKS`. Its `stereo_rx` task
//!   decodes the UART bytes with `protocol::Decoder` and hands each estimate to
//!   `Autopilot::on_estimate` (what the firmware's task body does).
//! * Camera board: `stereo_board::app::StereoBoardApp` with `stereo_board::app::TASKS`.

use super::sched::{BoardTask, SimTask};
use protocol::{encode, Message};

/// Scheduler tasks from a board's task table, each identified by `id`.
fn sim_tasks<Id: Copy>(
    table: &'static [task_table::TaskSpec<Id>],
    id: impl Fn(Id) -> BoardTask,
) -> Vec<SimTask> {
    table
        .iter()
        .map(|t| SimTask {
            task: id(t.id),
            priority: t.priority,
            period: t.trigger.period(),
        })
        .collect()
}

/// Scheduler tasks from the autopilot's table (`autopilot::tasks::TASKS`).
pub fn autopilot_tasks() -> Vec<SimTask> {
    sim_tasks(autopilot::tasks::TASKS, BoardTask::Autopilot)
}

/// Scheduler tasks from the camera board's table (`stereo_board::app::TASKS`).
pub fn camera_tasks() -> Vec<SimTask> {
    sim_tasks(stereo_board::app::TASKS, BoardTask::Stereo)
}

/// Encodes one message and hands the frame bytes to `tx`.
pub fn send<M: Message>(msg: &M, tx: &mut impl FnMut(&[u8])) {
    let mut buf = [0u8; 640];
    if let Ok(n) = encode(msg, &mut buf) {
        tx(&buf[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_of_both_boards_is_scheduled_once_periodic_ones_with_their_period() {
        use autopilot::tasks::Task as Ap;
        use stereo_board::app::Task as Cam;
        use task_table::TaskId;
        let tasks: Vec<SimTask> = autopilot_tasks()
            .into_iter()
            .chain(camera_tasks())
            .collect();
        let want: Vec<BoardTask> = Ap::ALL
            .iter()
            .map(|&t| BoardTask::Autopilot(t))
            .chain(Cam::ALL.iter().map(|&t| BoardTask::Stereo(t)))
            .collect();
        assert_eq!(tasks.iter().map(|t| t.task).collect::<Vec<_>>(), want);
        for t in &tasks {
            let period = match t.task {
                BoardTask::Autopilot(a) => a.spec().trigger.period(),
                BoardTask::Stereo(c) => c.spec().trigger.period(),
            };
            assert_eq!(t.period, period, "{}", t.task.name());
        }
        let status = tasks
            .iter()
            .find(|t| t.task == BoardTask::Stereo(Cam::Status));
        assert_eq!(
            status.and_then(|t| t.period),
            Some(stereo_board::app::STATUS_PERIOD)
        );
    }
}
