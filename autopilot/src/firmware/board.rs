//! Pin map and clock tree of the autopilot (Lisa-MX-class STM32F405), per flavour.
//!
//! | function | peripheral | pins |
//! |---|---|---|
//! | link to the camera board (protocol, 921,600 Bd 8N1) | USART1 | PA9 TX, PA10 RX |
//! | telemetry / HIL host link (IMU in, motors out) | USART2 | PA2 TX, PA3 RX |
//! | status LED (active high) | GPIO | PC13 |
//! | IMU MPU-6000 (SPI mode 3) | SPI1 | PA5 SCK, PA6 MISO, PA7 MOSI, PA4 CS |
//! | IMU data ready (MPU-6000 INT, rising edge) | EXTI4 | PC4 |
//! | RC receiver, SBUS (100,000 Bd 8E2, non-inverted) | USART3 RX | PB11 |
//! | motors 1-4 (FR, RR, RL, FL), 32 kHz PWM | TIM3 CH1-4 | PB4, PB5, PB0, PB1 |
//!
//! Wiring between the boards: autopilot PA9 (TX) -> camera PA10 (RX), autopilot PA10 (RX) <-
//! camera PA9 (TX), common ground. In QEMU (`-M netduinoplus2`) USART1 is the first `-serial` and USART2 the
//! second.

use stm32f4xx_hal::rcc::Config;

pub use board_support::clocks::{LINK_BAUD, SYSTICK_HZ, WATCHDOG_MS};

/// Crystal of the autopilot (12 MHz on the Lisa/MX), Hz.
pub const HSE_HZ: u32 = 12_000_000;

/// Clock configuration of this flavour (HSE + PLL to 168 MHz; the HSI in QEMU).
pub fn clocks() -> Config {
    board_support::clocks::config(HSE_HZ)
}

/// Rate of the TIM2 fallback timer, Hz (real flavour): it reads the IMU itself only while the
/// MPU-6000's data-ready interrupt (500 Hz) is missing. In HIL and QEMU the host's IMU samples
/// pace the loop.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub const IMU_RATE_HZ: u32 = 512;

/// The data-ready interrupt counts as missing after this long without one, µs (2.5 sample
/// periods of the 500 Hz IMU).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub const IMU_DRDY_TIMEOUT_US: u32 = 5_000;
