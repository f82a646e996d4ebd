//! The core clock both boards' parts run at on hardware, readable on the host by the boards'
//! clock tables. The clock a firmware flavour runs at is `clocks::CORE_HZ`, on the target.

/// Core clock of both boards on hardware, Hz: the 12 MHz crystal through the PLL, HSE / M=12 x
/// N=336 / P=2, the STM32F405/407's top speed. The camera board's
/// (\[SB\] system_stm32f4xx.c:149-150) and the Lisa/MX's (\[PZ\] lisa_mx_common.h:29-30).
pub const SYSCLK_HZ: u32 = 168_000_000;
