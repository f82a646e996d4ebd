//! Our SoC type: rigless's STM32F427 with the models it lacks, as the part a board really carries.
//!
//! rigless 0.4.0 models an STM32F427 (RM0090 rev 22). The boards carry an STM32F407 (camera
//! board) and an STM32F415 (autopilot), both of which the F427 is a superset of (RM0090 section
//! 1 and table 1 of each datasheet: DS8626 for the F405/F407, DS8597 for the F415/F417, DS9405
//! for the F427). [`Soc`] holds rigless's [`Stm32f427`] and, beside it, our models for the slots
//! it leaves without one: [`Exti`], [`Syscfg`] and the
//! camera board's [`Dcmi`]. It implements [`Mcu`] by answering those slots
//! itself and handing every other to the F427.
//!
//! DMA2 gets the wiring of RM0090 table 44 with the DCMI's request on channel 1 of streams 1 and
//! 7 (rigless's table leaves the DCMI out, having no model for it).
//!
//! [`Part`] says what the real part lacks: [`Part::lacks`] names the F427 instances it does not
//! have, [`Part::memory`] its flash, SRAM and CCM. The bench fails a run that reaches one of those
//! instances ([`crate::bench`] checks every peripheral access) or stores outside the part's SRAM,
//! and refuses an image placed outside the part's flash and RAM.

use rigless::device::{ErasedDevice, ResetCause};
use rigless::mcu::Mcu;
use rigless::snapshot::Store;
use rigless::soc::stm32f427::Stm32f427;
use rigless::soc::stm32f427::peripherals::dma::{Dma, Wire};
use rigless::soc::stm32f427::peripherals::{adc, sdio, spi, usart};
use rigless::soc::{Bus, Error};
use rigless::time::VirtualNanos;

use crate::clock_timer::ClockTimer;
use crate::dcmi::Dcmi;
use crate::exti::Exti;
use crate::syscfg::Syscfg;

/// The reserved space just below SRAM (RM0090 table 1 / DS8626 figure 18: nothing between the
/// option bytes, 0x1FFF_C000-0x1FFF_C00F, and SRAM at 0x2000_0000), which rigless leaves
/// unmapped (a store there lands nowhere and the core goes on). On the part the bus matrix
/// answers it with an error; here a store into it is a bus error too (the [`Syscfg`] model
/// answers it), which is what makes a stack that runs off the bottom of SRAM fault, as flip-link
/// relies on. Reads there are not refused (the region reads as erased memory).
pub const RESERVED_BELOW_SRAM: rigless::soc::Region = rigless::soc::Region::flash(
    "reserved below SRAM",
    0x1FFF_C010,
    0x2000_0000 - 0x1FFF_C010,
)
.programmed_by("SYSCFG");

/// The part a board carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// STM32F407VG, the camera board (DS8626).
    Stm32f407,
    /// STM32F415RG, the autopilot (DS8597): an F405 with the crypto processor.
    Stm32f415,
}

/// One memory range of a part, bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Range {
    /// What it is.
    pub name: &'static str,
    /// First address.
    pub base: u64,
    /// Length, bytes.
    pub size: u64,
}

impl Range {
    /// Whether `[address, address + len)` lies inside this range.
    #[must_use]
    pub fn holds(&self, address: u64, len: u64) -> bool {
        address >= self.base && address.saturating_add(len) <= self.base + self.size
    }
}

/// F427 instances none of the boards' parts has (DS9405 table 2 against DS8626 / DS8597 table 2).
const NOT_ON_F40X: [&str; 8] = [
    "UART7", "UART8", "SPI4", "SPI5", "SPI6", "SAI1", "DMA2D", "GPIOJ",
];
/// GPIOK is also F42x only.
const NOT_ON_F40X_PORTS: [&str; 1] = ["GPIOK"];
/// The F407 has no crypto processor or hash (those are the F415/F417's).
const NOT_ON_F407: [&str; 2] = ["CRYP", "HASH"];
/// The F405/F415 has no camera interface and no Ethernet MAC (DS8597 table 2).
const NOT_ON_F415: [&str; 5] = [
    "DCMI",
    "Ethernet_MAC",
    "Ethernet_MMC",
    "Ethernet_PTP",
    "Ethernet_DMA",
];

impl Part {
    /// Whether the real part lacks the F427 instance `name`.
    #[must_use]
    pub fn lacks(self, name: &str) -> bool {
        let eq = |other: &&str| other.eq_ignore_ascii_case(name);
        NOT_ON_F40X.iter().any(eq)
            || NOT_ON_F40X_PORTS.iter().any(eq)
            || match self {
                Self::Stm32f407 => NOT_ON_F407.iter().any(eq),
                Self::Stm32f415 => NOT_ON_F415.iter().any(eq),
            }
    }

    /// The part's memory (RM0090 section 2.3 and table 1 of each datasheet): 1 MiB of flash,
    /// 112 + 16 KiB of SRAM1/SRAM2 and 64 KiB of CCM. The F427 adds a second flash MiB and
    /// SRAM3 (64 KiB at `0x2002_0000`).
    #[must_use]
    pub fn memory(self) -> [Range; 3] {
        [
            Range {
                name: "flash",
                base: 0x0800_0000,
                size: 1 << 20,
            },
            Range {
                name: "sram",
                base: 0x2000_0000,
                size: 128 << 10,
            },
            Range {
                name: "ccm",
                base: 0x1000_0000,
                size: 64 << 10,
            },
        ]
    }

    /// The F427 memory this part does not have and a store into which fails the run.
    #[must_use]
    pub fn missing_ram(self) -> Range {
        Range {
            name: "SRAM3 (F42x only)",
            base: 0x2002_0000,
            size: 64 << 10,
        }
    }

    /// The part's name as its datasheet gives it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Stm32f407 => "STM32F407VG",
            Self::Stm32f415 => "STM32F415RG",
        }
    }
}

/// The request the DCMI drives for its DMA stream (RM0090 section 15.4: one request per word of
/// the FIFO).
pub const DCMI_REQUEST: usize = 0;

/// RM0090 rev 22 table 44 (DMA2 request mapping) for the instances our parts have and rigless
/// or we model: the converters, USART1, USART6, SDIO, SPI1 and the DCMI (channel 1, streams 1
/// and 7). Timer requests are left out, as rigless leaves them.
static DMA2_REQUESTS: [Wire; 11] = [
    Wire {
        instance: "ADC1",
        request: adc::DMA_REQUEST,
        channel: 0,
        streams: &[0, 4],
    },
    Wire {
        instance: "DCMI",
        request: DCMI_REQUEST,
        channel: 1,
        streams: &[1, 7],
    },
    Wire {
        instance: "ADC2",
        request: adc::DMA_REQUEST,
        channel: 1,
        streams: &[2, 3],
    },
    Wire {
        instance: "ADC3",
        request: adc::DMA_REQUEST,
        channel: 2,
        streams: &[0, 1],
    },
    Wire {
        instance: "SPI1",
        request: spi::RECEIVE_REQUEST,
        channel: 3,
        streams: &[0, 2],
    },
    Wire {
        instance: "SPI1",
        request: spi::TRANSMIT_REQUEST,
        channel: 3,
        streams: &[3, 5],
    },
    Wire {
        instance: "USART1",
        request: usart::RECEIVE_REQUEST,
        channel: 4,
        streams: &[2, 5],
    },
    Wire {
        instance: "USART1",
        request: usart::TRANSMIT_REQUEST,
        channel: 4,
        streams: &[7],
    },
    Wire {
        instance: "SDIO",
        request: sdio::TRANSFER_REQUEST,
        channel: 4,
        streams: &[3, 6],
    },
    Wire {
        instance: "USART6",
        request: usart::RECEIVE_REQUEST,
        channel: 5,
        streams: &[1, 2],
    },
    Wire {
        instance: "USART6",
        request: usart::TRANSMIT_REQUEST,
        channel: 5,
        streams: &[6, 7],
    },
];

/// Section 10.3.15: the card interface's last-data signal, on channel 4 of streams 3 and 6.
static DMA2_LAST_DATA: [Wire; 1] = [Wire {
    instance: "SDIO",
    request: sdio::LAST_DATA_REQUEST,
    channel: 4,
    streams: &[3, 6],
}];

/// The SoC of one board: rigless's F427 models and ours, as the part [`Soc::part`] says.
#[derive(Debug)]
pub struct Soc {
    /// The part the board really carries.
    pub part: Part,
    /// How fast its core retires instructions ([`crate::timing`]).
    pub core_rate: crate::timing::CoreRate,
    /// rigless's STM32F427: clock tree, ports, serial ports and interfaces, timers, DMA, IWDG...
    pub mcu: Stm32f427,
    /// The external interrupt controller, RM0090 section 12.
    pub exti: Exti,
    /// The system configuration controller, RM0090 section 9.
    pub syscfg: Syscfg,
    /// The camera interface, RM0090 section 15 (unused on the F415: any access fails the run).
    pub dcmi: Dcmi,
    /// A general-purpose timer the board uses as a clock generator, taken out of [`Soc::mcu`]
    /// (see [`Soc::use_as_clock`]): its bus slot and its model.
    pub clock_timer: Option<(usize, ClockTimer)>,
    slots: Slots,
}

#[derive(Debug, Clone, Copy)]
struct Slots {
    exti: usize,
    syscfg: usize,
    dcmi: usize,
    i2c2: usize,
}

impl Soc {
    /// Runs the core at `rate` from the next run on.
    pub fn set_core_rate(&mut self, rate: crate::timing::CoreRate) {
        self.core_rate = rate;
    }

    /// Calibrates the part's LSI to `hz` (kept across resets, as the oscillator is the part's).
    ///
    /// # Panics
    /// `hz` outside [`crate::timing::LSI_HZ_SLOWEST`]..=[`crate::timing::LSI_HZ_FASTEST`] (rigless refuses it).
    pub fn set_lsi_hz(&mut self, hz: u64) {
        self.mcu.rcc.calibrate_lsi(hz);
    }
}

impl Store for Soc {}

impl Soc {
    /// A part fresh out of reset, with no crystal, rail or chips: those are the board's.
    ///
    /// # Errors
    /// Only if rigless's own description fails to assemble.
    pub fn new(part: Part) -> Result<Self, Error> {
        let mut mcu = Stm32f427::new()?;
        mcu.dma[1] = dma2();
        mcu.bus_mut().add_region(RESERVED_BELOW_SRAM)?;
        let bus = mcu.bus();
        let slots = Slots {
            exti: bus.slot("EXTI")?,
            syscfg: bus.slot("SYSCFG")?,
            dcmi: bus.slot("DCMI")?,
            i2c2: bus.slot("I2C2")?,
        };
        Ok(Self {
            part,
            core_rate: crate::timing::CoreRate::Default,
            mcu,
            exti: Exti::default(),
            syscfg: Syscfg,
            dcmi: Dcmi::default(),
            clock_timer: None,
            slots,
        })
    }

    /// Serves general-purpose timer `nth` of [`Stm32f427::tim`] (TIM2, TIM3, TIM4, TIM5), named
    /// `name`, as a [`ClockTimer`]: the same model, woken only when something but its pins can
    /// see its counter's events. For a board whose timer only generates a clock for a chip.
    ///
    /// # Errors
    /// `name` is not an instance of the part, or rigless's part fails to assemble.
    pub fn use_as_clock(&mut self, name: &'static str, nth: usize) -> Result<(), Error> {
        let slot = self.mcu.bus().slot(name)?;
        // A spare part's timer takes the place of the one moved out; it is never served.
        let mut spare = Stm32f427::new()?;
        std::mem::swap(&mut self.mcu.tim[nth], &mut spare.tim[nth]);
        let [t2, t3, t4, t5] = spare.tim;
        let timer = [t2, t3, t4, t5]
            .into_iter()
            .nth(nth)
            .ok_or(Error::UnknownInstance { instance: name })?;
        self.clock_timer = Some((slot, ClockTimer::new(timer)));
        Ok(())
    }

    /// The bus slot of the EXTI, for driving its lines from the board.
    #[must_use]
    pub fn exti_slot(&self) -> usize {
        self.slots.exti
    }

    /// The bus slot of the DCMI, for driving its inputs from the board.
    #[must_use]
    pub fn dcmi_slot(&self) -> usize {
        self.slots.dcmi
    }

    /// Drives an input of the EXTI at `at` (a pin level the board puts on a line).
    pub fn drive_exti<T>(
        &mut self,
        at: VirtualNanos,
        input: impl FnOnce(
            &mut Exti,
            &mut rigless::device::RegisterFile,
            &mut rigless::device::DeviceContext<'_>,
        ) -> T,
    ) -> T {
        let slot = self.slots.exti;
        let (registers, mut context) = self.mcu.bus_mut().drive(at, slot);
        input(&mut self.exti, registers, &mut context)
    }

    /// Drives an input of the DCMI at `at` (what the camera puts on its pins).
    pub fn drive_dcmi<T>(
        &mut self,
        at: VirtualNanos,
        input: impl FnOnce(
            &mut Dcmi,
            &mut rigless::device::RegisterFile,
            &mut rigless::device::DeviceContext<'_>,
        ) -> T,
    ) -> T {
        let slot = self.slots.dcmi;
        let (registers, mut context) = self.mcu.bus_mut().drive(at, slot);
        input(&mut self.dcmi, registers, &mut context)
    }
}

fn dma2() -> Dma {
    Dma::new(&DMA2_REQUESTS, &DMA2_LAST_DATA, true)
}

impl Mcu for Soc {
    fn bus(&self) -> &Bus {
        self.mcu.bus()
    }

    fn bus_mut(&mut self) -> &mut Bus {
        self.mcu.bus_mut()
    }

    /// The F427's reset (a fresh part, what the board put on its pins kept), then ours: our
    /// registers are the fresh bus's, at their reset values; our models drop what they held.
    fn reset(&mut self, at: VirtualNanos, cause: ResetCause) {
        self.mcu.reset(at, cause);
        self.mcu.dma[1] = dma2();
        rigless::device::Device::reset(&mut self.exti);
        rigless::device::Device::reset(&mut self.syscfg);
        rigless::device::Device::reset(&mut self.dcmi);
        if let Some((_, timer)) = &mut self.clock_timer {
            timer.reset();
        }
    }

    fn poll(&mut self, now: VirtualNanos) {
        self.mcu.poll(now);
    }

    fn split(&mut self, slot: usize) -> (&mut Bus, Option<&mut dyn ErasedDevice>) {
        if slot == self.slots.exti {
            (self.mcu.bus_mut(), Some(&mut self.exti))
        } else if slot == self.slots.syscfg {
            (self.mcu.bus_mut(), Some(&mut self.syscfg))
        } else if slot == self.slots.dcmi {
            // The camera's pins, read off the part before every call into the DCMI.
            self.dcmi
                .sample(&self.mcu, self.clock_timer.as_ref().map(|(_, t)| t));
            (self.mcu.bus_mut(), Some(&mut self.dcmi))
        } else if self.clock_timer.as_ref().is_some_and(|(at, _)| *at == slot) {
            let timer = self
                .clock_timer
                .as_mut()
                .map(|(_, t)| t as &mut dyn ErasedDevice);
            (self.mcu.bus_mut(), timer)
        } else {
            if slot == self.slots.i2c2 {
                // The camera's SCCB port times its reset from the same pins.
                self.dcmi
                    .sample(&self.mcu, self.clock_timer.as_ref().map(|(_, t)| t));
            }
            self.mcu.split(slot)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rigless::mcu::Operate;

    #[test]
    fn every_instance_a_part_lacks_is_one_the_f427_has() {
        let soc = Soc::new(Part::Stm32f415).unwrap();
        let names: Vec<&str> = soc.bus().peripherals().map(|p| p.name).collect();
        for name in NOT_ON_F40X
            .iter()
            .chain(&NOT_ON_F40X_PORTS)
            .chain(&NOT_ON_F407)
            .chain(&NOT_ON_F415)
        {
            assert!(
                names.iter().any(|n| n.eq_ignore_ascii_case(name)),
                "{name} not on the F427 bus: {names:?}"
            );
        }
    }

    #[test]
    fn the_parts_lack_what_their_datasheets_leave_out() {
        assert!(Part::Stm32f415.lacks("DCMI"));
        assert!(!Part::Stm32f407.lacks("DCMI"));
        assert!(Part::Stm32f407.lacks("UART7"));
        assert!(Part::Stm32f407.lacks("CRYP"));
        assert!(!Part::Stm32f415.lacks("CRYP"));
        assert!(!Part::Stm32f415.lacks("USART2"));
        assert!(!Part::Stm32f407.lacks("UART4"));
    }

    #[test]
    fn our_models_answer_their_slots_with_the_layout_the_bus_carries() {
        let mut soc = Soc::new(Part::Stm32f407).unwrap();
        soc.check().unwrap();
    }
}
