//! The autopilot: a Paparazzi Lisa/MX 2.1 (STM32F415) in the pocket drone, wired as
//! `../shared/hardware/original-boards.md` gives it (\[PZ\] `lisa_mx_common.h`, `board.h`, the
//! airframe file).
//!
//! | function | wiring |
//! |---|---|
//! | MCU | STM32F415RG, HSE 12 MHz, 3.3 V |
//! | IMU | MPU-6000 ([`crate::mpu6000`]) on SPI2 (PB13 SCK, PB14 MISO, PB15 MOSI), CS PB12 active low; its INT is not wired (Paparazzi polls) |
//! | barometer | MS5611 (rigless's model) on SPI2, CS PC13 active low |
//! | motors | PC6 TIM3 CH1, PC7 TIM3 CH2, PA0 TIM5 CH1, PA1 TIM5 CH2 (all AF2), brushed via FETs |
//! | link to the camera board | USART2, PA2 TX / PA3 RX |
//! | telemetry | USART1, PA9 TX / PA10 RX |
//! | battery | 1S LiPo through the supply divider to PC4, ADC1 channel 14 ([`Autopilot::set_battery_v`]) |
//!
//! The world reaches the chips through [`Autopilot::set_body_rate`] and friends, in the
//! airframe's body axes (x forward, y right, z down), turned into the IMU chip's axes by the
//! board's axis map and the airframe's mounting ([`BODY_TO_CHIP`]).

use rigless::chip::ms5611::Ms5611;
use rigless::device::Level;
use rigless::machine::{Board, Crystal, Supply, Target};
use rigless::snapshot::Store;
use rigless::soc::Error;
use rigless::soc::stm32f427::peripherals::adc::Channel;
use rigless::soc::stm32f427::peripherals::gpio::Pin;
use rigless::soc::stm32f427::peripherals::spi::Select;
use rigless::time::VirtualNanos;

use crate::bench::BenchBoard;
use crate::clocks::Clocks;
use crate::flash::FlashContents;
use crate::link::WireEnd;
use crate::motors::{self, MotorPin, Output};
use crate::mpu6000::{self, Mpu6000};
use crate::ms5611::Barometer;
use crate::pins::{Mode, Wired};
use crate::soc::{Part, Soc};

/// The machine's name.
pub const NAME: &str = "pocket-drone-autopilot";
/// The crystal, Hz (\[PZ\] lisa_mx_common.h:29-30).
pub const HSE_HZ: u64 = 12_000_000;
/// The rail, mV (also the ADC's reference).
pub const SUPPLY_MV: u32 = 3300;
/// The battery a fresh board carries, V (a charged 1S LiPo at rest, about 70 %).
pub const BATTERY_V: f64 = 3.9;
/// SPI2 in rigless's order of serial interfaces (SPI1, SPI2, ...).
const SPI2: usize = 1;
/// USART1 and USART2 in rigless's order of serial ports.
const USART1: usize = 0;
const USART2: usize = 1;
/// The peers on SPI2, in the order they are attached.
const IMU: usize = 0;
const BARO: usize = 1;

/// The motors in the airframe's order (NE, NW, SW, SE = servo outputs 0, 1, 4, 5).
pub const MOTORS: [MotorPin; 4] = [
    MotorPin {
        port: "GPIOC",
        pin: 6,
        timer: "TIM3",
        channel: 1,
        function: 2,
    },
    MotorPin {
        port: "GPIOC",
        pin: 7,
        timer: "TIM3",
        channel: 2,
        function: 2,
    },
    MotorPin {
        port: "GPIOA",
        pin: 0,
        timer: "TIM5",
        channel: 1,
        function: 2,
    },
    MotorPin {
        port: "GPIOA",
        pin: 1,
        timer: "TIM5",
        channel: 2,
        function: 2,
    },
];

/// The motors' PWM frequency, Hz (\[PZ\] airframe xml:263-265: 36 kHz on the brushed-motor
/// FETs).
pub const MOTOR_PWM_HZ: u64 = 36_000;

/// [`MOTORS`] indices in the flight software's motor order (`protocol::MotorCommand`, the
/// mixer's: front-right, rear-right, rear-left, front-left): NE is front-right, SE rear-right,
/// SW rear-left, NW front-left (\[PZ\] airframe xml:30-33).
pub const MIXER_ORDER: [usize; 4] = [0, 3, 2, 1];

/// The board's wiring, pin by pin (\[PZ\] lisa_mx_common.h, board.h; datasheet DS8597 table 9
/// for the alternate functions). Written from the original board, not imported from the
/// firmware: it is what the firmware is checked against.
pub const WIRING: [Wired; 22] = {
    const fn af(port: &'static str, pin: u8, function: &'static str, af: u8) -> Wired {
        Wired {
            port,
            pin,
            function,
            mode: Mode::Alternate(af),
            pull: None,
            open_drain: None,
            optional: false,
        }
    }
    const fn out(port: &'static str, pin: u8, function: &'static str, optional: bool) -> Wired {
        Wired {
            port,
            pin,
            function,
            mode: Mode::Output,
            pull: None,
            open_drain: None,
            optional,
        }
    }
    const fn input(port: &'static str, pin: u8, function: &'static str, mode: Mode) -> Wired {
        Wired {
            port,
            pin,
            function,
            mode,
            pull: None,
            open_drain: None,
            optional: true,
        }
    }
    [
        af("GPIOB", 13, "SPI2 SCK (IMU, baro)", 5),
        af("GPIOB", 14, "SPI2 MISO", 5),
        af("GPIOB", 15, "SPI2 MOSI", 5),
        out("GPIOB", 12, "MPU-6000 chip select", false),
        out("GPIOC", 13, "MS5611 chip select", false),
        af("GPIOC", 6, "motor NE, TIM3 CH1", 2),
        af("GPIOC", 7, "motor NW, TIM3 CH2", 2),
        af("GPIOA", 0, "motor SW, TIM5 CH1", 2),
        af("GPIOA", 1, "motor SE, TIM5 CH2", 2),
        af("GPIOA", 2, "USART2 TX (camera link)", 7),
        af("GPIOA", 3, "USART2 RX (camera link)", 7),
        af("GPIOA", 9, "USART1 TX (telemetry)", 7),
        af("GPIOA", 10, "USART1 RX (telemetry)", 7),
        out("GPIOA", 8, "LED1 (active low)", true),
        out("GPIOB", 4, "LED2 (active low)", true),
        out("GPIOC", 2, "LED3 (active low)", true),
        out("GPIOC", 5, "LED4 (active low)", true),
        out("GPIOC", 15, "LED5 (active low)", true),
        input(
            "GPIOB",
            0,
            "baro data ready (not to be driven)",
            Mode::Input,
        ),
        input(
            "GPIOB",
            1,
            "external SPI data ready (not to be driven)",
            Mode::Input,
        ),
        input(
            "GPIOB",
            5,
            "magnetometer data ready (not to be driven)",
            Mode::Input,
        ),
        input("GPIOC", 4, "battery voltage (ADC)", Mode::Analog),
    ]
};

/// Body axes to the MPU-6000's axes. The board's axes are (-y, x, z) of the chip (\[PZ\]
/// imu_aspirin_2_spi.c:191-200), so chip = (board_y, -board_x, board_z); the pocket drone
/// mounts the board at psi = 135 deg, phi = -2 deg from the body (\[PZ\] airframe xml:64-66):
/// board = R_x(phi) R_z(psi) body. The chip sits face down (its z along the board's down axis),
/// which is what makes (-y, x, z) a right-handed x-forward, z-down board frame.
pub const BODY_TO_CHIP: [[f64; 3]; 3] = body_to_chip();

const fn body_to_chip() -> [[f64; 3]; 3] {
    // cos/sin of 135 deg and -2 deg.
    let (cpsi, spsi) = (
        -core::f64::consts::FRAC_1_SQRT_2,
        core::f64::consts::FRAC_1_SQRT_2,
    );
    let (cphi, sphi) = (0.999_390_827_019_095_7, -0.034_899_496_702_500_97);
    // R_z(psi) body -> intermediate (frame rotation: v' = [[c, s, 0], [-s, c, 0], [0, 0, 1]] v).
    let rz = [[cpsi, spsi, 0.0], [-spsi, cpsi, 0.0], [0.0, 0.0, 1.0]];
    // R_x(phi): [[1, 0, 0], [0, c, s], [0, -s, c]].
    let rx = [[1.0, 0.0, 0.0], [0.0, cphi, sphi], [0.0, -sphi, cphi]];
    let mut board = [[0.0; 3]; 3];
    let mut i = 0;
    while i < 3 {
        let mut j = 0;
        while j < 3 {
            board[i][j] = rx[i][0] * rz[0][j] + rx[i][1] * rz[1][j] + rx[i][2] * rz[2][j];
            j += 1;
        }
        i += 1;
    }
    // chip = (board_y, -board_x, board_z).
    [
        board[1],
        [-board[0][0], -board[0][1], -board[0][2]],
        board[2],
    ]
}

fn rotate(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// The autopilot board.
#[derive(Debug)]
pub struct Autopilot {
    /// The STM32F415 (rigless's F427 models and ours).
    pub soc: Soc,
    /// The 12 MHz crystal.
    pub hse: Crystal,
    /// The 3.3 V rail.
    pub rail: Supply,
    /// The far end of USART2, the link to the camera board.
    pub link: WireEnd,
    /// The far end of USART1, telemetry.
    pub telemetry: WireEnd,
    /// The clock tree as last read.
    pub clocks: Option<Clocks>,
    /// What the flash holds beside the firmware at power-on (the parameter sector).
    pub flash: FlashContents,
}

impl Store for Autopilot {}

impl Autopilot {
    /// The board with its chips, its link and telemetry ends open (a test feeds and reads them),
    /// the IMU's noise drawn from `seed`.
    ///
    /// # Errors
    /// rigless's part fails to assemble.
    pub fn new(seed: u64) -> Result<Self, Error> {
        Self::with_link(seed, WireEnd::open())
    }

    /// The same, with `link` on USART2 (one end of [`crate::link::join`]).
    ///
    /// # Errors
    /// rigless's part fails to assemble.
    pub fn with_link(seed: u64, link: WireEnd) -> Result<Self, Error> {
        let mut soc = Soc::new(Part::Stm32f415)?;
        soc.mcu.rcc.attach_crystals(HSE_HZ, Crystal::NONE.0);
        soc.mcu.set_supply(SUPPLY_MV);
        soc.mcu.spi[SPI2].attach_selected(
            Mpu6000::new(seed),
            Select {
                port: "GPIOB",
                pin: Pin::new(12).expect("a pin"),
                active: Level::Low,
            },
        );
        soc.mcu.spi[SPI2].attach_selected(
            Barometer::new(),
            Select {
                port: "GPIOC",
                pin: Pin::new(13).expect("a pin"),
                active: Level::Low,
            },
        );
        // Level and still.
        soc.mcu.spi[SPI2]
            .chip_mut::<Mpu6000>(IMU)
            .expect("just attached")
            .set_accel(rotate(&BODY_TO_CHIP, [0.0, 0.0, -9.806_65]));
        let telemetry = WireEnd::open();
        soc.mcu.usart[USART2].attach(link.clone());
        soc.mcu.usart[USART1].attach(telemetry.clone());
        soc.mcu.adc[0].set_reference(SUPPLY_MV);
        let mut board = Self {
            soc,
            hse: Crystal(HSE_HZ),
            rail: Supply(SUPPLY_MV),
            link,
            telemetry,
            clocks: None,
            flash: FlashContents::erased(),
        };
        board.set_battery_v(BATTERY_V);
        Ok(board)
    }

    /// Puts `volts` of battery on the supply divider: PC4 sees `volts` over the divider
    /// `autopilot::board::BATTERY_ADC` names (0.0045 V per count of 4096 at the 3.3 V
    /// reference, \[PZ\] lisa_mx_common.h:381), to the millivolt.
    pub fn set_battery_v(&mut self, volts: f64) {
        let adc = autopilot::board::BATTERY_ADC;
        let pin_mv = volts / (f64::from(adc.volts_per_count) * 4096.0) * f64::from(SUPPLY_MV);
        let channel = Channel::new(adc.channel).expect("PC4's channel is a pin channel");
        self.soc.mcu.adc[0].set_input(channel, pin_mv.round().max(0.0) as u32);
    }

    /// The same board, its flash holding `flash` beside the firmware at power-on.
    #[must_use]
    pub fn with_flash(self, flash: FlashContents) -> Self {
        Self { flash, ..self }
    }

    /// The IMU.
    pub fn imu(&mut self) -> &mut Mpu6000 {
        self.soc.mcu.spi[SPI2]
            .chip_mut::<Mpu6000>(IMU)
            .expect("the MPU-6000 is on SPI2")
    }

    /// The barometer.
    pub fn baro(&mut self) -> &mut Ms5611 {
        self.barometer().chip()
    }

    /// The barometer and its freeze ([`Barometer::set_frozen`]).
    pub fn barometer(&mut self) -> &mut Barometer {
        self.soc.mcu.spi[SPI2]
            .chip_mut::<Barometer>(BARO)
            .expect("the MS5611 is on SPI2")
    }

    /// The body's angular rate (x forward, y right, z down), rad/s, as the IMU senses it.
    pub fn set_body_rate(&mut self, rate: [f64; 3]) {
        let chip = rotate(&BODY_TO_CHIP, rate);
        self.imu().set_rate(chip);
    }

    /// The specific force in body axes, m/s^2 (level and still: (0, 0, -g)).
    pub fn set_body_specific_force(&mut self, force: [f64; 3]) {
        let chip = rotate(&BODY_TO_CHIP, force);
        self.imu().set_accel(chip);
    }

    /// The four motor duties in the mixer's order ([`MIXER_ORDER`]: FR, RR, RL, FL), 0..=1.
    #[must_use]
    pub fn duties_in_mixer_order(&self) -> [f64; 4] {
        let outputs = self.motors();
        MIXER_ORDER.map(|i| outputs[i].duty)
    }

    /// The four motor outputs, in [`MOTORS`] order.
    #[must_use]
    pub fn motors(&self) -> [Output; 4] {
        std::array::from_fn(|i| motors::output(&self.soc, &MOTORS[i]))
    }
}

impl BenchBoard for Autopilot {
    fn soc(&self) -> &Soc {
        &self.soc
    }

    fn soc_mut(&mut self) -> &mut Soc {
        &mut self.soc
    }

    fn flash_contents(&self) -> Vec<(u64, Vec<u8>)> {
        self.flash.ranges().to_vec()
    }

    /// Tells the chips how the firmware drives their buses now (SPI2's mode and clock, the
    /// UARTs' bauds).
    fn advance(&mut self, _now: VirtualNanos) {
        let clocks = Clocks::read(&self.soc, HSE_HZ);
        self.clocks = Some(clocks);
        if let Some((sclk_hz, mode_ok)) = clocks.spi(&self.soc, "SPI2") {
            self.imu().set_bus(mpu6000::Bus { mode_ok, sclk_hz });
        }
        let link = clocks.usart_baud(&self.soc, "USART2");
        self.link.tx.set_sender_baud(link);
        self.link.rx.set_receiver_baud(link);
        let telemetry = clocks.usart_baud(&self.soc, "USART1");
        self.telemetry.tx.set_sender_baud(telemetry);
    }
}

impl Board for Autopilot {
    fn name(&self) -> &'static str {
        NAME
    }

    fn target_names(&self) -> Vec<&'static str> {
        vec!["stm32f415"]
    }

    fn mcu(&mut self, target: usize) -> Option<&mut dyn rigless::mcu::Mcu> {
        (target == 0).then_some(&mut self.soc)
    }

    fn targets(&mut self) -> Vec<Target<'_>> {
        vec![super::target("stm32f415", &mut self.soc)]
    }
}
