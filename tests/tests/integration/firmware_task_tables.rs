//! The RTIC apps (every flavour of both firmwares) mirror their boards' task tables: every
//! task identifier (`stereo_board::app::Task::ALL`, `autopilot::tasks::Task::ALL`) has its RTIC
//! task in the firmware source, by the name and with the priority of its table entry, and the byte-moving interrupt handlers (those bound to a UART, a DMA
//! stream or the DCMI) preempt all of them.

use autopilot::tasks::TaskId;

/// One `#[task(...)]` of a firmware source.
#[derive(Debug)]
struct RticTask {
    name: String,
    priority: u8,
    /// The interrupt a hardware task is bound to (`binds = ...`), `None` for a software task.
    binds: Option<String>,
}

impl RticTask {
    /// Whether the task moves bytes between a peripheral and memory: bound to a (U)SART, a DMA
    /// stream or the camera interface.
    fn moves_bytes(&self) -> bool {
        self.binds.as_deref().is_some_and(|irq| {
            ["USART", "UART", "DMA", "DCMI"]
                .iter()
                .any(|kind| irq.starts_with(kind))
        })
    }
}

/// Every `#[task(...)]` in a firmware source.
fn rtic_tasks(src: &str) -> Vec<RticTask> {
    let mut out = Vec::new();
    let mut rest = src;
    while let Some(at) = rest.find("#[task(") {
        rest = &rest[at + 7..];
        let Some(end) = rest.find(")]") else { break };
        let value_of = |key: &str| {
            rest[..end].split(',').find_map(|kv| {
                Some(
                    kv.trim()
                        .strip_prefix(key)?
                        .trim()
                        .strip_prefix('=')?
                        .trim(),
                )
            })
        };
        let priority = value_of("priority")
            .and_then(|v| v.parse().ok())
            .unwrap_or(1);
        let binds = value_of("binds").map(str::to_owned);
        let after = &rest[end..];
        let Some(f) = after.find("fn ") else { break };
        let name = after[f + 3..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        out.push(RticTask {
            name,
            priority,
            binds,
        });
    }
    out
}

fn check(board: &str, src: &str, table: &[(&str, u8)]) {
    let tasks = rtic_tasks(src);
    for (name, priority) in table {
        let found = tasks.iter().find(|t| t.name == *name).map(|t| t.priority);
        assert_eq!(
            found,
            Some(*priority),
            "{board}: RTIC task {name} with priority {priority}; firmware has {tasks:?}"
        );
    }
    let top = table.iter().map(|t| t.1).max().unwrap_or(0);
    let movers: Vec<&RticTask> = tasks.iter().filter(|t| t.moves_bytes()).collect();
    assert!(
        movers.len() >= 3,
        "{board}: byte-moving handlers found: {movers:?} (every board has two UARTs and a DMA)"
    );
    for task in movers {
        assert!(
            task.priority > top,
            "{board}: {} (bound to {:?}, priority {}) must preempt the task table (up to {top})",
            task.name,
            task.binds,
            task.priority
        );
    }
}

#[test]
fn stereo_board_firmware_mirrors_its_task_table() {
    let table: Vec<_> = stereo_board::app::Task::ALL
        .iter()
        .map(|t| (t.name(), t.spec().priority))
        .collect();
    check(
        "stereo-board",
        include_str!("../../../stereo-board/src/firmware/mod.rs"),
        &table,
    );
}

#[test]
fn autopilot_firmware_mirrors_its_task_table() {
    let table: Vec<_> = autopilot::tasks::Task::ALL
        .iter()
        .map(|t| (t.name(), t.spec().priority))
        .collect();
    check(
        "autopilot",
        include_str!("../../../autopilot/src/firmware/mod.rs"),
        &table,
    );
}
