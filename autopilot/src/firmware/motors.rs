//! Four brushed motors driven by TIM3 PWM at 32 kHz (through MOSFETs), in the protocol's
//! motor order: 1 front-right (PB4, CH1), 2 rear-right (PB5, CH2), 3 rear-left (PB0, CH3),
//! 4 front-left (PB1, CH4).

use stm32f4xx_hal::pac::TIM3;
use stm32f4xx_hal::timer::PwmChannel;

/// PWM frequency of the brushed motors, Hz (above hearing, within the FETs' switching).
pub const PWM_HZ: u32 = 32_000;

/// The four motor outputs.
pub struct Motors {
    ch: (
        PwmChannel<TIM3, 0>,
        PwmChannel<TIM3, 1>,
        PwmChannel<TIM3, 2>,
        PwmChannel<TIM3, 3>,
    ),
}

impl Motors {
    /// Takes the enabled channels; outputs start at zero.
    pub fn new(
        ch: (
            PwmChannel<TIM3, 0>,
            PwmChannel<TIM3, 1>,
            PwmChannel<TIM3, 2>,
            PwmChannel<TIM3, 3>,
        ),
    ) -> Self {
        let mut m = Self { ch };
        m.set([0.0; 4]);
        m.ch.0.enable();
        m.ch.1.enable();
        m.ch.2.enable();
        m.ch.3.enable();
        m
    }

    /// Sets the throttles (each clamped to 0..=1; NaN is 0).
    pub fn set(&mut self, throttle: [f32; 4]) {
        let max = self.ch.0.get_max_duty();
        let duty = |t: f32| {
            let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
            (t * f32::from(max)) as u16
        };
        self.ch.0.set_duty(duty(throttle[0]));
        self.ch.1.set_duty(duty(throttle[1]));
        self.ch.2.set_duty(duty(throttle[2]));
        self.ch.3.set_duty(duty(throttle[3]));
    }
}
