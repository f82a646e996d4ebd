//! The clock tree as the firmware set it, read off RCC's registers (RM0090 rev 22 section 6.3):
//! what the bench needs to turn a peripheral's divider into a rate (a UART's baud, SPI's SCLK).

use rigless::mcu::Mcu;
use rigless::soc::stm32f427::generated::rcc::Register;
use rigless::soc::stm32f427::generated::{spi1, usart6};

use crate::soc::Soc;

/// The HSI, Hz (6.2.2).
pub const HSI_HZ: u64 = 16_000_000;

/// Bus clocks, Hz.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Clocks {
    /// SYSCLK.
    pub sysclk: u64,
    /// HCLK (AHB).
    pub hclk: u64,
    /// PCLK1 (APB1).
    pub pclk1: u64,
    /// PCLK2 (APB2).
    pub pclk2: u64,
}

impl Clocks {
    /// The tree as `soc`'s RCC registers set it, with a crystal of `hse_hz`.
    #[must_use]
    pub fn read(soc: &Soc, hse_hz: u64) -> Self {
        let rcc = soc.bus().registers("RCC").expect("the part has an RCC");
        let cfgr = rcc.get(Register::Cfgr);
        let pllcfgr = rcc.get(Register::Pllcfgr);
        let pll_in = if pllcfgr & (1 << 22) != 0 {
            hse_hz
        } else {
            HSI_HZ
        };
        let m = (pllcfgr & 0x3F).max(1);
        let n = (pllcfgr >> 6) & 0x1FF;
        let p = 2 * (((pllcfgr >> 16) & 3) + 1);
        let sysclk = match (cfgr >> 2) & 3 {
            1 => hse_hz,
            2 => pll_in / m * n / p,
            _ => HSI_HZ,
        };
        let hpre = (cfgr >> 4) & 0xF;
        let hclk = if hpre < 8 {
            sysclk
        } else {
            sysclk >> [1, 2, 3, 4, 6, 7, 8, 9][(hpre - 8) as usize]
        };
        let apb = |ppre: u64| if ppre < 4 { hclk } else { hclk >> (ppre - 3) };
        Self {
            sysclk,
            hclk,
            pclk1: apb((cfgr >> 10) & 7),
            pclk2: apb((cfgr >> 13) & 7),
        }
    }

    /// The baud a USART is set to (30.6.3 BRR, 30.3.4), `None` while disabled or unset.
    #[must_use]
    pub fn usart_baud(&self, soc: &Soc, instance: &str) -> Option<u32> {
        let registers = soc.bus().registers(instance)?;
        // SR, DR, BRR, CR1 are the first four rows of both of rigless's serial-port tables
        // (`usart6` and `uart4`), so one layout reads either.
        let brr = registers.get(usart6::Register::Brr) & 0xFFFF;
        let cr1 = registers.get(usart6::Register::Cr1);
        if cr1 & (1 << 13) == 0 || brr == 0 {
            return None;
        }
        let pclk = if matches!(instance, "USART1" | "USART6") {
            self.pclk2
        } else {
            self.pclk1
        };
        let over8 = cr1 & (1 << 15) != 0;
        let divider = if over8 {
            // USARTDIV = mantissa + fraction / 8, baud = pclk / (8 * USARTDIV).
            (brr >> 4) * 8 + (brr & 7)
        } else {
            brr
        };
        u32::try_from(pclk / divider.max(1)).ok()
    }

    /// SPI's SCLK (28.5.1 CR1.BR: PCLK / 2^(BR+1)), and whether CPOL/CPHA are mode 0 or 3.
    #[must_use]
    pub fn spi(&self, soc: &Soc, instance: &str) -> Option<(u64, bool)> {
        let registers = soc.bus().registers(instance)?;
        let cr1 = registers.get(spi1::Register::Cr1);
        let pclk = if matches!(instance, "SPI1" | "SPI4" | "SPI5" | "SPI6") {
            self.pclk2
        } else {
            self.pclk1
        };
        let sclk = pclk >> (((cr1 >> 3) & 7) + 1);
        let cpha = cr1 & 1;
        let cpol = (cr1 >> 1) & 1;
        Some((sclk, cpha == cpol))
    }
}
