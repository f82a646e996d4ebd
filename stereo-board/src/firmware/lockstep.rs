//! The lockstep flavours, `hil` and `qemu`: the camera board in step with a host's world
//! simulation (`sim-host hil`, the virtual boards, QEMU).
//!
//! * Frames arrive over the host link (USART2, [`host_link`]) in chunks, assembled into one
//!   frame slot ([`FrameSlot`]) the frame task takes; a frame completed before the previous
//!   one was processed replaces it and counts as dropped ([`HostFrames::on_bytes`]). Estimates
//!   and heartbeats are mirrored to the host.
//! * The library clock is the world time of the host's simulation ([`Current`]): frames carry
//!   their exposure time in world time and the autopilot, which runs in lockstep with the host,
//!   stamps its gyro samples with world time ([`on_link_bytes`]), so gyro ages and processing
//!   times are measured on one clock however slowly the link lets the world run.
//! * The cameras are held in reset (`hil`) and the DCMI, its DMA and SCCB stay off: their
//!   interrupts never fire ([`on_dcmi_interrupt`], [`on_dma_interrupt`]) and the capture path
//!   has nothing to report ([`check_camera`]).
//! * Pins: `hil` configures the board's link and host UART pins, the camera reset and the LED
//!   ([`stereo_board::board::HIL_PINS`]); `qemu` the LED only. The link UART ([`LinkUart`]) is
//!   the board's UART4 in `hil`, USART1 on QEMU's machine.

use super::{log, pins, HostLink, HostStore};
use board_support::flavour::host_receiver;
use core::sync::atomic::AtomicU32;
use protocol::{CaptureCounts, STEREO_FRAME_BYTES};
use stereo_board::app::{FrameAssembler, StereoBoardApp};
use stereo_board::board::PinAssignment;
use stereo_board::camera::CaptureMonitor;
use stm32f4xx_hal::gpio::{PA2, PA3};
use stm32f4xx_hal::rcc::Rcc;
use stm32f4xx_hal::{pac, prelude::*, serial};
use timebase::{Instant, WorldTime, WrapExtender};

/// The flavour's side of the contract both boards' flavour modules fulfil.
pub struct Current;

impl board_support::flavour::Flavour for Current {
    /// Frames come from the host's world; the cameras stay off.
    const OWN_SENSORS: bool = false;
    /// The heartbeat-fed timeout both boards share (the 1 Hz status task feeds it).
    const WATCHDOG: board_support::watchdog::Timeout = board_support::watchdog::HEARTBEAT_FED;

    /// The world time, as the frames' exposure times and the autopilot's gyro timestamps
    /// carry it.
    fn lib_now() -> Instant {
        cortex_m::interrupt::free(|cs| WORLD.borrow(cs).borrow().0)
    }
}

/// The library clock (the world time as the flight clock), and the extender of the autopilot's
/// wire gyro timestamps onto the world's timeline.
static WORLD: cortex_m::interrupt::Mutex<core::cell::RefCell<(Instant, WrapExtender<WorldTime>)>> =
    cortex_m::interrupt::Mutex::new(core::cell::RefCell::new((
        Instant::ZERO,
        WrapExtender::new(),
    )));

/// A world time seen on a link (a frame's exposure time, as the flight clock): the library
/// clock moves forward to it (never back).
fn observe_world(t: Instant) {
    cortex_m::interrupt::free(|cs| {
        let mut w = WORLD.borrow(cs).borrow_mut();
        w.0 = w.0.max(t);
    });
}

/// After a batch of the autopilot's bytes: the library clock moves to its latest gyro timestamp
/// (its world time, a wire time).
pub fn on_link_bytes(board: &StereoBoardApp) {
    if let Some(g) = board.latest_gyro() {
        let t = g.timestamp_us;
        cortex_m::interrupt::free(|cs| {
            let mut w = WORLD.borrow(cs).borrow_mut();
            let t = w.1.extend(t).as_flight_clock();
            w.0 = w.0.max(t);
        });
    }
}

/// Bytes of the host link's receive and transmit queues.
pub const HOST_QUEUE: (usize, usize) = (super::RX_QUEUE, super::TX_QUEUE);

/// The link UART: the board's UART4 (`hil`); USART1 on QEMU's machine (`qemu`), its first
/// `-serial` port.
#[cfg(not(feature = "qemu"))]
pub type LinkUart = pac::UART4;
/// The link UART (see the `hil` flavour's).
#[cfg(feature = "qemu")]
pub type LinkUart = pac::USART1;

/// Whether this is the `qemu` flavour (QEMU's netduinoplus2 rather than the board).
const QEMU: bool = cfg!(feature = "qemu");

/// The pins this flavour configures: the board's link and host UART pins, the camera reset and
/// the LED (`hil`); QEMU's machine has the LED only.
const PINS: &[PinAssignment] = if QEMU {
    &[stereo_board::board::LED]
} else {
    &stereo_board::board::HIL_PINS
};

/// A frame handed from the host-link task to the frame task: the buffer and its exposure time
/// (`None`: empty).
pub struct FrameSlot {
    buf: [u8; STEREO_FRAME_BYTES],
    capture: Option<Instant>,
}

impl FrameSlot {
    const fn new() -> Self {
        Self {
            buf: [0; STEREO_FRAME_BYTES],
            capture: None,
        }
    }
}

/// The frame slot (SRAM).
static mut SLOT: FrameSlot = FrameSlot::new();

/// The frame assembler (SRAM).
static mut ASSEMBLER: FrameAssembler = FrameAssembler::new();

/// Where the frame task finds its frame.
pub type Frames = &'static mut FrameSlot;

/// What the frame task is spawned with: nothing, the frame is in the slot.
pub type FrameReady = ();

impl super::FrameSource for &'static mut FrameSlot {
    fn take(&mut self, _: &()) -> Option<(&[u8; STEREO_FRAME_BYTES], Instant)> {
        let capture = self.capture.take()?;
        Some((&self.buf, capture))
    }
    // The slot is written only by `host_rx`, under the same lock as the frame task's.
    fn intact(_: &()) -> bool {
        true
    }
    fn release(_: &()) {}
}

/// The host link's frame path: the assembler of the frames' chunks.
pub struct HostFrames {
    assembler: &'static mut FrameAssembler,
}

impl HostFrames {
    /// Decodes the host's `bytes` and assembles frame chunks; a completed frame goes to the
    /// frame slot (replacing, and counting as dropped, one that was not processed yet).
    /// Returns what to spawn the frame task with when a frame is ready.
    pub fn on_bytes(
        &mut self,
        board: &mut StereoBoardApp,
        slot: &mut Frames,
        bytes: &[u8],
    ) -> Option<FrameReady> {
        let mut ready = false;
        board.on_host_bytes(bytes, self.assembler, |frame, capture| {
            let replaced = slot.capture.is_some();
            slot.buf.copy_from_slice(frame);
            slot.capture = Some(capture);
            observe_world(capture);
            ready = true;
            replaced
        });
        ready.then_some(())
    }
}

/// The host link (frames in, estimates mirrored out): USART2 on PA2/PA3 at
/// [`board_support::link::HOST_BAUD`], its receiver by RXNE or DMA
/// ([`board_support::flavour::host_receiver`]). Called once, from `init`.
pub fn host_link(
    usart: pac::USART2,
    pins: (PA2, PA3),
    rcc: &mut Rcc,
    store: &'static mut HostStore,
    lost: &'static AtomicU32,
) -> Option<HostLink> {
    let (tx, rx) = usart
        .serial::<u8>(
            pins,
            serial::Config::default().baudrate(board_support::link::HOST_BAUD.bps()),
            rcc,
        )
        .unwrap_or_else(|_| log::fatal("USART2 configuration"))
        .split();
    let rx = host_receiver(rx, super::board::HOST_RX_DMA);
    let (writer, interrupt, reader) = store.split(pac::Interrupt::USART2, tx, rx, lost);
    // SAFETY: `init` calls this once; this is the only reference ever made to ASSEMBLER.
    #[allow(static_mut_refs)]
    let assembler = unsafe { &mut *core::ptr::addr_of_mut!(ASSEMBLER) };
    Some((writer, interrupt, reader, HostFrames { assembler }))
}

/// This flavour's pins, and the frame slot. Called once, from `init`.
pub fn start_frames(_i2c: pac::I2C2) -> (Frames, CaptureMonitor) {
    pins::configure(PINS);
    // SAFETY: `init` calls this once; this is the only reference ever made to SLOT.
    #[allow(static_mut_refs)]
    let slot = unsafe { &mut *core::ptr::addr_of_mut!(SLOT) };
    (slot, CaptureMonitor::new())
}

/// The DCMI's interrupt: never enabled in these flavours (no camera), no frame.
pub fn on_dcmi_interrupt(_m: &mut CaptureMonitor, _now: Instant) -> Option<FrameReady> {
    None
}

/// The camera DMA's interrupt: never enabled in these flavours.
pub fn on_dma_interrupt(_m: &mut CaptureMonitor) {}

/// The capture path: off, nothing to report.
pub fn check_camera(_m: &mut CaptureMonitor, _now: Instant) -> Option<(CaptureCounts, bool)> {
    None
}
