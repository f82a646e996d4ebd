//! Test 6: every pin the firmware configures matches its board's wiring table (mode, alternate
//! function, pull), and no pin outside the table is driven.

use virtual_board::bench::{Options, Setup, Watching, run};
use virtual_board::boards::autopilot::{Autopilot, WIRING};
use virtual_board::firmware::Firmware;
use virtual_board::pins;

#[test]
fn the_autopilot_configures_exactly_its_boards_wiring() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(2).expect("the board"),
            firmware,
            probe: Watching,
        },
        // Long enough for every task's set-up (and the first status line).
        Options::seconds(1.2),
    )
    .expect("the run");
    let problems = pins::check(&outcome.board().soc, &WIRING);
    assert!(
        problems.is_empty(),
        "the autopilot's pins differ from the Lisa/MX wiring:\n  {}\n{}",
        problems.join("\n  "),
        outcome.report()
    );
}
