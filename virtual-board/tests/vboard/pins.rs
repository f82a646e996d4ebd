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

/// A still scene for the camera: a horizontal gradient, the same in both sensors.
fn still_scene() -> virtual_board::frames::Recorded {
    use virtual_board::frames::{Recorded, STEREO_BYTES, StereoImage, WIDTH};
    let mut frame = [0u8; STEREO_BYTES];
    for (i, byte) in frame.iter_mut().enumerate() {
        *byte = ((i / 2 % WIDTH) * 2) as u8;
    }
    Recorded::new(vec![StereoImage::from_interleaved(&frame); 40])
}

/// The camera board: every pin as the stereoboard's wiring
/// table, and what the bench can observe of each job: the sensors' master clock on PA7 from
/// TIM3 CH2 at 21 MHz, their reset on PD2 released, the CPLD's mode pins at the stereo
/// interleave, the DCMI's data lines D6/D7 on PB8/PB9, UART4 on PA0/PA1 at 115,200 Bd, the LED
/// on PB12; and, the proof the set-up is the one a working camera needs, frames captured.
#[test]
fn the_camera_board_configures_exactly_its_boards_wiring() {
    use virtual_board::boards::camera::{
        self, CPLD_MODE, CPLD_STEREO_LEVELS, CameraBoard, LINK_BAUD, SENSOR_CLOCK_HZ, SENSOR_RESET,
    };
    let firmware = Firmware::real("stereo-board").expect("the camera-board image");
    let board = CameraBoard::new(Box::new(still_scene())).expect("the board");
    let outcome = run(
        Setup {
            board,
            firmware,
            probe: Watching,
        },
        // The camera's bring-up and a few frames at 40.5 ms each.
        Options::seconds(0.8),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let board = outcome.board();
    let problems = pins::check(&board.soc, &camera::WIRING);
    assert!(
        problems.is_empty(),
        "the camera board's pins differ from the stereoboard's wiring:\n  {}\n{report}",
        problems.join("\n  ")
    );
    // D6 and D7 where the board wires them (and so not on PE5/PE6, which the check above
    // would report as driven).
    for (bit, (port, pin)) in [(6, ("GPIOB", 8)), (7, ("GPIOB", 9))] {
        let now = pins::configured(&board.soc, port, pin).expect("the port");
        assert_eq!(
            now.mode,
            pins::Mode::Alternate(camera::AF_DCMI),
            "DCMI D{bit} on {}\n{report}",
            pins::name(port, pin)
        );
    }
    let clock = board.sensor_clock_hz();
    assert_eq!(
        clock,
        Some(SENSOR_CLOCK_HZ),
        "the sensors' master clock on PA7 (TIM3 CH2)\n{report}"
    );
    assert_eq!(
        board.output_level(SENSOR_RESET),
        Some(true),
        "the sensors' reset PD2 released (driven high)\n{report}"
    );
    let levels = CPLD_MODE.map(|p| board.output_level(p));
    assert_eq!(
        levels,
        CPLD_STEREO_LEVELS.map(Some),
        "the CPLD's mode pins PC10, PC12, PB5\n{report}"
    );
    let baud = board
        .clocks
        .and_then(|c| c.usart_baud(&board.soc, "UART4"))
        .unwrap_or_else(|| panic!("UART4 is not running\n{report}"));
    let error = (f64::from(baud) - f64::from(LINK_BAUD)).abs() / f64::from(LINK_BAUD);
    assert!(
        error < 0.01,
        "UART4 at {baud} Bd, the link runs at {LINK_BAUD}\n{report}"
    );
    assert!(
        pins::configured(&board.soc, camera::LED.port, camera::LED.pin)
            .is_some_and(|c| c.mode == pins::Mode::Output),
        "the LED on PB12 is an output\n{report}"
    );
    println!(
        "camera board: master clock {} Hz on PA7, UART4 {baud} Bd, {} frames captured",
        clock.unwrap_or(0),
        board.captured().len()
    );
    assert!(
        !board.captured().is_empty(),
        "the sensors streamed once set up: no frame captured\n{report}\ndcmi {:?}",
        board.dcmi_stats()
    );
}
