//! The RTIC apps (every flavour of both firmwares) mirror their boards' task tables: every
//! task of `stereo_board::app::TASKS` and `autopilot::app::TASKS` exists in the firmware source
//! with the same priority, and the byte-moving interrupt handlers preempt all of them.

/// `(name, priority)` of every `#[task(...)]` in a firmware source.
fn rtic_tasks(src: &str) -> Vec<(String, u8)> {
    let mut out = Vec::new();
    let mut rest = src;
    while let Some(at) = rest.find("#[task(") {
        rest = &rest[at + 7..];
        let Some(end) = rest.find(")]") else { break };
        let priority = rest[..end]
            .split(',')
            .find_map(|kv| kv.trim().strip_prefix("priority")?.trim().strip_prefix('='))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(1);
        let after = &rest[end..];
        let Some(f) = after.find("fn ") else { break };
        let name = after[f + 3..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        out.push((name, priority));
    }
    out
}

fn check(board: &str, src: &str, table: &[(&str, u8)]) {
    let tasks = rtic_tasks(src);
    for (name, priority) in table {
        let found = tasks.iter().find(|(n, _)| n == name).map(|(_, p)| *p);
        assert_eq!(
            found,
            Some(*priority),
            "{board}: RTIC task {name} with priority {priority}; firmware has {tasks:?}"
        );
    }
    let top = table.iter().map(|t| t.1).max().unwrap_or(0);
    for (name, p) in &tasks {
        if name.starts_with("usart") || name.starts_with("dcmi") || name == "imu_timer" {
            assert!(*p > top, "{board}: {name} must preempt the task table");
        }
    }
}

#[test]
fn stereo_board_firmware_mirrors_its_task_table() {
    let table: Vec<_> = stereo_board::app::TASKS
        .iter()
        .map(|t| (t.name, t.priority))
        .collect();
    check(
        "stereo-board",
        include_str!("../../stereo-board/src/firmware/mod.rs"),
        &table,
    );
}

#[test]
fn autopilot_firmware_mirrors_its_task_table() {
    let table: Vec<_> = autopilot::app::TASKS
        .iter()
        .map(|t| (t.name, t.priority))
        .collect();
    check(
        "autopilot",
        include_str!("../../autopilot/src/firmware/mod.rs"),
        &table,
    );
}
