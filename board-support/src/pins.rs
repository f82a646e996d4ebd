//! The vocabulary of both boards' wiring tables: a pin, what it is set to, its pull, and the
//! output stage where a board states one (RM0090 section 8.4: MODER, OTYPER, OSPEEDR, PUPDR,
//! AFRL/AFRH). Plain data, so the tables are read on the host too (tests, docs).
//!
//! A row's [`PinAssignment::drive`] and [`PinAssignment::speed`] are `None` where the board
//! leaves the output stage to the driver that takes the pin (the autopilot's HAL drivers);
//! the camera board, which sets every pin from its table, states both.

/// A GPIO port of the STM32F405/407/415.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Port {
    /// GPIOA.
    A,
    /// GPIOB.
    B,
    /// GPIOC.
    C,
    /// GPIOD.
    D,
    /// GPIOE.
    E,
}

impl Port {
    /// Index of the port (A = 0): its GPIO block sits at `0x4002_0000 + 0x400 * index` and its
    /// clock-enable bit in RCC_AHB1ENR is bit `index`.
    pub const fn index(self) -> u8 {
        match self {
            Port::A => 0,
            Port::B => 1,
            Port::C => 2,
            Port::D => 3,
            Port::E => 4,
        }
    }

    /// The port letter.
    pub const fn letter(self) -> char {
        match self {
            Port::A => 'A',
            Port::B => 'B',
            Port::C => 'C',
            Port::D => 'D',
            Port::E => 'E',
        }
    }
}

/// One pin: port and number 0..=15.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pin {
    /// Port.
    pub port: Port,
    /// Pin number, 0..=15.
    pub number: u8,
}

/// The pin `number` of `port`.
pub const fn pin(port: Port, number: u8) -> Pin {
    Pin { port, number }
}

/// What a pin is set to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Function {
    /// Alternate function `af` (0..=15, the datasheet's alternate-function table).
    Alternate(u8),
    /// General-purpose output, driven to `high` before the pin is switched to output.
    Output {
        /// Level at start-up.
        high: bool,
    },
}

/// Output driver of a pin (OTYPER).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    /// Push-pull.
    PushPull,
    /// Open drain (external pull-up).
    OpenDrain,
}

/// Internal pull resistor of a pin (PUPDR).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pull {
    /// None.
    None,
    /// Pull-up.
    Up,
}

/// Output speed (slew rate) of a pin, as the OSPEEDR codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Speed {
    /// 2 MHz (code 0).
    Low,
    /// 100 MHz (code 3).
    VeryHigh,
}

/// One row of a wiring table: a pin the firmware configures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PinAssignment {
    /// The signal on the pin.
    pub signal: &'static str,
    /// The pin.
    pub pin: Pin,
    /// Mode and alternate function.
    pub function: Function,
    /// Pull resistor.
    pub pull: Pull,
    /// Output driver (`None`: the driver that takes the pin sets it).
    pub drive: Option<Drive>,
    /// Output speed (`None`: the driver that takes the pin sets it).
    pub speed: Option<Speed>,
    /// Where the fact comes from.
    pub source: &'static str,
}
