//! Clock tree and link constants of both boards, per flavour.

use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::time::Hertz;

pub use crate::link::{HOST_BAUD, LINK_BAUD};

/// Core clock of this flavour, Hz: [`crate::chip::SYSCLK_HZ`] from the PLL on hardware; the
/// 16 MHz HSI in QEMU (QEMU 7.2 has no RCC model, so the HSE and PLL ready bits never come up).
#[cfg(not(feature = "qemu"))]
pub const CORE_HZ: u32 = crate::chip::SYSCLK_HZ;
/// Core clock of this flavour, Hz (see the hardware flavour).
#[cfg(feature = "qemu")]
pub const CORE_HZ: u32 = 16_000_000;

/// Clock of the SysTick (the RTIC monotonic), Hz: the core clock on hardware. QEMU 7.2 drives
/// the emulated SysTick from a fixed 168 MHz whatever the RCC says.
pub const SYSTICK_HZ: u32 = 168_000_000;

/// Clock configuration of this flavour for a board with an `hse_hz` crystal (unused in QEMU).
pub fn config(hse_hz: u32) -> Config {
    #[cfg(not(feature = "qemu"))]
    {
        Config::hse(Hertz::from_raw(hse_hz)).sysclk(Hertz::from_raw(CORE_HZ))
    }
    #[cfg(feature = "qemu")]
    {
        let _ = hse_hz;
        Config::hsi().sysclk(Hertz::from_raw(CORE_HZ))
    }
}
