//! The autopilot board: a Paparazzi Lisa/MX 2.1 (STM32F415RG), as the pocket drone flew it.
//!
//! This file is the whole board definition: every pin, peripheral instance, clock, rate and
//! polarity the firmware uses, each with its source. A board wired differently is a change to
//! this file only. The tables are plain data (also on the host, for the virtual-board bench
//! and `docs/hardware.md`); the `hw` part (MCU only) binds them to the HAL's types.
//!
//! Sources (see `../shared/hardware/original-boards.md`, "Autopilot"): \[PZ\] is
//! `knmcguire/paparazzi` branch imav2017: `lisa_mx_common.h` (LM), `lisa_mx/chibios/v2.1/board.h`
//! (BH), the pocket-drone airframe `tudelft_ladybird_lisamxs_wifi_indi_stereoboard.xml` (AF),
//! `imu_lisa_m_v2.1.xml` (IX), `imu_aspirin_2_spi.c` (IA), `mpu60x0_spi.c` (MS),
//! `baro_board.makefile` (BB), `lisa-mx.ld` (LD).
//!
//! | function | peripheral | pins | settings | source |
//! |---|---|---|---|---|
//! | MCU | STM32F415RG | - | HSE 12 MHz, SYSCLK 168 MHz, 1 MiB flash, 128 KiB SRAM + 64 KiB CCM | LD:24-31, LM:29-30 |
//! | IMU MPU-6000 | SPI2 | PB13 SCK, PB14 MISO, PB15 MOSI (AF5), CS PB12 (output, idle high) | mode 3, 656 kHz (at most 1 MHz for every register) | IX:21-27, LM:273-288, BH:209-212, MS:37-38 |
//! | barometer MS5611 | SPI2 (shared) | CS PC13 (output, idle high) | mode 3 | BH:326, BB:95-97 |
//! | motors (brushed, via FETs) | TIM3 CH1, CH2; TIM5 CH1, CH2 | PC6, PC7; PA0, PA1 (AF2) | 36 kHz PWM, high = on | AF:30-33, 263-265, LM:421-491 |
//! | link to the camera board | USART2 | PA2 TX, PA3 RX (AF7) | [`LINK_BAUD`] 8N1 | AF:232-233, LM:152-156 |
//! | telemetry (WiFi modem; the HIL host in the `hil` flavour) | USART1 | PA9 TX, PA10 RX (AF7) | [`TELEMETRY_BAUD`] 8N1 | AF:268-270, LM:145-149 |
//! | RC receiver (none on the pocket drone; [`RC_RECEIVER`]) | UART5 RX | PD2 (AF8) | 100,000 Bd 8E2 | AF:242 (open, see below) |
//! | status LED (LED 1) | GPIO | PA8 (output) | **active low** | LM:36-84 |
//! | loop timer | TIM2 | - | [`LOOP_RATE_HZ`] update interrupt | - (the original polls the IMU from its main loop) |
//! | supply voltage ([`BATTERY_ADC`]) | ADC1 IN14 | PC4 (analog) | 0.0045 V per count (divider) | LM:330, 369-373, 381 |
//!
//! Pins the firmware leaves alone (never outputs): see [`NOT_DRIVEN`]. PB4 is LED 2 on the
//! board but also JTAG NJTRST with a pull-up, and the brief of this port keeps it an input.
//!
//! Choices the sources leave open, each a one-line change here:
//!
//! * IMU data-ready: which pin the MPU-6000's INT reaches is not in the sources (Paparazzi polls
//!   the IMU); the loop is paced by [`LOOP_RATE_HZ`] on TIM2 instead and no pin is read.
//! * RC: the pocket drone has no receiver (pilot commands come over the telemetry link), so
//!   [`RC_RECEIVER`] is off and PD2 stays at reset. With it on, the Lisa/MX's receiver input,
//!   UART5 RX (PD2, Spektrum in Paparazzi), decodes SBUS ([`crate::rc`]).
//! * Status LED: LED 1 (PA8) blinks at 1 Hz; the other LEDs stay off (inputs).

use board_support::pins::pin;
pub use board_support::pins::{Function, Pin, PinAssignment, Port, Pull};
use timebase::Duration;

/// Every pin the `real` firmware configures (and [`RC_PIN`] with [`RC_RECEIVER`]); all others
/// stay in their reset state (input,
/// except the debug pins PA13, PA14, PA15, PB3, PB4). The HAL's default for the alternate
/// functions is no pull; the UART receive pins get a pull-up so that an unplugged line idles
/// high instead of reading noise as start bits.
pub const PINS: [PinAssignment; 14] = [
    PinAssignment {
        pin: pin(Port::B, 13),
        signal: "SPI2 SCK (MPU-6000, MS5611)",
        function: Function::Alternate(5),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] lisa_mx_common.h:273-288",
    },
    PinAssignment {
        pin: pin(Port::B, 14),
        signal: "SPI2 MISO",
        function: Function::Alternate(5),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] lisa_mx_common.h:273-288",
    },
    PinAssignment {
        pin: pin(Port::B, 15),
        signal: "SPI2 MOSI",
        function: Function::Alternate(5),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] lisa_mx_common.h:273-288",
    },
    PinAssignment {
        pin: pin(Port::B, 12),
        signal: "MPU-6000 chip select (active low)",
        function: Function::Output { high: true },
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] imu_lisa_m_v2.1.xml:21-27, board.h:209-212",
    },
    PinAssignment {
        pin: pin(Port::C, 13),
        signal: "MS5611 chip select (active low)",
        function: Function::Output { high: true },
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] board.h:326, baro_board.makefile:95-97",
    },
    PinAssignment {
        pin: pin(Port::C, 6),
        signal: "motor NE / front-right (TIM3 CH1)",
        function: Function::Alternate(2),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:30-33, lisa_mx_common.h:421-491",
    },
    PinAssignment {
        pin: pin(Port::C, 7),
        signal: "motor NW / front-left (TIM3 CH2)",
        function: Function::Alternate(2),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:30-33, lisa_mx_common.h:421-491",
    },
    PinAssignment {
        pin: pin(Port::A, 0),
        signal: "motor SW / rear-left (TIM5 CH1)",
        function: Function::Alternate(2),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:30-33, lisa_mx_common.h:421-491",
    },
    PinAssignment {
        pin: pin(Port::A, 1),
        signal: "motor SE / rear-right (TIM5 CH2)",
        function: Function::Alternate(2),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:30-33, lisa_mx_common.h:421-491",
    },
    PinAssignment {
        pin: pin(Port::A, 2),
        signal: "USART2 TX (link to the camera board)",
        function: Function::Alternate(7),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:232-233, lisa_mx_common.h:152-156",
    },
    PinAssignment {
        pin: pin(Port::A, 3),
        signal: "USART2 RX (link to the camera board)",
        function: Function::Alternate(7),
        pull: Pull::Up,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:232-233, lisa_mx_common.h:152-156",
    },
    PinAssignment {
        pin: pin(Port::A, 9),
        signal: "USART1 TX (telemetry / host)",
        function: Function::Alternate(7),
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:268-270, lisa_mx_common.h:145-149",
    },
    PinAssignment {
        pin: pin(Port::A, 10),
        signal: "USART1 RX (telemetry / host)",
        function: Function::Alternate(7),
        pull: Pull::Up,
        drive: None,
        speed: None,
        source: "[PZ] airframe xml:268-270, lisa_mx_common.h:145-149",
    },
    PinAssignment {
        pin: pin(Port::A, 8),
        signal: "LED 1 (status, active low)",
        function: Function::Output { high: true },
        pull: Pull::None,
        drive: None,
        speed: None,
        source: "[PZ] lisa_mx_common.h:36-84",
    },
];

/// Whether the board carries an RC receiver on the Lisa/MX's receiver port ([`RC_PIN`]). The
/// pocket drone has none: its pilot commands come over the telemetry link (\[PZ\] airframe
/// xml:242; original-boards.md, "RC"), so by default UART5 and PD2 stay at reset and the RC
/// task does not run. A drone with an SBUS receiver sets this to `true` (one line).
pub const RC_RECEIVER: bool = false;

/// The receiver port's pin, configured only when [`RC_RECEIVER`] is set.
pub const RC_PIN: PinAssignment = PinAssignment {
    pin: pin(Port::D, 2),
    signal: "UART5 RX (RC receiver, SBUS; only with RC_RECEIVER)",
    function: Function::Alternate(8),
    pull: Pull::Up,
    drive: None,
    speed: None,
    source: "[PZ] airframe xml:242 (receiver port; open)",
};

/// Pins that must never be driven as outputs, and why.
pub const NOT_DRIVEN: [(Pin, &str); 6] = [
    (
        pin(Port::B, 4),
        "LED 2 and JTAG NJTRST with a pull-up ([PZ] board.h:197-202)",
    ),
    (
        pin(Port::B, 5),
        "magnetometer data-ready ([PZ] board.h:197-202)",
    ),
    (
        pin(Port::B, 0),
        "barometer data-ready ([PZ] board.h:197-202)",
    ),
    (
        pin(Port::B, 1),
        "external-SPI data-ready ([PZ] board.h:197-202)",
    ),
    (
        pin(Port::C, 4),
        "battery-voltage input, analog ([BATTERY_ADC]; [PZ] lisa_mx_common.h:330, 369-373)",
    ),
    (
        pin(Port::C, 5),
        "LED 4; left off, so that only LED 1 shows status",
    ),
];

/// The supply-voltage input: PC4 in analog mode, read by ADC1 on channel 14 (\[PZ\]
/// lisa_mx_common.h:330, "BATT PC4/ADC14", and 369-373, `AD1_4_CHANNEL 14` on `GPIOC`
/// `GPIO4`), through the board's divider: Paparazzi converts a 12-bit conversion to volts as
/// `DefaultVoltageOfAdc(adc) (0.0045*adc)` (lisa_mx_common.h:381; `lisa_mx_2.1.h` keeps it),
/// that is a divider of 0.0045 × 4096 / 3.3 = 5.59 before the 3.3 V reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryAdc {
    /// The input pin (analog mode).
    pub pin: Pin,
    /// ADC channel of the pin (ADC1/ADC2 IN14).
    pub channel: u8,
    /// Supply volts per count of a 12-bit conversion (divider and 3.3 V reference together).
    pub volts_per_count: f32,
}

/// The Lisa/MX 2.1's supply-voltage input.
pub const BATTERY_ADC: BatteryAdc = BatteryAdc {
    pin: pin(Port::C, 4),
    channel: 14,
    volts_per_count: 0.0045,
};

/// Crystal, Hz (\[PZ\] lisa_mx_common.h:29-30).
pub const HSE_HZ: u32 = 12_000_000;
// Core clock, Hz: the PLL from the HSE (\[PZ\] lisa_mx_common.h:29-30), as on the camera board.
pub use board_support::chip::SYSCLK_HZ;
/// APB1 timer clock (TIM2, TIM3, TIM5), Hz: APB1 at SYSCLK / 4 = 42 MHz, timers at twice that.
pub const APB1_TIMER_HZ: u32 = 84_000_000;

/// Rate of the control loop and of the IMU reads, Hz (TIM2 update interrupt). The MPU-6000
/// produces a new sample every 1 ms ([`IMU_OUTPUT_RATE_HZ`]), so every read gets a fresh one.
pub const LOOP_RATE_HZ: u32 = 512;
/// The MPU-6000's output rate as configured (1 kHz gyro rate with the 188 Hz low-pass,
/// sample-rate divider 0), Hz.
pub const IMU_OUTPUT_RATE_HZ: u32 = 1_000;
/// SPI2 clock, Hz: APB1 (42 MHz) / 64. The MPU-6000 takes at most 1 MHz (+-10 %) for its
/// configuration registers (datasheet section 6.3); one speed for every access keeps the bus
/// simple (a 15-byte sample read takes 183 us).
pub const SPI_HZ: u32 = 656_250;

/// PWM frequency of the brushed motors, Hz (\[PZ\] airframe xml:263-265).
pub const MOTOR_PWM_HZ: u32 = 36_000;

/// Which output drives each motor of the mixer's order (`protocol::MotorCommand`: 1 FR, 2 RR,
/// 3 RL, 4 FL; see [`crate::mixer`]). The original's servo numbers: NE = 0 (PC6, TIM3 CH1),
/// NW = 1 (PC7, TIM3 CH2), SW = 4 (PA0, TIM5 CH1), SE = 5 (PA1, TIM5 CH2) (\[PZ\] airframe
/// xml:30-33); NE is front-right, SE rear-right, SW rear-left, NW front-left.
pub const MOTOR_OUTPUTS: [MotorOutput; 4] = [
    MotorOutput {
        timer: 3,
        channel: 1,
        pin: pin(Port::C, 6),
    },
    MotorOutput {
        timer: 5,
        channel: 2,
        pin: pin(Port::A, 1),
    },
    MotorOutput {
        timer: 5,
        channel: 1,
        pin: pin(Port::A, 0),
    },
    MotorOutput {
        timer: 3,
        channel: 2,
        pin: pin(Port::C, 7),
    },
];

/// One motor's PWM output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorOutput {
    /// Timer number (3: TIM3, 5: TIM5).
    pub timer: u8,
    /// Channel (1-based, as in the reference manual).
    pub channel: u8,
    /// Output pin.
    pub pin: Pin,
}

/// Baud rate of the link to the camera board (shared with it: `board_support::link`).
pub const LINK_BAUD: u32 = board_support::link::LINK_BAUD;
/// Baud rate of the telemetry port (the WiFi modem of the original, 115,200 Bd: \[PZ\] airframe
/// xml:268-270); 921,600 Bd in the `hil` flavour, where the HIL bridge sits there.
pub const TELEMETRY_BAUD: u32 = board_support::link::HOST_BAUD;

/// The longest a hung task keeps the motors live before the independent watchdog resets the
/// part (motors off, see `board_support::fault`), ms, at any LSI of the datasheet (17 to 47 kHz,
/// DS8626 table 41; real flavour). 50 ms: from rest a drone falls g t^2 / 2 = 1.2 cm in 50 ms,
/// so a hung firmware is reset before it has dropped noticeably or flown far on its last
/// command. The 512 Hz control loop feeds the watchdog, and only while the guidance task ran
/// within [`GUIDANCE_ALIVE`] and the heartbeat within [`HEARTBEAT_ALIVE`]: a hang in the
/// loop or at any priority above starves it at once; one at the guidance priority or above
/// starves it within [`GUIDANCE_ALIVE`]; one below (telemetry, gyro, barometer, heartbeat)
/// within [`HEARTBEAT_ALIVE`]. [`WATCHDOG`] is programmed so that the guidance window plus
/// the timeout at the slowest LSI is at most this. In the lockstep flavours (`hil`, `qemu`)
/// the world clock may stall while the host computes, so the 1 Hz heartbeat feeds the
/// watchdog there, with [`board_support::watchdog::HEARTBEAT_FED`] (the boards' timeouts side
/// by side: [`board_support::watchdog`]).
pub const WATCHDOG_MS: u32 = 50;
/// How recently the 50 Hz guidance task must have run for the control loop to feed the
/// watchdog: its 20 ms period and 5 ms for a release delayed by the tasks above it.
pub const GUIDANCE_ALIVE: Duration = Duration::from_millis(25);
/// How recently the 1 Hz heartbeat (the lowest priority) must have run for the control loop to
/// feed the watchdog: its period and half a period of delay.
pub const HEARTBEAT_ALIVE: Duration = Duration::from_millis(1_500);
/// The independent watchdog's programmed timeout (real flavour): [`WATCHDOG_MS`] less the
/// guidance window at the slowest LSI (24.9 ms there, 9.0 ms at the fastest, where the 512 Hz
/// loop feeds it every 1.95 ms).
pub const WATCHDOG: board_support::watchdog::Timeout = board_support::watchdog::Timeout::within_ms(
    WATCHDOG_MS - GUIDANCE_ALIVE.as_millis() as u32,
    board_support::watchdog::LSI_HZ_SLOWEST,
);

/// The longest time from a panic or HardFault to every motor at 0: the fault path's first
/// act after masking interrupts is the register writes of `hw::motors_off` (a few dozen
/// instructions; `board_support::fault`).
pub const FAULT_MOTORS_OFF: Duration = Duration::from_micros(10);

/// The MPU-6000's axes on the board: board axis i is `sign[i]` times chip axis `axis[i]`.
/// Paparazzi's Lisa/MX 2.1 mapping is board = (-chip y, chip x, chip z) (\[PZ\]
/// imu_aspirin_2_spi.c:191-200); the board frame is x forward, y right, z down when the board
/// is mounted straight.
pub const IMU_AXES: AxisMap = AxisMap {
    axis: [1, 0, 2],
    sign: [-1, 1, 1],
};

/// A fixed permutation with signs from one frame's axes to another's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisMap {
    /// Source axis (0: x, 1: y, 2: z) of each target axis.
    pub axis: [usize; 3],
    /// Sign (+1 or -1) of each target axis.
    pub sign: [i8; 3],
}

impl AxisMap {
    /// `v` (source frame) in the target frame.
    pub fn apply(&self, v: [f32; 3]) -> [f32; 3] {
        let pick = |i: usize| {
            let x = v.get(self.axis[i]).copied().unwrap_or(0.0);
            if self.sign[i] < 0 {
                -x
            } else {
                x
            }
        };
        [pick(0), pick(1), pick(2)]
    }
}

/// How the airframe mounts the board: Paparazzi's `BODY_TO_IMU` Euler angles (roll, pitch,
/// yaw; rad), the rotation from the body frame to the board's frame. An airframe setting, not
/// a board constant; the default is the pocket drone's ([`Mounting::POCKET_DRONE`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mounting {
    /// Roll (phi), rad.
    pub roll_rad: f32,
    /// Pitch (theta), rad.
    pub pitch_rad: f32,
    /// Yaw (psi), rad.
    pub yaw_rad: f32,
}

impl Mounting {
    /// The pocket drone: `BODY_TO_IMU_PSI` = 135 deg, `BODY_TO_IMU_PHI` = -2 deg (\[PZ\] airframe
    /// xml:64-66).
    pub const POCKET_DRONE: Mounting = Mounting {
        roll_rad: -2.0 * core::f32::consts::PI / 180.0,
        pitch_rad: 0.0,
        yaw_rad: 135.0 * core::f32::consts::PI / 180.0,
    };

    /// The board straight in the body frame.
    pub const IDENTITY: Mounting = Mounting {
        roll_rad: 0.0,
        pitch_rad: 0.0,
        yaw_rad: 0.0,
    };

    /// The direction-cosine matrix from body to board (Z-Y-X Euler): `v_board = M v_body`.
    pub fn body_to_board(&self) -> [[f32; 3]; 3] {
        let (sr, cr) = (libm::sinf(self.roll_rad), libm::cosf(self.roll_rad));
        let (sp, cp) = (libm::sinf(self.pitch_rad), libm::cosf(self.pitch_rad));
        let (sy, cy) = (libm::sinf(self.yaw_rad), libm::cosf(self.yaw_rad));
        [
            [cp * cy, cp * sy, -sp],
            [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp],
            [cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp],
        ]
    }

    /// A board-frame vector in the body frame: `M^T v`.
    pub fn board_to_body(&self, v: [f32; 3]) -> [f32; 3] {
        let m = self.body_to_board();
        let col = |j: usize| m[0][j] * v[0] + m[1][j] * v[1] + m[2][j] * v[2];
        [col(0), col(1), col(2)]
    }
}

impl Default for Mounting {
    fn default() -> Self {
        Self::POCKET_DRONE
    }
}

/// The board bound to the HAL (MCU only): the peripheral instances and typed pins of the tables
/// above, brought up in one place.
#[cfg(target_os = "none")]
pub mod hw {
    use super::{BATTERY_ADC, HSE_HZ, LINK_BAUD, MOTOR_PWM_HZ, SPI_HZ, TELEMETRY_BAUD};
    use stm32f4xx_hal::gpio::{Analog, Output, PinState, PA8, PB12, PC13, PC4};
    use stm32f4xx_hal::pac;
    use stm32f4xx_hal::prelude::*;
    use stm32f4xx_hal::rcc::Rcc;
    use stm32f4xx_hal::serial::{self, Rx, Serial};
    use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};
    use stm32f4xx_hal::timer::{CounterHz, PwmChannel};

    /// The UART of the link to the camera board.
    pub type LinkUart = pac::USART2;
    /// Its interrupt.
    pub const LINK_IRQ: pac::Interrupt = pac::Interrupt::USART2;
    /// The UART of the telemetry port (the HIL host in the `hil` and `qemu` flavours).
    pub type TelemetryUart = pac::USART1;
    /// Its interrupt.
    pub const TELEMETRY_IRQ: pac::Interrupt = pac::Interrupt::USART1;
    /// The DMA stream that takes the telemetry port's received bytes in the `hil` flavour
    /// (921,600 Bd; see `board_support::uart_dma`): USART1_RX is DMA2 stream 2, channel 4
    /// (RM0090 table 43).
    pub const TELEMETRY_RX_DMA: board_support::uart_dma::RxStream =
        board_support::uart_dma::RxStream {
            controller: board_support::uart_dma::Controller::Dma2,
            stream: 2,
            channel: 4,
        };
    /// The UART of the RC receiver (receive only).
    pub type RcUart = pac::UART5;
    /// Its interrupt.
    pub const RC_IRQ: pac::Interrupt = pac::Interrupt::UART5;
    /// The timer pacing the control loop.
    pub type LoopTimer = pac::TIM2;
    /// The sensors' SPI bus.
    pub type SensorSpi = Spi<pac::SPI2>;
    /// The MPU-6000's chip select (active low).
    pub type ImuCs = PB12<Output>;
    /// The MS5611's chip select (active low).
    pub type BaroCs = PC13<Output>;
    /// The status LED (active low).
    pub type Led = PA8<Output>;
    /// Level that lights the LED.
    pub const LED_ON: PinState = PinState::Low;

    /// Everything the firmware drives, configured.
    pub struct Board {
        /// Clocks (for the HAL's later use).
        pub rcc: Rcc,
        /// Link to the camera board.
        pub link: Serial<LinkUart>,
        /// Telemetry port.
        pub telemetry: Serial<TelemetryUart>,
        /// RC receiver input (`None` without [`super::RC_RECEIVER`]).
        pub rc: Option<Rx<RcUart>>,
        /// The sensors' bus and chip selects.
        pub spi: SensorSpi,
        /// MPU-6000 chip select, high (deselected).
        pub imu_cs: ImuCs,
        /// MS5611 chip select, high (deselected).
        pub baro_cs: BaroCs,
        /// The four motors, off.
        pub motors: Motors,
        /// The loop timer (not started).
        pub loop_timer: CounterHz<LoopTimer>,
        /// Status LED, off.
        pub led: Led,
        /// The watchdog (not started).
        pub iwdg: pac::IWDG,
        /// The flash interface (the clock set-up has set its wait states), for the parameter
        /// sector.
        pub flash: pac::FLASH,
        /// The supply-voltage converter and its pin, untouched: [`BatteryInput::new`] sets them
        /// up (only a flavour that reads its own sensors does).
        pub battery: (pac::ADC1, pac::ADC_COMMON, PC4),
    }

    /// Brings the board up: clocks, then every pin of [`super::PINS`] in its mode, motors at 0.
    /// Pins not in the table are not touched. A configuration the HAL refuses (a baud rate it
    /// cannot make) stops the firmware through the fault path.
    pub fn take(dp: pac::Peripherals) -> Board {
        let mut rcc = dp.RCC.freeze(board_support::clocks::config(HSE_HZ));
        let gpioa = dp.GPIOA.split(&mut rcc);
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
        let gpiod = dp.GPIOD.split(&mut rcc);

        // Motors first, so their pins leave the reset state as PWM at 0 straight away.
        let (_, (c1, c2, _, _)) = dp.TIM3.pwm_hz(MOTOR_PWM_HZ.Hz(), &mut rcc);
        let (_, (d1, d2, _, _)) = dp.TIM5.pwm_hz(MOTOR_PWM_HZ.Hz(), &mut rcc);
        let motors = Motors::new(
            c1.with(gpioc.pc6),
            d2.with(gpioa.pa1),
            d1.with(gpioa.pa0),
            c2.with(gpioc.pc7),
        );

        let imu_cs = gpiob.pb12.into_push_pull_output_in_state(PinState::High);
        let baro_cs = gpioc.pc13.into_push_pull_output_in_state(PinState::High);
        let mode = Mode {
            polarity: Polarity::IdleHigh,
            phase: Phase::CaptureOnSecondTransition,
        };
        let spi = dp.SPI2.spi(
            (Some(gpiob.pb13), Some(gpiob.pb14), Some(gpiob.pb15)),
            mode,
            SPI_HZ.Hz(),
            &mut rcc,
        );

        let link = dp
            .USART2
            .serial(
                (gpioa.pa2, gpioa.pa3.internal_pull_up(true)),
                serial::Config::default().baudrate(LINK_BAUD.bps()),
                &mut rcc,
            )
            .unwrap_or_else(|_| panic!("USART2 configuration"));
        let telemetry = dp
            .USART1
            .serial(
                (gpioa.pa9, gpioa.pa10.internal_pull_up(true)),
                serial::Config::default().baudrate(TELEMETRY_BAUD.bps()),
                &mut rcc,
            )
            .unwrap_or_else(|_| panic!("USART1 configuration"));
        // SBUS: 100,000 Bd, 8 data bits + even parity (a 9-bit word), 2 stop bits.
        let rc = super::RC_RECEIVER.then(|| {
            dp.UART5
                .rx(
                    gpiod.pd2.internal_pull_up(true),
                    serial::Config::default()
                        .baudrate(crate::rc::SBUS_BAUD.bps())
                        .wordlength_9()
                        .parity_even()
                        .stopbits(serial::config::StopBits::STOP2),
                    &mut rcc,
                )
                .unwrap_or_else(|_| panic!("UART5 configuration"))
        });
        let loop_timer = dp.TIM2.counter_hz(&mut rcc);
        let led = gpioa.pa8.into_push_pull_output_in_state(!LED_ON);
        Board {
            rcc,
            link,
            telemetry,
            rc,
            spi,
            imu_cs,
            baro_cs,
            motors,
            loop_timer,
            led,
            iwdg: dp.IWDG,
            flash: dp.FLASH,
            battery: (dp.ADC1, dp.ADC_COMMON, gpioc.pc4),
        }
    }

    /// Polls of the end-of-conversion flag before a conversion counts as failed: one takes
    /// 480 + 12 ADC cycles at 21 MHz, 23 µs or about 4,000 core cycles, and a poll several.
    const CONVERSION_POLLS: u32 = 4_000;

    /// The supply-voltage input ([`BATTERY_ADC`]): ADC1 on PC4 in analog mode, one
    /// software-started conversion a read. Written on the PAC rather than the HAL's `Adc`,
    /// whose set-up converts the internal reference against a factory value in system memory
    /// and whose conversions wait without bound (and panic when none started): a supply
    /// reading must never stall or stop the flight firmware.
    pub struct BatteryInput {
        adc: pac::ADC1,
        _common: pac::ADC_COMMON,
        _pin: PC4<Analog>,
    }

    impl BatteryInput {
        /// Clocks ADC1 at APB2 / 4 = 21 MHz (at most 36 MHz), selects channel 14 alone with
        /// 480 sampling cycles (the divider's source impedance) and powers it up.
        pub fn new((adc, common, pin): (pac::ADC1, pac::ADC_COMMON, PC4), rcc: &mut Rcc) -> Self {
            use stm32f4xx_hal::rcc::Enable as _;
            pac::ADC1::enable(rcc);
            let pin = pin.into_analog();
            common.ccr().modify(|_, w| w.adcpre().div4());
            adc.smpr1()
                .modify(|_, w| w.smp(BATTERY_ADC.channel - 10).cycles480());
            adc.sqr1().modify(|_, w| w.l().set(0));
            // SAFETY: SQ1 takes any channel number 0..=18; 14 is PC4's.
            adc.sqr3()
                .write(|w| unsafe { w.sq1().bits(BATTERY_ADC.channel) });
            adc.cr2().write(|w| w.adon().set_bit());
            Self {
                adc,
                _common: common,
                _pin: pin,
            }
        }

        /// One conversion: the supply voltage, V (`None`: the conversion did not end within
        /// the bounded number of polls).
        pub fn read_volts(&mut self) -> Option<f32> {
            self.adc.sr().modify(|_, w| w.eoc().clear_bit());
            self.adc.cr2().modify(|_, w| w.swstart().set_bit());
            for _ in 0..CONVERSION_POLLS {
                if self.adc.sr().read().eoc().bit_is_set() {
                    let raw = self.adc.dr().read().data().bits();
                    return Some(f32::from(raw) * BATTERY_ADC.volts_per_count);
                }
            }
            None
        }
    }

    /// The four motor outputs in the mixer's order (see [`super::MOTOR_OUTPUTS`]).
    pub struct Motors {
        front_right: PwmChannel<pac::TIM3, 0>,
        rear_right: PwmChannel<pac::TIM5, 1>,
        rear_left: PwmChannel<pac::TIM5, 0>,
        front_left: PwmChannel<pac::TIM3, 1>,
    }

    impl Motors {
        fn new(
            front_right: PwmChannel<pac::TIM3, 0>,
            rear_right: PwmChannel<pac::TIM5, 1>,
            rear_left: PwmChannel<pac::TIM5, 0>,
            front_left: PwmChannel<pac::TIM3, 1>,
        ) -> Self {
            let mut m = Self {
                front_right,
                rear_right,
                rear_left,
                front_left,
            };
            m.set([0.0; 4]);
            m.front_right.enable();
            m.rear_right.enable();
            m.rear_left.enable();
            m.front_left.enable();
            m
        }

        /// Sets the throttles (FR, RR, RL, FL; each clamped to 0..=1, NaN is 0).
        pub fn set(&mut self, throttle: [f32; 4]) {
            let duty = |t: f32, max: u16| {
                let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
                (t * f32::from(max)) as u16
            };
            let [fr, rr, rl, fl] = throttle;
            let max = self.front_right.get_max_duty();
            self.front_right.set_duty(duty(fr, max));
            self.front_left.set_duty(duty(fl, max));
            let max = self.rear_right.get_max_duty();
            self.rear_right.set_duty(duty(rr, max));
            self.rear_left.set_duty(duty(rl, max));
        }
    }

    /// Forces every motor output off at the registers, for the fault path: each channel's
    /// compare value to 0 and its output mode to "force inactive" (OCxM = 0b100, RM0090
    /// section 18.4.7: immediate, not at the next PWM period), then the four pins to plain
    /// outputs driven low (the FETs' gates). No lock and no HAL state: callable at any instant;
    /// before the timers and ports are clocked the writes are ignored and the pins stay inputs.
    pub fn motors_off() {
        // SAFETY: plain register writes on the fault path, interrupts off; nothing else runs
        // afterwards. The bits written are the motor channels' and motor pins' only.
        unsafe {
            let tim3 = &*pac::TIM3::ptr();
            tim3.ccr(0).write(|w| w.bits(0));
            tim3.ccr(1).write(|w| w.bits(0));
            tim3.ccmr1_output()
                .modify(|_, w| w.oc1m().bits(0b100).oc2m().bits(0b100));
            let tim5 = &*pac::TIM5::ptr();
            tim5.ccr(0).write(|w| w.bits(0));
            tim5.ccr(1).write(|w| w.bits(0));
            tim5.ccmr1_output()
                .modify(|_, w| w.oc1m().bits(0b100).oc2m().bits(0b100));
        }
        force_low(pac::GPIOC::ptr() as usize, &[6, 7]);
        force_low(pac::GPIOA::ptr() as usize, &[0, 1]);
    }

    /// Drives `pins` of the GPIO port at `base` low as general-purpose outputs: BSRR (offset
    /// 0x18) reset bits, then MODER (offset 0x00) to 0b01 (RM0090 section 8.4).
    fn force_low(base: usize, pins: &[u32]) {
        let reset = pins.iter().fold(0u32, |m, p| m | (1 << (16 + p)));
        let moder = base as *mut u32;
        let bsrr = (base + 0x18) as *mut u32;
        // SAFETY: `base` is a GPIO port's register block; BSRR writes are atomic per bit and
        // MODER is read-modify-written with interrupts off (fault path).
        unsafe {
            core::ptr::write_volatile(bsrr, reset);
            let m = pins.iter().fold(core::ptr::read_volatile(moder), |m, p| {
                (m & !(0b11 << (2 * p))) | (0b01 << (2 * p))
            });
            core::ptr::write_volatile(moder, m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b.iter()).all(|(x, y)| (x - y).abs() < 1e-5)
    }

    #[test]
    fn imu_axes_follow_paparazzi_lisa_mx_mapping() {
        // board = (-chip y, chip x, chip z).
        assert_eq!(IMU_AXES.apply([1.0, 2.0, 3.0]), [-2.0, 1.0, 3.0]);
    }

    #[test]
    fn mounting_rotates_body_into_board_and_back() {
        let yaw90 = Mounting {
            roll_rad: 0.0,
            pitch_rad: 0.0,
            yaw_rad: core::f32::consts::FRAC_PI_2,
        };
        // The board is turned 90 deg right: the body's forward axis is the board's -y.
        let m = yaw90.body_to_board();
        let fwd = [m[0][0], m[1][0], m[2][0]];
        assert!(close(fwd, [0.0, -1.0, 0.0]), "{fwd:?}");
        assert!(close(
            yaw90.board_to_body([0.0, -1.0, 0.0]),
            [1.0, 0.0, 0.0]
        ));
        // Any mounting is a rotation: board_to_body inverts body_to_board.
        let mount = Mounting::POCKET_DRONE;
        let v = [0.3, -1.2, 9.0];
        let m = mount.body_to_board();
        let board = [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]);
        assert!(close(mount.board_to_body(board), v));
    }

    #[test]
    fn pins_are_unique_and_sensor_nets_are_never_outputs() {
        // With the RC receiver option on, its pin joins the table.
        let all = || PINS.iter().chain(core::iter::once(&RC_PIN));
        for (i, a) in all().enumerate() {
            for b in all().skip(i + 1) {
                assert_ne!(a.pin, b.pin, "{} and {}", a.signal, b.signal);
            }
            for (p, why) in NOT_DRIVEN {
                assert_ne!(
                    a.pin, p,
                    "{} drives a pin that must not be driven: {why}",
                    a.signal
                );
            }
        }
        for m in MOTOR_OUTPUTS {
            let a = PINS
                .iter()
                .find(|a| a.pin == m.pin)
                .expect("motor pin in PINS");
            assert_eq!(a.function, Function::Alternate(2), "{}", a.signal);
        }
    }
}
