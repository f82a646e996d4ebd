//! The camera board (TU Delft stereoboard) as `../shared/hardware/original-boards.md` wires it:
//! an STM32F407 with a 12 MHz crystal, the two TCM8230 sensors behind the CPLD on the DCMI, their
//! SCCB on I2C2, their master clock from TIM3 CH2 on PA7, their reset on PD2, the CPLD's mode pins
//! PC10, PC12, PB5, and the link to the autopilot on UART4 (PA0 TX, PA1 RX).
//!
//! | function | pins | source (\[SB\], see original-boards.md) |
//! |---|---|---|
//! | DCMI sync | HSYNC PA4, PIXCLK PA6, VSYNC PB7 (AF13) | dcmi.c:187-199 |
//! | DCMI data | D0 PC6, D1 PC7, D2 PC8, D3 PC9, D4 PC11, D5 PB6, D6 PB8, D7 PB9 (AF13) | dcmi.c:187-199 |
//! | sensor master clock | TIM3 CH2 on PA7 (AF2) | dcmi.c:116-177 |
//! | sensor reset | PD2, output, low = reset | dcmi.c:84-114 |
//! | CPLD mode | PC10, PC12, PB5, outputs | cpld.c:17-69 |
//! | SCCB | I2C2: PB10 SCL, PB11 SDA, address 0x3C | tcm8230.c:54-85 |
//! | link | UART4: PA0 TX, PA1 RX | edgeFS.h:24-31 |
//! | second UART (unused on the pocket drone; the `hil` flavour's host link) | USART2: PA2 TX, PA3 RX | usart.c:303-330 |
//!
//! A data line of the DCMI reaches the camera only through the pin the board wires it to: a
//! firmware that puts `DCMI_D6` on PE5 (the F407's other choice) reads 0 on that bit.

use rigless::machine::{Board, Crystal, Supply, Target};
use rigless::snapshot::Store;
use rigless::soc::Error;
use rigless::soc::st::tim::Channel;
use rigless::soc::stm32f427::Stm32f427;
use rigless::soc::stm32f427::generated::{gpioa, rcc as rcc_regs, tim3};
use rigless::soc::stm32f427::peripherals::gpio::{Gpio, Pin};
use rigless::soc::stm32f427::peripherals::rcc::Apb;

use rigless::time::VirtualNanos;

use crate::bench::BenchBoard;
use crate::clock_timer::ClockTimer;
use crate::clocks::Clocks;
use crate::cpld::Mode;
use crate::dcmi::{Camera, DcmiInputs, DcmiStats};
use crate::flash::FlashContents;
use crate::frames::FrameSource;
use crate::link::WireEnd;
use crate::pins::{Mode as PinMode, Pull, Wired};
use crate::soc::{Part, Soc};
use crate::tcm8230::{SensorHandle, SensorPins};

/// The machine's name.
pub const NAME: &str = "pocket-drone-camera";
/// The rail, mV.
pub const SUPPLY_MV: u32 = 3300;
/// I2C2 in rigless's order of I2C interfaces.
const I2C2: usize = 1;
/// USART2 and UART4 in rigless's order of serial ports (USART1, USART2, USART3, USART6, UART7,
/// UART8, UART4, UART5).
const USART2: usize = 1;
const UART4: usize = 6;

/// The camera board's crystal, Hz (\[SB\] system_stm32f4xx.c: HSE 12 MHz).
pub const HSE_HZ: u64 = 12_000_000;

/// A pin: port index (A = 0) and number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardPin {
    /// Port name, as the vendor names the instance.
    pub port: &'static str,
    /// Pin number, 0 to 15.
    pub pin: u8,
}

const fn pin(port: &'static str, pin: u8) -> BoardPin {
    BoardPin { port, pin }
}

/// The DCMI's alternate function number (DS8626 table 9: AF13).
pub const AF_DCMI: u8 = 13;
/// TIM3's alternate function number (DS8626 table 9: AF2).
pub const AF_TIM3: u8 = 2;

/// HSYNC, PIXCLK, VSYNC.
pub const DCMI_SYNC: [BoardPin; 3] = [pin("GPIOA", 4), pin("GPIOA", 6), pin("GPIOB", 7)];
/// D0 to D7.
pub const DCMI_DATA: [BoardPin; 8] = [
    pin("GPIOC", 6),
    pin("GPIOC", 7),
    pin("GPIOC", 8),
    pin("GPIOC", 9),
    pin("GPIOC", 11),
    pin("GPIOB", 6),
    pin("GPIOB", 8),
    pin("GPIOB", 9),
];
/// The sensors' master clock input: TIM3 CH2.
pub const SENSOR_CLOCK: BoardPin = pin("GPIOA", 7);
/// The sensors' reset (low = reset).
pub const SENSOR_RESET: BoardPin = pin("GPIOD", 2);
/// The CPLD's mode pins, in the order [`Mode::from_pins`] takes them.
pub const CPLD_MODE: [BoardPin; 3] = [pin("GPIOC", 10), pin("GPIOC", 12), pin("GPIOB", 5)];

/// TIM3 in rigless's [`Stm32f427::tim`] (TIM2, TIM3, TIM4, TIM5).
const TIM3_INDEX: usize = 1;

/// The instances the sampler reads, by name.
const SAMPLED: [&str; 6] = ["GPIOA", "GPIOB", "GPIOC", "GPIOD", "RCC", "TIM3"];

/// Their bus slots, resolved once: every part is built from the one description, so a slot's
/// index is the same on every bus (the sampler runs on every DMA read of `DR`).
static SLOTS: std::sync::OnceLock<[usize; SAMPLED.len()]> = std::sync::OnceLock::new();

fn registers<'a>(mcu: &'a Stm32f427, instance: &str) -> &'a rigless::device::RegisterFile {
    let bus = rigless::mcu::Mcu::bus(mcu);
    let slots = SLOTS.get_or_init(|| {
        SAMPLED.map(|name| {
            bus.slot_of(name)
                .unwrap_or_else(|| panic!("the part carries {name}"))
        })
    });
    let nth = SAMPLED
        .iter()
        .position(|name| *name == instance)
        .unwrap_or_else(|| panic!("{instance} is not among the sampled instances"));
    bus.slots()[slots[nth]].registers()
}

/// The pin's alternate function, if it is in alternate-function mode.
fn function(mcu: &Stm32f427, p: BoardPin) -> Option<u8> {
    Gpio::function(Pin::new(p.pin)?, registers(mcu, p.port))
}

/// The level the MCU drives on `p`, if it drives it as an output (RM0090 8.4.1, 8.4.6).
fn output(mcu: &Stm32f427, p: BoardPin) -> Option<bool> {
    let r = registers(mcu, p.port);
    let mode = (r.get(gpioa::Register::Moder) >> (2 * p.pin)) & 0b11;
    (mode == 0b01).then(|| r.get(gpioa::Register::Odr) >> p.pin & 1 == 1)
}

/// The frequency of the clock TIM3 CH2 puts on PA7, Hz, if PA7 carries it: PA7 in AF2 and the
/// channel running a PWM (rigless's pulse read-back); the frequency from the timer's kernel clock
/// (RCC, APB1 timers) and its period in counts.
fn sensor_clock_hz(mcu: &Stm32f427, clock_timer: Option<&ClockTimer>) -> Option<u64> {
    if function(mcu, SENSOR_CLOCK) != Some(AF_TIM3) {
        return None;
    }
    let tim = registers(mcu, "TIM3");
    let timer = clock_timer.map_or(&mcu.tim[TIM3_INDEX], |t| &t.timer);
    let pulse = timer.pulse(Channel::new(2)?, tim)?;
    if pulse.width.0 == 0 || pulse.width.0 >= pulse.period.0 {
        return None;
    }
    let kernel = mcu.rcc.timer_clock(registers(mcu, "RCC"), Apb::One);
    let counts = (tim.get(tim3::Register::Psc) + 1) * (tim.get(tim3::Register::Arr) + 1);
    let hz = kernel / counts.max(1);
    // The read-back period (whole ns) must agree with the registers to within a nanosecond.
    let expected = 1_000_000_000 / hz.max(1);
    (expected.abs_diff(pulse.period.0) <= 1).then_some(hz)
}

/// What the camera board's pins carry for the DCMI and its camera, read off the part.
#[must_use]
pub fn sample(mcu: &Stm32f427, clock_timer: Option<&ClockTimer>) -> DcmiInputs {
    let rcc = registers(mcu, "RCC");
    let clock_enabled = rcc_regs::ahb2enr::DCMIEN.is_set(rcc.get(rcc_regs::Register::Ahb2enr));
    let sync_connected = DCMI_SYNC.iter().all(|p| function(mcu, *p) == Some(AF_DCMI));
    let data_mask = DCMI_DATA
        .iter()
        .enumerate()
        .filter(|(_, p)| function(mcu, **p) == Some(AF_DCMI))
        .fold(0u8, |mask, (bit, _)| mask | 1 << bit);
    DcmiInputs {
        sensor: SensorPins {
            extclk_hz: sensor_clock_hz(mcu, clock_timer),
            reset_released: output(mcu, SENSOR_RESET) == Some(true),
        },
        cpld: Mode::from_pins(CPLD_MODE.map(|p| output(mcu, p))),
        clock_enabled,
        sync_connected,
        data_mask,
    }
}

/// The sensors' master clock the original sets, Hz: TIM3 at 84 MHz, prescaler 1, period 1 (\[SB\]
/// dcmi.c:116-177, "21MHz").
pub const SENSOR_CLOCK_HZ: u64 = 21_000_000;
/// The link's baud in the paper's era ([SB-17] edgeFS.h:24-31).
pub const LINK_BAUD: u32 = 115_200;
/// The CPLD mode pins' levels (PC10, PC12, PB5) that select the stereo interleave (\[SB\]
/// cpld.c:17-69, main_parameters.h:120).
pub const CPLD_STEREO_LEVELS: [bool; 3] = [false, true, false];
/// The status LED, active high (\[SB\] led.c:15-33).
pub const LED: BoardPin = pin("GPIOB", 12);
/// The link UART's pins, TX and RX ([SB-17] edgeFS.h:24-31).
pub const LINK_PINS: [BoardPin; 2] = [pin("GPIOA", 0), pin("GPIOA", 1)];
/// The SCCB (I2C2) pins, SCL and SDA (\[SB\] tcm8230.c:54-85).
pub const SCCB_PINS: [BoardPin; 2] = [pin("GPIOB", 10), pin("GPIOB", 11)];
/// UART4's alternate function on PA0/PA1 (DS8626 table 9: AF8).
pub const AF_UART4: u8 = 8;
/// The second UART's pins, USART2 TX and RX (\[SB\] usart.c:303-330).
pub const HOST_PINS: [BoardPin; 2] = [pin("GPIOA", 2), pin("GPIOA", 3)];
/// USART2's alternate function on PA2/PA3 (DS8626 table 9: AF7).
pub const AF_USART2: u8 = 7;
/// I2C2's alternate function on PB10/PB11 (DS8626 table 9: AF4).
pub const AF_I2C2: u8 = 4;

/// The board's wiring, pin by pin, from the original firmware's set-up (\[SB\] dcmi.c:84-199,
/// tcm8230.c:54-70, cpld.c:17-69, led.c:15-33, usart.c:303-330; [SB-17] edgeFS.h:24-31) and
/// DS8626 table 9 for the alternate functions. Written from the original board, not imported
/// from the firmware: it is what the firmware is checked against.
pub const WIRING: [Wired; 23] = {
    const fn row(
        p: BoardPin,
        function: &'static str,
        mode: PinMode,
        pull: Option<Pull>,
        open_drain: Option<bool>,
        optional: bool,
    ) -> Wired {
        Wired {
            port: p.port,
            pin: p.pin,
            function,
            mode,
            pull,
            open_drain,
            optional,
        }
    }
    // The DCMI pins: AF13, push-pull, pull-up (dcmi.c:187-199).
    const fn dcmi(p: BoardPin, function: &'static str) -> Wired {
        row(
            p,
            function,
            PinMode::Alternate(AF_DCMI),
            Some(Pull::Up),
            Some(false),
            false,
        )
    }
    const fn out(p: BoardPin, function: &'static str, optional: bool) -> Wired {
        row(p, function, PinMode::Output, None, Some(false), optional)
    }
    [
        dcmi(DCMI_SYNC[0], "DCMI HSYNC"),
        dcmi(DCMI_SYNC[1], "DCMI PIXCLK"),
        dcmi(DCMI_SYNC[2], "DCMI VSYNC"),
        dcmi(DCMI_DATA[0], "DCMI D0"),
        dcmi(DCMI_DATA[1], "DCMI D1"),
        dcmi(DCMI_DATA[2], "DCMI D2"),
        dcmi(DCMI_DATA[3], "DCMI D3"),
        dcmi(DCMI_DATA[4], "DCMI D4"),
        dcmi(DCMI_DATA[5], "DCMI D5"),
        dcmi(DCMI_DATA[6], "DCMI D6"),
        dcmi(DCMI_DATA[7], "DCMI D7"),
        // dcmi.c:116-177: AF2, push-pull, no pull.
        row(
            SENSOR_CLOCK,
            "camera master clock, TIM3 CH2",
            PinMode::Alternate(AF_TIM3),
            Some(Pull::None),
            Some(false),
            false,
        ),
        // dcmi.c:84-114: output, push-pull, no pull.
        row(
            SENSOR_RESET,
            "camera reset (low = reset)",
            PinMode::Output,
            Some(Pull::None),
            Some(false),
            false,
        ),
        out(CPLD_MODE[0], "CPLD mode: manual", false),
        out(CPLD_MODE[1], "CPLD mode: pixel mux", false),
        out(CPLD_MODE[2], "CPLD mode: line mux", false),
        // tcm8230.c:54-70: open drain, no internal pull (2.8 V external pull-ups).
        row(
            SCCB_PINS[0],
            "SCCB SCL (I2C2)",
            PinMode::Alternate(AF_I2C2),
            Some(Pull::None),
            Some(true),
            false,
        ),
        row(
            SCCB_PINS[1],
            "SCCB SDA (I2C2)",
            PinMode::Alternate(AF_I2C2),
            Some(Pull::None),
            Some(true),
            false,
        ),
        row(
            LINK_PINS[0],
            "UART4 TX (link to the autopilot)",
            PinMode::Alternate(AF_UART4),
            None,
            None,
            false,
        ),
        row(
            LINK_PINS[1],
            "UART4 RX (link to the autopilot)",
            PinMode::Alternate(AF_UART4),
            None,
            None,
            false,
        ),
        out(LED, "LED (active high)", true),
        // The second UART: a spare on the pocket drone, so it may stay at reset.
        row(
            HOST_PINS[0],
            "USART2 TX (spare; the hil flavour's host link)",
            PinMode::Alternate(AF_USART2),
            None,
            None,
            true,
        ),
        row(
            HOST_PINS[1],
            "USART2 RX (spare; the hil flavour's host link)",
            PinMode::Alternate(AF_USART2),
            None,
            None,
            true,
        ),
    ]
};

/// The camera board.
#[derive(Debug)]
pub struct CameraBoard {
    /// The STM32F407 (rigless's F427 models and ours); the camera hangs on its DCMI and I2C2.
    pub soc: Soc,
    /// The 12 MHz crystal.
    pub hse: Crystal,
    /// The 3.3 V rail.
    pub rail: Supply,
    /// The far end of UART4, the link to the autopilot.
    pub link: WireEnd,
    /// The far end of USART2, the second UART: the host link of the `hil` flavour (frames in,
    /// estimates out), open (a test or a [`crate::serve::TcpBridge`] feeds and reads it).
    pub host: WireEnd,
    /// The sensor pair (its SCCB port is on I2C2, its pixel port on the DCMI).
    pub sensor: SensorHandle,
    /// The clock tree as last read.
    pub clocks: Option<Clocks>,
    /// What the flash holds beside the firmware at power-on (the parameter sector).
    pub flash: FlashContents,
}

impl Store for CameraBoard {}

impl CameraBoard {
    /// The board with its camera seeing what `source` gives and its link end open (a test
    /// feeds and reads it).
    ///
    /// # Errors
    /// rigless's part fails to assemble.
    pub fn new(source: Box<dyn FrameSource>) -> Result<Self, Error> {
        Self::with_link(source, WireEnd::open())
    }

    /// The same, with `link` on UART4 (one end of [`crate::link::join`]).
    ///
    /// # Errors
    /// rigless's part fails to assemble.
    pub fn with_link(source: Box<dyn FrameSource>, link: WireEnd) -> Result<Self, Error> {
        let mut soc = Soc::new(Part::Stm32f407)?;
        // TIM3 only generates the sensors' 21 MHz clock: woken at its counter's 42 million
        // events a second, the core could never skip ahead (see `crate::clock_timer`).
        soc.use_as_clock("TIM3", TIM3_INDEX)?;
        soc.mcu.rcc.attach_crystals(HSE_HZ, Crystal::NONE.0);
        soc.mcu.set_supply(SUPPLY_MV);
        let sensor = SensorHandle::new();
        soc.mcu.i2c[I2C2].attach(sensor.sccb_port());
        soc.dcmi.attach(Camera::new(sensor.clone(), source), sample);
        soc.mcu.usart[UART4].attach(link.clone());
        let host = WireEnd::open();
        soc.mcu.usart[USART2].attach(host.clone());
        let mut board = Self {
            soc,
            hse: Crystal(HSE_HZ),
            rail: Supply(SUPPLY_MV),
            link,
            host,
            sensor,
            clocks: None,
            flash: FlashContents::erased(),
        };
        // The camera's pins are watched from power-up (a fresh part drives none of them).
        board
            .soc
            .drive_dcmi(VirtualNanos(0), |dcmi, registers, context| {
                dcmi.start(registers, context);
            });
        Ok(board)
    }

    /// The same board, its flash holding `flash` beside the firmware at power-on.
    #[must_use]
    pub fn with_flash(self, flash: FlashContents) -> Self {
        Self { flash, ..self }
    }

    /// What happened on the DCMI.
    #[must_use]
    pub fn dcmi_stats(&self) -> DcmiStats {
        self.soc.dcmi.stats()
    }

    /// Every frame the DCMI captured whole: the camera frame's number and the instant, ns.
    #[must_use]
    pub fn captured(&self) -> Vec<(u64, u64)> {
        self.soc
            .dcmi
            .captured()
            .iter()
            .map(|(frame, at)| (*frame, at.0))
            .collect()
    }

    /// The frequency of the sensors' master clock on PA7 now, Hz (`None`: PA7 carries no
    /// clock from TIM3 CH2).
    #[must_use]
    pub fn sensor_clock_hz(&self) -> Option<u64> {
        sensor_clock_hz(&self.soc.mcu, self.soc.clock_timer.as_ref().map(|(_, t)| t))
    }

    /// The level the part drives on `p` now, if it drives it as a GPIO output.
    #[must_use]
    pub fn output_level(&self, p: BoardPin) -> Option<bool> {
        output(&self.soc.mcu, p)
    }

    /// Fault: the camera stops for good (no VSYNC, no data).
    pub fn stop_camera(&mut self) {
        self.soc.dcmi.stop_camera();
    }
}

impl BenchBoard for CameraBoard {
    fn soc(&self) -> &Soc {
        &self.soc
    }

    fn soc_mut(&mut self) -> &mut Soc {
        &mut self.soc
    }

    fn flash_contents(&self) -> Vec<(u64, Vec<u8>)> {
        self.flash.ranges().to_vec()
    }

    /// Tells the lines how the firmware drives UART4 and USART2 now (their bauds).
    fn advance(&mut self, _now: VirtualNanos) {
        let clocks = Clocks::read(&self.soc, HSE_HZ);
        self.clocks = Some(clocks);
        let baud = clocks.usart_baud(&self.soc, "UART4");
        self.link.tx.set_sender_baud(baud);
        self.link.rx.set_receiver_baud(baud);
        let host = clocks.usart_baud(&self.soc, "USART2");
        self.host.tx.set_sender_baud(host);
    }
}

impl Board for CameraBoard {
    fn name(&self) -> &'static str {
        NAME
    }

    fn target_names(&self) -> Vec<&'static str> {
        vec!["stm32f407"]
    }

    fn mcu(&mut self, target: usize) -> Option<&mut dyn rigless::mcu::Mcu> {
        (target == 0).then_some(&mut self.soc)
    }

    fn targets(&mut self) -> Vec<Target<'_>> {
        vec![super::target("stm32f407", &mut self.soc)]
    }
}
