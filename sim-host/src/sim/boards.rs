//! The two boards as the simulator runs them: each board's own task table turned into
//! scheduler tasks. The task bodies are the boards' own libraries, called by `flight`:
//!
//! * Autopilot: `autopilot::app::Autopilot` with `autopilot::tasks::TASKS`. Its `stereo_rx` task
//!   decodes the UART bytes with `protocol::Decoder` and hands each estimate to
//!   `Autopilot::on_estimate` (what the firmware's task body does).
//! * Camera board: `stereo_board::app::StereoBoardApp` with `stereo_board::app::TASKS`.

use super::sched::{Board, SimTask};
use protocol::{encode, Message};

/// Scheduler tasks from a board's task table.
fn sim_tasks(board: Board, table: &'static [task_table::TaskSpec]) -> Vec<SimTask> {
    table
        .iter()
        .map(|t| SimTask {
            board,
            name: t.name,
            priority: t.priority,
            period_us: t.trigger.period_us(),
        })
        .collect()
}

/// Scheduler tasks from the autopilot's table (`autopilot::tasks::TASKS`).
pub fn autopilot_tasks() -> Vec<SimTask> {
    sim_tasks(Board::Autopilot, autopilot::tasks::TASKS)
}

/// Scheduler tasks from the camera board's table (`stereo_board::app::TASKS`).
pub fn camera_tasks() -> Vec<SimTask> {
    sim_tasks(Board::Stereo, stereo_board::app::TASKS)
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
    fn tables_have_the_tasks_the_simulator_runs() {
        let ap = autopilot_tasks();
        for name in ["imu_indi", "guidance", "gyro_tx", "stereo_rx", "heartbeat"] {
            assert!(ap.iter().any(|t| t.name == name), "autopilot task {name}");
        }
        let cam = camera_tasks();
        for name in [
            stereo_board::app::TASK_FRAME,
            stereo_board::app::TASK_UART_RX,
            stereo_board::app::TASK_STATUS,
        ] {
            assert!(cam.iter().any(|t| t.name == name), "camera task {name}");
        }
        assert!(cam
            .iter()
            .any(|t| t.name == stereo_board::app::TASK_STATUS && t.period_us.is_some()));
    }
}
