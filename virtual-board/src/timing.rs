//! The bench's timing corners: how fast the emulated core retires instructions and how fast the
//! watchdog's oscillator (the LSI) runs, so a timing test states its margin at both ends.
//!
//! A Cortex-M4 at 168 MHz takes 1.1 to 1.5 cycles per instruction on our code
//! (`docs/performance.md`: flash wait states mostly hidden by the ART accelerator, loads and
//! branches costing more). rigless retires one instruction every 4 ns (250 M a second, one
//! cycle per instruction at 250 MHz), which is optimistic; [`CoreRate::Pessimistic`] is the
//! slow end, 1.5 cycles per instruction at 168 MHz. Peripherals keep their own clocks at
//! either rate (baud rates, timers, the sensors), so only the code gets slower.
//!
//! The LSI clocks the independent watchdog: 17 to 47 kHz on the STM32F4 (DS8626 table 41,
//! DS9405 table 42), 32 kHz typical, which is what rigless runs it at unless the board
//! calibrates it ([`crate::soc::Soc::set_lsi_hz`]).

use std::num::NonZeroU64;

/// The core clock of both boards, Hz (RM0090 section 6.2: 168 MHz from the PLL).
pub const CORE_HZ: u64 = 168_000_000;

/// The slowest LSI the STM32F4's datasheets give, Hz (DS8626 table 41, DS9405 table 42).
pub const LSI_HZ_SLOWEST: u64 = 17_000;
/// The typical LSI, Hz: what the firmware's watchdog timeout is computed at, and what rigless
/// runs the LSI at unless told otherwise.
pub const LSI_HZ_TYPICAL: u64 = 32_000;
/// The fastest LSI the datasheets give, Hz.
pub const LSI_HZ_FASTEST: u64 = 47_000;

/// How fast the emulated core retires instructions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoreRate {
    /// rigless's rate: one instruction every 4 ns (250 M instructions per second).
    #[default]
    Default,
    /// 168 MHz at 1.5 cycles per instruction: 112 M instructions per second, 8.93 ns each.
    Pessimistic,
}

impl CoreRate {
    /// Both rates, the default first.
    pub const ALL: [Self; 2] = [Self::Default, Self::Pessimistic];

    /// Instructions retired per second of virtual time.
    #[must_use]
    pub fn instructions_per_second(self) -> NonZeroU64 {
        match self {
            Self::Default => rigless::machine::armv7m::INSTRUCTIONS_PER_SECOND,
            // 168 MHz / 1.5 = 112 MHz, exactly.
            Self::Pessimistic => NonZeroU64::new(CORE_HZ * 2 / 3).expect("a running core"),
        }
    }

    /// Nanoseconds one instruction takes.
    #[must_use]
    pub fn ns_per_instruction(self) -> f64 {
        1e9 / self.instructions_per_second().get() as f64
    }

    /// A short name for test output: `"4.00 ns/insn"`, `"8.93 ns/insn"`.
    #[must_use]
    pub fn label(self) -> String {
        format!("{:.2} ns/insn", self.ns_per_instruction())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pessimistic_rate_is_one_and_a_half_cycles_at_168_mhz() {
        let ns = CoreRate::Pessimistic.ns_per_instruction();
        assert!((ns - 1.5e9 / 168e6).abs() < 1e-9, "{ns}");
        assert!((CoreRate::Default.ns_per_instruction() - 4.0).abs() < 1e-12);
    }
}
