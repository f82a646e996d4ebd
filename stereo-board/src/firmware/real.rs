//! The `real` flavour: the camera board on its own cameras.
//!
//! * Frames come from the two TCM8230s through the CPLD onto the DCMI, into a double buffer by
//!   DMA ([`dcmi`]); the cameras are brought up over SCCB ([`sccb`]) at start-up as the original
//!   board does ([`start_frames`]), and the status task reports a stopped camera and re-arms
//!   capture ([`check_camera`]).
//! * The library clock is the board clock ([`Current`]).
//! * No host link: the board's second UART (USART2) stays untouched
//!   ([`stereo_board::board::HOST_UART_USED`]), so [`HostFrames`] has no value.
//! * Every pin of the board table is configured ([`stereo_board::board::PINS`]).

#[path = "dcmi.rs"]
mod dcmi;
#[path = "sccb.rs"]
mod sccb;

pub use dcmi::{on_dcmi_interrupt, on_dma_interrupt};

use super::{clock, log, pins, HostLink, HostStore};
use core::sync::atomic::AtomicU32;
use protocol::{CaptureCounts, STEREO_FRAME_BYTES};
use stereo_board::app::StereoBoardApp;
use stereo_board::camera::CaptureMonitor;
use stm32f4xx_hal::gpio::{PA2, PA3};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Rcc;
use timebase::{Duration, Instant};

/// The flavour's side of the contract both boards' flavour modules fulfil.
pub struct Current;

impl board_support::flavour::Flavour for Current {
    /// The board's own cameras.
    const OWN_SENSORS: bool = true;
    /// The heartbeat-fed timeout both boards share (the 1 Hz status task feeds it).
    const WATCHDOG: board_support::watchdog::Timeout = board_support::watchdog::HEARTBEAT_FED;

    /// The board clock.
    fn lib_now() -> Instant {
        clock::now()
    }
}

/// The link UART: the board's UART4 ([`stereo_board::board::LINK_UART`]).
pub type LinkUart = pac::UART4;

/// Nothing to take from the autopilot's messages: the library runs on the board clock.
pub fn on_link_bytes(_board: &StereoBoardApp) {}

/// Bytes of the host link's receive and transmit queues: tokens, there is no host link.
pub const HOST_QUEUE: (usize, usize) = (2, 2);

/// The host link's frame path: none in this flavour, no value of it exists.
pub enum HostFrames {}

impl HostFrames {
    /// Never called: no value exists.
    pub fn on_bytes(
        &mut self,
        _board: &mut StereoBoardApp,
        _frames: &mut Frames,
        _bytes: &[u8],
    ) -> Option<FrameReady> {
        match *self {}
    }
}

/// No host link: USART2 and its pins are left at reset.
pub fn host_link(
    _usart: pac::USART2,
    _pins: (PA2, PA3),
    _rcc: &mut Rcc,
    _store: &'static mut HostStore,
    _lost: &'static AtomicU32,
) -> Option<HostLink> {
    None
}

/// The camera's double buffer (the buffers themselves live in [`dcmi`]).
pub struct Camera;

/// Where the frame task finds its frame.
pub type Frames = Camera;

/// What the frame task is spawned with: the delivered DMA buffer.
pub type FrameReady = dcmi::Delivered;

impl super::FrameSource for Camera {
    fn take(&mut self, ready: &FrameReady) -> Option<(&[u8; STEREO_FRAME_BYTES], Instant)> {
        dcmi::frame(ready).map(|f| (f, ready.capture))
    }
    fn intact(ready: &FrameReady) -> bool {
        dcmi::intact(ready)
    }
    fn release(ready: &FrameReady) {
        dcmi::release(ready);
    }
}

/// Every pin of the board table (CPLD in pixel-mux mode, cameras held in reset, clock, DCMI
/// and SCCB pins, the link's pull-ups, the LED), the cameras brought up, capture started.
pub fn start_frames(i2c: pac::I2C2) -> (Frames, CaptureMonitor) {
    pins::configure(&stereo_board::board::PINS);
    match bring_up_cameras(i2c) {
        Ok(()) => log::info!("cameras configured"),
        Err((reg, e)) => {
            defmt::error!("camera set-up failed at register {=u8:#x}: {}", reg, e)
        }
    }
    let mut capture = CaptureMonitor::new();
    dcmi::configure();
    dcmi::start(&mut capture, clock::now());
    (Camera, capture)
}

/// The status task's look at the capture path at board time `now`: its counts, and whether the
/// camera stopped (then capture is re-armed).
pub fn check_camera(m: &mut CaptureMonitor, now: Instant) -> Option<(CaptureCounts, bool)> {
    let stopped = m.camera_stopped(now);
    if stopped {
        dcmi::rearm(m);
    }
    Some((m.counts(), stopped))
}

/// Busy-waits `d` on the core clock (start-up only; to the microsecond).
fn busy_wait(d: Duration) {
    let us = u32::try_from(d.as_micros()).unwrap_or(u32::MAX);
    cortex_m::asm::delay(
        us.saturating_mul(stereo_board::board::SYSCLK_HZ / stereo_board::board::HZ_PER_MHZ),
    );
}

/// Brings the cameras up as the original board does: CPLD mode and reset are already set by
/// the pin table (reset held low); clock on, reset released after
/// [`stereo_board::board::CAMERA_RESET_LOW`], registers written after
/// [`stereo_board::board::CAMERA_RESET_RECOVERY`] and each read back. Returns the first
/// register that failed, if any.
fn bring_up_cameras(i2c: pac::I2C2) -> Result<(), (u8, sccb::SccbError)> {
    use stereo_board::board;
    use stereo_board::camera::tcm8230;
    dcmi::start_camera_clock();
    busy_wait(board::CAMERA_RESET_LOW);
    pins::set(&board::CAMERA_RESET, true);
    busy_wait(board::CAMERA_RESET_RECOVERY);
    let mut bus = sccb::Sccb::new(i2c);
    for &(reg, value) in &tcm8230::SETUP {
        bus.write(reg, value).map_err(|e| (reg, e))?;
        match bus.read(reg) {
            Ok(v) if v == value => {}
            Ok(_) => return Err((reg, sccb::SccbError::Bus)),
            Err(e) => return Err((reg, e)),
        }
    }
    Ok(())
}
