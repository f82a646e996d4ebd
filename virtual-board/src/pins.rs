//! A board's wiring table, and the check of a firmware's pin configuration against it.
//!
//! Each row is one pin the board's wiring gives a job, with the configuration that job needs
//! (RM0090 section 8.3: mode, alternate function per the datasheet's table 9, pull, output
//! type where the board needs one). [`check`] reads every port of a running part and reports each pin configured unlike
//! its row, each row not configured at all, and each pin outside the table that the firmware
//! drives (output or alternate function) or otherwise moved from its reset state.

use rigless::mcu::Mcu;
use rigless::soc::stm32f427::generated::gpioa::Register;
use rigless::soc::stm32f427::peripherals::PORTS;

use crate::soc::Soc;

/// A pin's mode (MODER).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Input (00).
    Input,
    /// General-purpose output (01).
    Output,
    /// Alternate function `n` (10, AFRL/AFRH = n).
    Alternate(u8),
    /// Analog (11).
    Analog,
}

/// A pull (PUPDR).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pull {
    /// Neither.
    None,
    /// Pull-up.
    Up,
    /// Pull-down.
    Down,
}

/// One pin of a wiring table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wired {
    /// `GPIOA`...
    pub port: &'static str,
    /// 0..=15.
    pub pin: u8,
    /// What the board uses it for.
    pub function: &'static str,
    /// The mode the job needs.
    pub mode: Mode,
    /// The pull it needs (`None`: the sources leave it open, any pull is accepted).
    pub pull: Option<Pull>,
    /// Whether its output is open drain (`Some(true)`) or push-pull (`Some(false)`); `None`:
    /// the sources leave it open, either is accepted.
    pub open_drain: Option<bool>,
    /// Whether it may stay unconfigured (at reset) without failing the check: an LED, a
    /// spare UART.
    pub optional: bool,
}

/// A pin as the firmware left it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Configured {
    /// The mode.
    pub mode: Mode,
    /// The pull.
    pub pull: Pull,
    /// Open drain (OTYPER).
    pub open_drain: bool,
}

/// Pins the part itself configures out of reset (RM0090 8.3.1): the SWD/JTAG pins PA13, PA14,
/// PA15, PB3, PB4 in AF0 with their pulls.
const DEBUG_PINS: [(&str, u8); 5] = [
    ("GPIOA", 13),
    ("GPIOA", 14),
    ("GPIOA", 15),
    ("GPIOB", 3),
    ("GPIOB", 4),
];

/// How `port`'s `pin` is configured now.
#[must_use]
pub fn configured(soc: &Soc, port: &str, pin: u8) -> Option<Configured> {
    let registers = soc.bus().registers(port)?;
    let field = |register: Register, bits: u32| {
        (registers.get(register) >> (bits * u32::from(pin))) & ((1 << bits) - 1)
    };
    let mode = match field(Register::Moder, 2) {
        0 => Mode::Input,
        1 => Mode::Output,
        2 => {
            let (register, index) = if pin < 8 {
                (Register::Afrl, pin)
            } else {
                (Register::Afrh, pin - 8)
            };
            Mode::Alternate(((registers.get(register) >> (4 * u32::from(index))) & 0xF) as u8)
        }
        _ => Mode::Analog,
    };
    let pull = match field(Register::Pupdr, 2) {
        1 => Pull::Up,
        2 => Pull::Down,
        _ => Pull::None,
    };
    Some(Configured {
        mode,
        pull,
        open_drain: field(Register::Otyper, 1) == 1,
    })
}

/// Every departure of the running part's pins from `table`, as readable lines; empty when the
/// firmware configured exactly the table.
#[must_use]
pub fn check(soc: &Soc, table: &[Wired]) -> Vec<String> {
    let mut problems = Vec::new();
    for row in table {
        let Some(now) = configured(soc, row.port, row.pin) else {
            problems.push(format!("{}: no such port", name(row.port, row.pin)));
            continue;
        };
        let debug = DEBUG_PINS.contains(&(row.port, row.pin));
        let at_reset = (now.mode == Mode::Input && now.pull == Pull::None)
            || (debug && now.mode == Mode::Alternate(0));
        if row.optional && at_reset {
            continue;
        }
        if now.mode != row.mode {
            problems.push(format!(
                "{} ({}): mode {:?}, the board needs {:?}",
                name(row.port, row.pin),
                row.function,
                now.mode,
                row.mode
            ));
        }
        if let Some(pull) = row.pull
            && now.pull != pull
        {
            problems.push(format!(
                "{} ({}): pull {:?}, the board needs {:?}",
                name(row.port, row.pin),
                row.function,
                now.pull,
                pull
            ));
        }
        if let Some(open_drain) = row.open_drain
            && now.open_drain != open_drain
        {
            let kind = |od: bool| if od { "open drain" } else { "push-pull" };
            problems.push(format!(
                "{} ({}): {}, the board needs {}",
                name(row.port, row.pin),
                row.function,
                kind(now.open_drain),
                kind(open_drain)
            ));
        }
    }
    for port in PORTS.iter().take(9) {
        for pin in 0..16u8 {
            if table.iter().any(|row| row.port == *port && row.pin == pin)
                || DEBUG_PINS.contains(&(*port, pin))
            {
                continue;
            }
            let Some(now) = configured(soc, port, pin) else {
                continue;
            };
            match now.mode {
                Mode::Output | Mode::Alternate(_) => problems.push(format!(
                    "{}: driven ({:?}) but the board wires nothing there to drive",
                    name(port, pin),
                    now.mode
                )),
                Mode::Input | Mode::Analog => {}
            }
        }
    }
    problems
}

/// `GPIOB`, 12 -> `PB12`.
#[must_use]
pub fn name(port: &str, pin: u8) -> String {
    format!("P{}{pin}", port.strip_prefix("GPIO").unwrap_or(port))
}
