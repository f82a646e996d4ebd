//! Test 1: both unmodified `real` images boot to their main loop on their boards.

use virtual_board::bench::{Options, Setup, Watching, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;

/// The status line each firmware's heartbeat task logs once a period, from its main loop.
const STATUS: &str = "status uptime_ms=";

#[test]
fn the_autopilot_boots_to_its_main_loop() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(1).expect("the board"),
            firmware,
            probe: Watching,
        },
        Options::seconds(2.5),
    )
    .expect("the run");
    println!("{}", outcome.report());
    outcome.assert_clean();
    let status = outcome
        .log
        .lines()
        .iter()
        .filter(|line| line.text.contains(STATUS))
        .count();
    assert!(
        status >= 2,
        "expected a status line every second, saw {status}\n{}",
        outcome.report()
    );
}
