//! Sets the board's pins up from its wiring table ([`stereo_board::board::PINS`]): the one
//! place that says which pin does what, so the firmware follows the table instead of repeating
//! it in typed pins.
//!
//! Registers per RM0090 §8.4 (GPIOx at `0x4002_0000 + 0x400 * port`): MODER, OTYPER, OSPEEDR,
//! PUPDR, BSRR, AFRL/AFRH. An output is driven to its start level (BSRR) before it becomes an
//! output, and an alternate function is selected before the pin leaves input mode, so no pin
//! glitches.

use stereo_board::board::{Drive, Function, PinAssignment, Pull, Speed};
use stm32f4xx_hal::pac;

const GPIO_BASE: usize = 0x4002_0000;
const MODER: usize = 0x00;
const OTYPER: usize = 0x04;
const OSPEEDR: usize = 0x08;
const PUPDR: usize = 0x0C;
const BSRR: usize = 0x18;
const AFRL: usize = 0x20;

fn reg(port: u8, offset: usize) -> *mut u32 {
    (GPIO_BASE + 0x400 * usize::from(port) + offset) as *mut u32
}

/// Sets `width` bits at field `index` of register `offset` of `port` to `value`.
///
/// # Safety
/// The caller owns the pin (start-up, interrupts off).
unsafe fn set_field(port: u8, offset: usize, index: u8, width: u8, value: u32) {
    let shift = u32::from(index) * u32::from(width);
    let mask = ((1u32 << width) - 1) << shift;
    let r = reg(port, offset);
    // SAFETY: `r` is a GPIO register of the STM32F407 (RM0090 §8.4); the caller owns the pin.
    unsafe {
        let old = core::ptr::read_volatile(r);
        core::ptr::write_volatile(r, (old & !mask) | ((value << shift) & mask));
    }
}

/// Configures one pin as its table row says.
fn apply(a: &PinAssignment) {
    let port = a.pin.port.index();
    let n = a.pin.number & 0xF;
    // SAFETY: called from `init` only (interrupts off), on the pins of the board table, which
    // no HAL driver owns.
    unsafe {
        // A row without an output stage leaves OTYPER and OSPEEDR as they are (every row of
        // this board's tables states both).
        if let Some(drive) = a.drive {
            set_field(port, OTYPER, n, 1, u32::from(drive == Drive::OpenDrain));
        }
        if let Some(speed) = a.speed {
            let code = match speed {
                Speed::Low => 0,
                Speed::VeryHigh => 3,
            };
            set_field(port, OSPEEDR, n, 2, code);
        }
        let pull = match a.pull {
            Pull::None => 0,
            Pull::Up => 1,
        };
        set_field(port, PUPDR, n, 2, pull);
        match a.function {
            Function::Output { high } => {
                let bit = if high { 1u32 << n } else { 1u32 << (n + 16) };
                core::ptr::write_volatile(reg(port, BSRR), bit);
                set_field(port, MODER, n, 2, 0b01);
            }
            Function::Alternate(af) => {
                set_field(
                    port,
                    AFRL + usize::from(n / 8) * 4,
                    n % 8,
                    4,
                    u32::from(af & 0xF),
                );
                set_field(port, MODER, n, 2, 0b10);
            }
        }
    }
}

/// Enables the GPIO ports' clocks and configures `pins` (start-up only).
pub fn configure(pins: &[PinAssignment]) {
    // SAFETY: only GPIO clock-enable bits are set, read-modify-write at start-up.
    let rcc = unsafe { &*pac::RCC::ptr() };
    let ports = pins.iter().fold(0u32, |m, a| m | (1 << a.pin.port.index()));
    let enabled = rcc.ahb1enr().read().bits() | ports;
    // SAFETY: only GPIO clock-enable bits are added; the other bits are written back unchanged.
    rcc.ahb1enr().write(|w| unsafe { w.bits(enabled) });
    // Two AHB cycles before the ports answer (RM0090 §6.3.10 note): read back once.
    let _ = rcc.ahb1enr().read();
    for a in pins {
        apply(a);
    }
}

/// Drives output pin `a` to `high` (BSRR, atomic).
pub fn set(a: &PinAssignment, high: bool) {
    let n = a.pin.number & 0xF;
    let bit = if high { 1u32 << n } else { 1u32 << (n + 16) };
    // SAFETY: BSRR writes are atomic and touch only this pin.
    unsafe { core::ptr::write_volatile(reg(a.pin.port.index(), BSRR), bit) };
}

/// Toggles output pin `a` (reads ODR, then BSRR).
pub fn toggle(a: &PinAssignment) {
    let n = a.pin.number & 0xF;
    // SAFETY: ODR is read only; the write is BSRR, which touches only this pin.
    let odr = unsafe { core::ptr::read_volatile(reg(a.pin.port.index(), 0x14)) };
    set(a, odr & (1 << n) == 0);
}
