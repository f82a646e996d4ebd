//! Motor outputs read as a FET gate sees them: the PWM duty on a timer channel's pin.
//!
//! A motor's duty is the timer channel's pulse (rigless's `Tim::pulse`: high time over period,
//! through the channel's polarity) when its pin is in alternate-function mode with the timer's
//! function selected; a pin driven as a GPIO output is a constant 0 or 1; any other pin (input,
//! analog, another function) drives nothing and the gate's pull-down holds the FET off: 0.

use rigless::device::Level;
use rigless::mcu::Mcu;
use rigless::soc::st::tim::Channel;
use rigless::soc::stm32f427::generated::gpioa;
use rigless::soc::stm32f427::peripherals::PORTS;
use rigless::soc::stm32f427::peripherals::gpio::{Gpio, Pin};

use crate::soc::Soc;

/// One motor output: the pin and the timer channel that should drive it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorPin {
    /// The port, `GPIOA`...
    pub port: &'static str,
    /// The pin number.
    pub pin: u8,
    /// The general-purpose timer, `TIM2`..`TIM5`.
    pub timer: &'static str,
    /// The channel, 1..=4.
    pub channel: u8,
    /// The alternate function that routes the timer to the pin (datasheet table 9).
    pub function: u8,
}

/// What a motor output does now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Output {
    /// Duty, 0..=1.
    pub duty: f64,
    /// PWM period, ns (`None`: not a PWM output now).
    pub period_ns: Option<u64>,
}

fn timer_index(name: &str) -> Option<usize> {
    ["TIM2", "TIM3", "TIM4", "TIM5"]
        .iter()
        .position(|t| *t == name)
}

fn port_index(name: &str) -> Option<usize> {
    PORTS.iter().position(|p| *p == name)
}

/// The output on `motor` now.
#[must_use]
pub fn output(soc: &Soc, motor: &MotorPin) -> Output {
    let off = Output {
        duty: 0.0,
        period_ns: None,
    };
    let (Some(port), Some(pin), Some(timer), Some(channel)) = (
        port_index(motor.port),
        Pin::new(motor.pin),
        timer_index(motor.timer),
        Channel::new(motor.channel),
    ) else {
        return off;
    };
    let bus = soc.bus();
    let Some(port_regs) = bus.registers(motor.port) else {
        return off;
    };
    let mode = (port_regs.get(gpioa::Register::Moder) >> (2 * motor.pin)) & 3;
    match mode {
        // Output: the ODR bit.
        1 => {
            let high = soc.mcu.gpio[port].level(pin, port_regs) == Level::High;
            Output {
                duty: if high { 1.0 } else { 0.0 },
                period_ns: None,
            }
        }
        2 if Gpio::function(pin, port_regs) == Some(motor.function) => {
            let Some(timer_regs) = bus.registers(motor.timer) else {
                return off;
            };
            let tim = &soc.mcu.tim[timer];
            match tim.pulse(channel, timer_regs) {
                Some(pulse) if pulse.period.0 > 0 => Output {
                    duty: pulse.width.0 as f64 / pulse.period.0 as f64,
                    period_ns: Some(pulse.period.0),
                },
                _ => Output {
                    duty: if tim.output(channel, timer_regs) == Some(Level::High) {
                        1.0
                    } else {
                        0.0
                    },
                    period_ns: None,
                },
            }
        }
        _ => off,
    }
}
