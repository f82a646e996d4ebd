//! The external interrupt/event controller, RM0090 rev 22 section 12.2 and 12.3 (rigless has no
//! model for it).
//!
//! | Register | Behaviour | Source |
//! |---|---|---|
//! | `IMR`, `EMR`, `RTSR`, `FTSR` | stored; `IMR` gates a line's pending bit and interrupt | 12.3.1-12.3.4, figure 41 |
//! | `SWIER` | writing 1 to a bit at 0 sets the line's pending bit (while `IMR` has it); cleared with the pending bit | 12.3.5 |
//! | `PR` | set by a selected edge on an unmasked line, cleared by writing 1 (rc_w1) | 12.3.6 |
//! | interrupts | EXTI0..4 each their own line, EXTI9_5 and EXTI15_10 shared, line 21 (tamper/time stamp): the positions of rigless's table for the instance (IRQ 2, 6-10, 23, 40) | table 61, 12.2.5 |
//! | inputs | [`Exti::drive_line`]: the level of a GPIO pin the board drives, routed by SYSCFG `EXTICR` ([`crate::soc::Soc::drive_exti`]) | 12.2.5, 9.2.3 |
//!
//! Left out: the event outputs (`EMR` is stored, no event reaches the core: WFE wake-ups by
//! event are not modelled) and the internal lines 16-22 other than their pending bits.

use rigless::device::{Device, DeviceContext, Level, RegisterFile};
use rigless::soc::stm32f427::generated::exti::Register;

/// Lines with an input: 0..=22 (RM0090 12.2.5: 16 GPIO lines and 7 internal ones).
pub const LINES: u32 = 23;
const LINE_MASK: u32 = (1 << LINES) - 1;

/// The EXTI's state beyond its registers: each line's last input level, and the pending bits
/// (the truth of `PR`, which the register file would otherwise overwrite with a write's value).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Exti {
    levels: u32,
    pending: u32,
}

impl Exti {
    /// The level on input `line` at the context's instant: a selected edge of an unmasked line
    /// sets its pending bit and raises its interrupt.
    pub fn drive_line(
        &mut self,
        line: u32,
        level: Level,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        if line >= LINES {
            return;
        }
        let bit = 1u32 << line;
        let was_high = self.levels & bit != 0;
        let high = level == Level::High;
        if high {
            self.levels |= bit;
        } else {
            self.levels &= !bit;
        }
        let rising = high && !was_high;
        let falling = !high && was_high;
        let selected = (rising && reg(registers, Register::Rtsr) & bit != 0)
            || (falling && reg(registers, Register::Ftsr) & bit != 0);
        if selected && reg(registers, Register::Imr) & bit != 0 {
            self.pending |= bit;
            self.publish(registers, context);
        }
    }

    /// Pending lines (the `PR` bits).
    #[must_use]
    pub fn pending(&self) -> u32 {
        self.pending
    }

    fn publish(&self, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        registers.set(Register::Pr, u64::from(self.pending));
        let active = self.pending & reg(registers, Register::Imr);
        let mut levels = [false; 8];
        for line in 0..LINES {
            if active & (1 << line) != 0
                && let Some(position) = position_of(line)
            {
                levels[position] = true;
            }
        }
        for (position, high) in levels.into_iter().enumerate() {
            context.interrupt(position, Level::from(high));
        }
    }
}

fn reg(registers: &RegisterFile, register: Register) -> u32 {
    // 32-bit registers, kept in a u64 by the file.
    (registers.get(register) & u64::from(u32::MAX)) as u32
}

/// The interrupt positions of the instance in rigless's table, in order: line 21, EXTI0..4,
/// EXTI9_5, EXTI15_10.
fn position_of(line: u32) -> Option<usize> {
    match line {
        0..=4 => Some(1 + line as usize),
        5..=9 => Some(6),
        10..=15 => Some(7),
        21 => Some(0),
        _ => None,
    }
}

impl Device for Exti {
    type Register = Register;

    fn write(
        &mut self,
        register: Register,
        value: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        let value = (value as u32) & LINE_MASK;
        match register {
            Register::Pr => {
                self.pending &= !value;
                let swier = reg(registers, Register::Swier) & !value;
                registers.set(Register::Swier, u64::from(swier));
            }
            Register::Swier => {
                self.pending |= value & reg(registers, Register::Imr);
            }
            _ => {}
        }
        self.publish(registers, context);
    }

    fn reset(&mut self) {
        self.levels = 0;
        self.pending = 0;
    }
}
