//! A timer that only generates a clock: rigless's TIM model, woken only when something can see
//! its counter's events.
//!
//! rigless's STM32F427 timers ask the event queue to wake them at every counter event (every
//! update and every compare match). The camera board's TIM3 puts the sensors' 21 MHz master
//! clock on PA7 (CH2 in PWM mode, a period of four counts at 84 MHz): 42 million wake-ups per
//! virtual second, each of which stops the emulated core. That alone made a second of the camera
//! board take minutes of wall time.
//!
//! Nothing on the board needs those wake-ups: the sensors see the clock's frequency, which the
//! board reads off the timer's registers ([`rigless::soc::st::tim::Tim::pulse`]), not its edges;
//! the firmware does not read the timer after setting it up. So [`ClockTimer`] holds the
//! timer's model and forwards everything to it except the timer's own wake-ups while nothing
//! but the pin can observe them: no interrupt or DMA request enabled (`DIER` = 0), no slave
//! mode, no trigger output (`MMS` below update), no one-pulse mode. The model is then settled
//! lazily, at the next access: a read, a write or a clock change walks the counter up to that
//! instant exactly as a wake-up would have (rigless's own "woken when seen" policy, which its
//! other parts use). Once any of those observers is enabled, every wake-up is forwarded again.

use rigless::device::{DeviceContext, ErasedDevice, InterruptChange, RegisterFile, RequestChange};
use rigless::emulator::InterruptLine;
use rigless::soc::stm32f427::generated::tim3::{Register, cr1, cr2, smcr};
use rigless::soc::stm32f427::peripherals::tim::{General, Tim};
use rigless::soc::{RegisterSpec, Width};
use rigless::time::{EventId, VirtualNanos};

/// `CR2.MMS` codes from which the trigger output follows the counter's events (RM0090 18.4.2:
/// 0b010 update, then compare pulse and the references).
const MMS_UPDATE: u64 = 0b010;

/// One general-purpose timer used as a clock generator (see the module's notes).
#[derive(Debug)]
pub struct ClockTimer {
    /// rigless's model of the timer.
    pub timer: Tim<General>,
    /// Wake-ups dropped because nothing could see them.
    pub dropped_wakeups: u64,
}

impl ClockTimer {
    /// The timer `timer`, taken out of its part.
    #[must_use]
    pub fn new(timer: Tim<General>) -> Self {
        Self {
            timer,
            dropped_wakeups: 0,
        }
    }

    /// Whether anything but the output pins can see the counter's events now.
    fn events_observed(registers: &RegisterFile) -> bool {
        let cr1_value = registers.get(Register::Cr1);
        registers.get(Register::Dier) != 0
            || cr1::OPM.is_set(cr1_value)
            || cr2::MMS.get(registers.get(Register::Cr2)) >= MMS_UPDATE
            || smcr::SMS.get(registers.get(Register::Smcr)) != 0
    }
}

impl ErasedDevice for ClockTimer {
    fn layout(&self) -> &'static [RegisterSpec] {
        self.timer.layout()
    }

    fn read(
        &mut self,
        row: usize,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> Option<u64> {
        ErasedDevice::read(&mut self.timer, row, registers, context)
    }

    fn peek(&self, row: usize, registers: &RegisterFile, now: VirtualNanos) -> Option<u64> {
        ErasedDevice::peek(&self.timer, row, registers, now)
    }

    fn write(
        &mut self,
        row: usize,
        value: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::write(&mut self.timer, row, value, registers, context);
    }

    fn on_event(
        &mut self,
        event: EventId,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        if Self::events_observed(registers) {
            ErasedDevice::on_event(&mut self.timer, event, registers, context);
        } else {
            self.dropped_wakeups += 1;
        }
    }

    fn on_request(
        &mut self,
        request: RequestChange,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::on_request(&mut self.timer, request, registers, context);
    }

    fn on_interrupt(
        &mut self,
        change: InterruptChange,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::on_interrupt(&mut self.timer, change, registers, context);
    }

    fn acknowledge_interrupt(
        &mut self,
        line: InterruptLine,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> Option<u64> {
        ErasedDevice::acknowledge_interrupt(&mut self.timer, line, registers, context)
    }

    fn on_clock(&mut self, hz: u64, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        ErasedDevice::on_clock(&mut self.timer, hz, registers, context);
    }

    fn on_clock_input(
        &mut self,
        input: usize,
        hz: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::on_clock_input(&mut self.timer, input, hz, registers, context);
    }

    fn poll(&mut self, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        ErasedDevice::poll(&mut self.timer, registers, context);
    }

    fn reset(&mut self) {
        ErasedDevice::reset(&mut self.timer);
    }

    fn reset_line(&mut self, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        ErasedDevice::reset_line(&mut self.timer, registers, context);
    }

    fn on_access(
        &mut self,
        token: u64,
        value: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::on_access(&mut self.timer, token, value, registers, context);
    }

    fn write_region(
        &mut self,
        address: u64,
        width: Width,
        value: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> bool {
        ErasedDevice::write_region(&mut self.timer, address, width, value, registers, context)
    }

    fn on_refused(
        &mut self,
        token: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::on_refused(&mut self.timer, token, registers, context);
    }

    fn read_window(&mut self, offset: u64, width: Width, context: &mut DeviceContext<'_>) -> u64 {
        ErasedDevice::read_window(&mut self.timer, offset, width, context)
    }

    fn write_window(
        &mut self,
        offset: u64,
        width: Width,
        value: u64,
        context: &mut DeviceContext<'_>,
    ) {
        ErasedDevice::write_window(&mut self.timer, offset, width, value, context);
    }

    fn peek_window(&self, offset: u64, width: Width, now: VirtualNanos) -> Option<u64> {
        ErasedDevice::peek_window(&self.timer, offset, width, now)
    }
}
