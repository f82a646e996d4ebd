//! The system configuration controller, RM0090 rev 22 section 9 (rigless has no model for it).
//!
//! | Register | Behaviour | Source |
//! |---|---|---|
//! | `MEMRM`, `PMC` | stored (the memory remap and the Ethernet PHY interface select are not acted on) | 9.2.1, 9.2.2 |
//! | `EXTICR1..4` | stored; [`Syscfg::port_of_line`] says which port drives each EXTI line 0..15 | 9.2.3-9.2.6 |
//! | `CMPCR` | `CMP_PD` (bit 0) stored, `READY` (bit 8) follows it at once | 9.2.7 |
//!
//! Left out: the compensation cell's settling time (`READY` is immediate) and the remap itself.
//!
//! It also answers the stores into the reserved space below SRAM ([`crate::soc::RESERVED_BELOW_SRAM`])
//! with a bus error: rigless sends a region's stores to one instance's model, and this is the
//! model we own that has nothing else to do with them.

use rigless::device::{Device, DeviceContext, RegisterFile};
use rigless::soc::stm32f427::generated::syscfg::Register;

/// The SYSCFG's model: the registers are its whole state.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Syscfg;

impl Syscfg {
    /// The port (0 = A, 1 = B, ...) that `EXTICR` routes to EXTI `line` (0..=15).
    #[must_use]
    pub fn port_of_line(line: u32, registers: &RegisterFile) -> Option<usize> {
        let register = match line {
            0..=3 => Register::Exticr1,
            4..=7 => Register::Exticr2,
            8..=11 => Register::Exticr3,
            12..=15 => Register::Exticr4,
            _ => return None,
        };
        let shift = 4 * (line % 4);
        usize::try_from((registers.get(register) >> shift) & 0xF).ok()
    }
}

/// `CMPCR.CMP_PD` and `CMPCR.READY`, 9.2.7.
const CMP_PD: u64 = 1;
const READY: u64 = 1 << 8;

impl Device for Syscfg {
    type Register = Register;

    /// A store into the reserved space below SRAM: the bus answers it with an error.
    fn write_region(
        &mut self,
        _address: u64,
        _width: rigless::soc::Width,
        _value: u64,
        _registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> bool {
        context.bus_error();
        true
    }

    fn write(
        &mut self,
        register: Register,
        value: u64,
        registers: &mut RegisterFile,
        _context: &mut DeviceContext<'_>,
    ) {
        if register == Register::Cmpcr {
            // ST's file makes the whole register read-only; the manual has CMP_PD read-write.
            let on = value & CMP_PD;
            registers.set(Register::Cmpcr, on | if on != 0 { READY } else { 0 });
        }
    }
}
