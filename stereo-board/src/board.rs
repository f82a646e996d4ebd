//! The camera board's hardware, in one place: the TU Delft stereoboard the paper flew.
//!
//! Every pin, peripheral instance, clock, rate and polarity the firmware uses is here, each with
//! the row of `shared/hardware/original-boards.md` it comes from (\[SB\] = the stereoboard
//! firmware, `wuyou33/stereoboard_opentemp` at df6441c; [SB-17] = the same at 956375c, the
//! paper's era). The firmware configures every pin from [`PINS`], the docs and the virtual
//! board's wiring are written from it. A board wired differently changes this file only.
//!
//! Plain data, no HAL types, so that host tools (the virtual board, tests) can import it.
//!
//! Choices the sources leave open, each a one-line change here:
//! * [`CAMERA_RESET_LOW`] and [`CAMERA_RESET_RECOVERY`]: the original waits with busy
//!   loops of unstated length; the TCM8230 needs at least 100 master-clock cycles in reset and
//!   2,000 after release (the original's comments). 1 ms each is 200x and 10x that at 21 MHz.
//! * [`SCCB_HZ`]: the original's 25 kHz (the TCM8230 allows more; the bus has 2.8 V pull-ups
//!   and two sensors on it, so the slow rate is kept).
//! * [`CAMERA_STOPPED_FRAMES`]: how many frame periods without a VSYNC make the camera stopped.
//! * [`LINK_BAUD`]: 115,200 Bd as the original harness; one setting both boards share.

use board_support::pins::pin;
pub use board_support::pins::{Drive, Function, Pin, PinAssignment, Port, Pull, Speed};
use timebase::Duration;

/// Alternate function of the DCMI pins.
pub const AF_DCMI: u8 = 13;
/// Alternate function of TIM3 on PA7.
pub const AF_TIM3: u8 = 2;
/// Alternate function of I2C2 on PB10/PB11.
pub const AF_I2C2: u8 = 4;
/// Alternate function of UART4 on PA0/PA1.
pub const AF_UART4: u8 = 8;
/// Alternate function of USART2 on PA2/PA3.
pub const AF_USART2: u8 = 7;

const fn dcmi(signal: &'static str, pin: Pin) -> PinAssignment {
    PinAssignment {
        signal,
        pin,
        function: Function::Alternate(AF_DCMI),
        drive: Some(Drive::PushPull),
        pull: Pull::Up,
        speed: Some(Speed::VeryHigh),
        source: "[SB] dcmi.c:187-199 (AF13, 100 MHz, pull-up)",
    }
}

const fn gpio_out(
    signal: &'static str,
    pin: Pin,
    high: bool,
    source: &'static str,
) -> PinAssignment {
    PinAssignment {
        signal,
        pin,
        function: Function::Output { high },
        drive: Some(Drive::PushPull),
        pull: Pull::None,
        speed: Some(Speed::Low),
        source,
    }
}

/// DCMI HSYNC.
pub const DCMI_HSYNC: PinAssignment = dcmi("DCMI_HSYNC", pin(Port::A, 4));
/// DCMI pixel clock.
pub const DCMI_PIXCLK: PinAssignment = dcmi("DCMI_PIXCLK", pin(Port::A, 6));
/// DCMI VSYNC.
pub const DCMI_VSYNC: PinAssignment = dcmi("DCMI_VSYNC", pin(Port::B, 7));
/// DCMI data D0..D7 (D6/D7 on PB8/PB9).
pub const DCMI_DATA: [PinAssignment; 8] = [
    dcmi("DCMI_D0", pin(Port::C, 6)),
    dcmi("DCMI_D1", pin(Port::C, 7)),
    dcmi("DCMI_D2", pin(Port::C, 8)),
    dcmi("DCMI_D3", pin(Port::C, 9)),
    dcmi("DCMI_D4", pin(Port::C, 11)),
    dcmi("DCMI_D5", pin(Port::B, 6)),
    dcmi("DCMI_D6", pin(Port::B, 8)),
    dcmi("DCMI_D7", pin(Port::B, 9)),
];

/// Master clock of both cameras: TIM3 channel 2 output.
pub const CAMERA_CLOCK_PIN: PinAssignment = PinAssignment {
    signal: "CAM_XCLK (TIM3_CH2)",
    pin: pin(Port::A, 7),
    function: Function::Alternate(AF_TIM3),
    drive: Some(Drive::PushPull),
    pull: Pull::None,
    speed: Some(Speed::VeryHigh),
    source: "[SB] dcmi.c:116-177",
};

/// Reset of both cameras, active low: held low at start-up, released after the clock runs.
pub const CAMERA_RESET: PinAssignment =
    gpio_out("CAM_RESET_N", pin(Port::D, 2), false, "[SB] dcmi.c:84-114");

/// CPLD mode pins (PC10 "Manual", PC12 "PxMux", PB5 "LnMux"); the levels select the pixel
/// interleave `[L0 R0 L1 R1 ...]` (pixmux: 0, 1, 0), the pocket drone's mode.
pub const CPLD_MODE: [PinAssignment; 3] = [
    gpio_out("CPLD_MANUAL", pin(Port::C, 10), false, "[SB] cpld.c:17-69"),
    gpio_out(
        "CPLD_PXMUX",
        pin(Port::C, 12),
        true,
        "[SB] cpld.c:17-69, main_parameters.h:120",
    ),
    gpio_out("CPLD_LNMUX", pin(Port::B, 5), false, "[SB] cpld.c:17-69"),
];

const fn sccb(signal: &'static str, pin: Pin) -> PinAssignment {
    PinAssignment {
        signal,
        pin,
        function: Function::Alternate(AF_I2C2),
        // Open drain, no internal pull: the bus has 2.8 V pull-ups; driving it to 3.3 V would
        // harm the sensors.
        drive: Some(Drive::OpenDrain),
        pull: Pull::None,
        speed: Some(Speed::Low),
        source: "[SB] tcm8230.c:54-85",
    }
}

/// SCCB (I2C2) clock.
pub const SCCB_SCL: PinAssignment = sccb("SCCB_SCL (I2C2)", pin(Port::B, 10));
/// SCCB (I2C2) data.
pub const SCCB_SDA: PinAssignment = sccb("SCCB_SDA (I2C2)", pin(Port::B, 11));

/// A UART pin as the original sets every UART's (one GPIO set-up for all: push-pull,
/// pull-up).
const fn uart(signal: &'static str, pin: Pin, af: u8, source: &'static str) -> PinAssignment {
    PinAssignment {
        signal,
        pin,
        function: Function::Alternate(af),
        drive: Some(Drive::PushPull),
        pull: Pull::Up,
        speed: Some(Speed::Low),
        source,
    }
}

const fn link(signal: &'static str, pin: Pin) -> PinAssignment {
    uart(
        signal,
        pin,
        AF_UART4,
        "[SB-17] edgeFS.h:24-31, [SB] usart.c:376-390",
    )
}

const fn host(signal: &'static str, pin: Pin) -> PinAssignment {
    uart(signal, pin, AF_USART2, "[SB] usart.c:303-330")
}

/// Link to the autopilot: UART4 TX ("top (cpld)" connector).
pub const LINK_TX: PinAssignment = link("LINK_TX (UART4)", pin(Port::A, 0));
/// Link to the autopilot: UART4 RX.
pub const LINK_RX: PinAssignment = link("LINK_RX (UART4)", pin(Port::A, 1));

/// The board's second UART, USART2 TX: unused by the pocket drone, the host link of the `hil`
/// flavour ([`HOST_UART_USED`]).
pub const HOST_TX: PinAssignment = host("HOST_TX (USART2)", pin(Port::A, 2));
/// The board's second UART, USART2 RX (see [`HOST_TX`]).
pub const HOST_RX: PinAssignment = host("HOST_RX (USART2)", pin(Port::A, 3));

/// Status LED, active high.
pub const LED: PinAssignment = gpio_out("LED", pin(Port::B, 12), false, "[SB] led.c:15-33");
/// Level that lights [`LED`].
pub const LED_ON_HIGH: bool = true;

/// Every pin the `real` firmware configures, in the order it configures them: the CPLD mode
/// and the reset first (the cameras stay in reset until their clock runs), then the clock, the
/// DCMI bus, the SCCB bus, the link and the LED. No other pin is touched.
pub const PINS: [PinAssignment; 21] = [
    CPLD_MODE[0],
    CPLD_MODE[1],
    CPLD_MODE[2],
    CAMERA_RESET,
    CAMERA_CLOCK_PIN,
    DCMI_HSYNC,
    DCMI_PIXCLK,
    DCMI_VSYNC,
    DCMI_DATA[0],
    DCMI_DATA[1],
    DCMI_DATA[2],
    DCMI_DATA[3],
    DCMI_DATA[4],
    DCMI_DATA[5],
    DCMI_DATA[6],
    DCMI_DATA[7],
    SCCB_SCL,
    SCCB_SDA,
    LINK_TX,
    LINK_RX,
    LED,
];

/// Every pin the `hil` firmware configures, in order: the cameras held in reset (their frames
/// come over the host link, so the sensors stay off), the link, the host link (USART2) and the
/// LED. The camera's clock, DCMI, SCCB and CPLD pins stay at their reset state.
pub const HIL_PINS: [PinAssignment; 6] = [CAMERA_RESET, LINK_TX, LINK_RX, HOST_TX, HOST_RX, LED];

// ---------------------------------------------------------------------------------------------
// Clocks. [SB] stm32_flash.ld:6,45-47, Makefile:21,68, system_stm32f4xx.c:149-150.

/// The part: STM32F407VG (1 MiB flash, 128 KiB SRAM + 64 KiB CCM; the F405 has no DCMI).
pub const MCU: &str = "STM32F407VGTx";
/// Crystal, Hz.
pub const HSE_HZ: u32 = 12_000_000;
// Core clock, Hz: HSE / M=12 x N=336 / P=2, as on the autopilot.
pub use board_support::chip::SYSCLK_HZ;
/// Hertz per megahertz: a clock in Hz over this is its cycles per µs.
pub const HZ_PER_MHZ: u32 = 1_000_000;
/// APB1 bus clock, Hz (core / 4).
pub const APB1_HZ: u32 = SYSCLK_HZ / 4;
/// Clock of the timers on APB1 (TIM3), Hz: twice the bus clock because APB1 is divided.
pub const APB1_TIMER_HZ: u32 = APB1_HZ * 2;

// ---------------------------------------------------------------------------------------------
// Camera master clock: TIM3 CH2, PWM mode 1. [SB] dcmi.c:116-177.

/// TIM3 prescaler (PSC register): the counter ticks at `APB1_TIMER_HZ / (PSC + 1)`.
pub const CAMERA_CLOCK_PSC: u16 = 1;
/// TIM3 auto-reload (ARR register): the period is `ARR + 1` ticks.
pub const CAMERA_CLOCK_ARR: u16 = 1;
/// TIM3 channel 2 compare (CCR2): high for `CCR2` of the `ARR + 1` ticks, 50 % duty.
pub const CAMERA_CLOCK_CCR: u16 = 1;
/// The cameras' master clock, Hz: 84 MHz / 2 / 2 = 21 MHz.
pub const CAMERA_CLOCK_HZ: u32 =
    APB1_TIMER_HZ / (CAMERA_CLOCK_PSC as u32 + 1) / (CAMERA_CLOCK_ARR as u32 + 1);
const _: () = assert!(CAMERA_CLOCK_HZ == 21_000_000);

/// Time the cameras are held in reset with their clock running (see the module docs).
pub const CAMERA_RESET_LOW: Duration = Duration::from_millis(1);
/// Time after releasing reset before the first SCCB access (see the module docs).
pub const CAMERA_RESET_RECOVERY: Duration = Duration::from_millis(1);
const _: () =
    assert!(CAMERA_RESET_LOW.as_micros() * CAMERA_CLOCK_HZ as u64 >= 100 * HZ_PER_MHZ as u64);
const _: () = assert!(
    CAMERA_RESET_RECOVERY.as_micros() * CAMERA_CLOCK_HZ as u64 >= 2_000 * HZ_PER_MHZ as u64
);

// ---------------------------------------------------------------------------------------------
// Frame timing, from the camera set-up.

/// Master clock at which the TCM8230's fast mode gives 30 fps, Hz (\[SB\] dcmi.c's comment).
pub const TCM8230_NOMINAL_CLOCK_HZ: u32 = 25_540_000;
/// Frame rate of the TCM8230's fast mode at its nominal clock, fps.
pub const TCM8230_NOMINAL_FPS: u32 = 30;
/// One frame of the TCM8230 in master-clock cycles (its timing is counted in clock cycles).
pub const FRAME_CLOCKS: u32 = TCM8230_NOMINAL_CLOCK_HZ / TCM8230_NOMINAL_FPS;
/// Frame period of the cameras at [`CAMERA_CLOCK_HZ`] (to the nearest microsecond): 851,333
/// cycles at 21 MHz = 40,540 µs, i.e. **25 fps** (24.7). The frame task's deadline.
pub const FRAME_PERIOD: Duration = Duration::from_micros(
    (FRAME_CLOCKS as u64 * 1_000_000 + CAMERA_CLOCK_HZ as u64 / 2) / CAMERA_CLOCK_HZ as u64,
);
const _: () = assert!(FRAME_PERIOD.as_micros() > 40_000 && FRAME_PERIOD.as_micros() < 41_000);

/// Frame periods without a VSYNC after which the camera counts as stopped (200 ms).
pub const CAMERA_STOPPED_FRAMES: u32 = 5;

// ---------------------------------------------------------------------------------------------
// DCMI and DMA. [SB] camera_type.h:51, dcmi.c:245-246,264,289-298, main_parameters.h:126-129.

/// DCMI samples data on the falling pixel-clock edge (the TCM8230 with its clock polarity bit
/// set, register 0x02 bit 1).
pub const DCMI_PIXCLK_RISING: bool = false;
/// HSYNC is active (blanking) low.
pub const DCMI_HSYNC_BLANKING_HIGH: bool = false;
/// VSYNC is active (blanking) low.
pub const DCMI_VSYNC_BLANKING_HIGH: bool = false;
/// Crop window: pixel clocks captured per line (128 stereo pixels, 2 bytes each).
pub const CROP_PIXEL_CLOCKS: u16 = 256;
/// Crop window: lines captured per frame.
pub const CROP_LINES: u16 = 96;
/// Crop window: first line captured.
pub const CROP_FIRST_LINE: u16 = 0;
/// Crop window: first pixel clock captured in a line.
pub const CROP_FIRST_PIXEL_CLOCK: u16 = 0;
/// Bytes per captured frame, as the DMA moves them.
pub const FRAME_BYTES: usize = CROP_PIXEL_CLOCKS as usize * CROP_LINES as usize;
const _: () = assert!(FRAME_BYTES == protocol::STEREO_FRAME_BYTES);
/// DMA controller of the DCMI (DMA2; stream 1, channel 1).
pub const DCMI_DMA_STREAM: u8 = 1;
/// DMA channel (request) of the DCMI on stream 1.
pub const DCMI_DMA_CHANNEL: u8 = 1;

// ---------------------------------------------------------------------------------------------
// SCCB. [SB] tcm8230.c:54-85,104.

/// SCCB (I2C2) clock, Hz.
pub const SCCB_HZ: u32 = 25_000;
/// 7-bit bus address of the TCM8230 pair (both answer together through the CPLD).
pub const TCM8230_ADDRESS: u8 = 0x3C;

// ---------------------------------------------------------------------------------------------
// Link. [SB-17] edgeFS.h:24-31, [SB] usart.c:376-390.

/// The autopilot link: UART4 (PA0 TX, PA1 RX).
pub const LINK_UART: &str = "UART4";
/// Link baud rate, 8N1: the one setting both boards share ([`board_support::link::LINK_BAUD`],
/// 115,200 Bd as the original harness runs).
pub const LINK_BAUD: u32 = board_support::link::LINK_BAUD;
/// A second UART (USART2, PA2/PA3: [`HOST_TX`], [`HOST_RX`]) exists on the board; the pocket
/// drone leaves it unused, so the `real` firmware does not touch it (\[SB\] usart.c:303-330). The
/// `hil` flavour takes its host link there ([`HIL_PINS`]).
pub const HOST_UART_USED: bool = false;

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::{format, string::String, vec::Vec};

    #[test]
    fn no_pin_is_assigned_twice() {
        let all: Vec<&PinAssignment> = PINS.iter().chain([&HOST_TX, &HOST_RX]).collect();
        for (i, a) in all.iter().enumerate() {
            assert!(a.pin.number < 16, "{} has pin {}", a.signal, a.pin.number);
            for b in all.iter().skip(i + 1) {
                assert_ne!(a.pin, b.pin, "{} and {} share a pin", a.signal, b.signal);
            }
        }
    }

    #[test]
    fn table_matches_the_original_board() {
        let name = |a: &PinAssignment| format!("P{}{}", a.pin.port.letter(), a.pin.number);
        let data: Vec<String> = DCMI_DATA.iter().map(name).collect();
        assert_eq!(
            data,
            ["PC6", "PC7", "PC8", "PC9", "PC11", "PB6", "PB8", "PB9"]
        );
        assert_eq!(name(&DCMI_HSYNC), "PA4");
        assert_eq!(name(&DCMI_PIXCLK), "PA6");
        assert_eq!(name(&DCMI_VSYNC), "PB7");
        assert_eq!(name(&CAMERA_CLOCK_PIN), "PA7");
        assert_eq!(name(&CAMERA_RESET), "PD2");
        assert_eq!(name(&LED), "PB12");
        assert_eq!(
            (name(&LINK_TX), name(&LINK_RX)),
            ("PA0".into(), "PA1".into())
        );
        assert_eq!(
            (name(&SCCB_SCL), name(&SCCB_SDA)),
            ("PB10".into(), "PB11".into())
        );
        assert_eq!(
            (name(&HOST_TX), name(&HOST_RX)),
            ("PA2".into(), "PA3".into())
        );
        assert_eq!(HOST_TX.function, Function::Alternate(7));
        let cpld: Vec<(String, Function)> =
            CPLD_MODE.iter().map(|a| (name(a), a.function)).collect();
        assert_eq!(
            cpld,
            [
                ("PC10".into(), Function::Output { high: false }),
                ("PC12".into(), Function::Output { high: true }),
                ("PB5".into(), Function::Output { high: false }),
            ]
        );
        assert_eq!(CAMERA_RESET.function, Function::Output { high: false });
    }

    #[test]
    fn frame_rate_is_25_fps() {
        let fps = 1.0 / FRAME_PERIOD.as_secs_f64();
        assert!((fps - 24.67).abs() < 0.01, "{fps}");
    }
}
