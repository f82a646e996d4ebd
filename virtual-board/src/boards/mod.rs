//! The two boards, each wired as its original (`../shared/hardware/original-boards.md`).

pub mod autopilot;
pub mod camera;

use std::num::{NonZeroU32, NonZeroU64};

use rigless::machine::{Target, armv7m};
use rigless::mcu::{Mcu, Operate};

use crate::soc::Soc;

/// The Cortex-M4F core of both parts at 168 MHz (RM0090 section 6.2; PM0214 for the core: FPv4-SP,
/// eight MPU regions, four priority bits), as rigless runs it, at the SoC's
/// [`crate::timing::CoreRate`].
pub(crate) fn target<'a>(name: &'static str, soc: &'a mut Soc) -> Target<'a> {
    let core = armv7m::Core {
        variant: armv7m::Variant::M4,
        clock_hz: NonZeroU64::new(168_000_000).expect("a running clock"),
        interrupt_lines: NonZeroU32::new(u32::from(soc.cpu().interrupt_lines))
            .expect("a part with interrupts"),
        priority_bits: 4,
        // SysTick's external reference is HCLK / 8 (RM0090 figure 21).
        refclk_divider: NonZeroU32::new(8).expect("a divider divides"),
        instructions_per_second: soc.core_rate.instructions_per_second(),
        boot: "flash",
    }
    .spec_with_parts(
        &rigless::cpu::armv7m::windows(soc.bus()),
        armv7m::Fpu::FpV4Sp,
        armv7m::MpuRegions::Eight,
    );
    Target::new(name, soc, core)
}
