//! Camera capture on the PAC (stm32f4xx-hal has no DCMI driver): the cameras' master clock
//! (TIM3 CH2), the DCMI with hardware sync and a crop window, and DMA2 stream 1 channel 1 in
//! double-buffer mode, with every frame checked before it is handed on.
//!
//! The stereo camera delivers left and right luminance interleaved (`[L0 R0 L1 R1 ...]`, 256
//! bytes per line, 96 lines). The DCMI packs four bytes into each 32-bit data-register read and
//! the DMA moves one frame's words into one of two SRAM buffers, then switches to the other on
//! its own (`CT` names the one it writes).
//!
//! Interrupts (both at the highest task priority):
//! * DCMI: FRAME (capture of a frame ended), VSYNC (the camera's sign of life), OVR (the DMA
//!   did not drain the DCMI FIFO in time), ERR (sync error). At FRAME the DMA's state decides
//!   whether the frame is whole ([`CaptureMonitor::on_frame_end`]): whole frames go to the
//!   frame task, torn ones are dropped and capture is re-armed. OVR and ERR re-arm at once.
//! * DMA2 stream 1: transfer error (the stream stops: re-arm at once) and direct-mode error
//!   (data lost: the frame is torn). The transfer-complete flag is polled at FRAME instead of
//!   interrupting, so that the frame boundary has one source, the DCMI.
//!
//! Re-arming stops the DMA and the DCMI, reloads a full frame's count into the buffer the frame
//! task does not hold, and restarts capture, which the DCMI begins at the next frame start: the
//! following frame lands aligned in a buffer.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use protocol::STEREO_FRAME_BYTES;
use stereo_board::board;
use stereo_board::camera::{CaptureMonitor, DmaAtFrameEnd, FrameEnd, FRAME_WORDS};
use stm32f4xx_hal::pac;
use timebase::Instant;

/// Two frame buffers in SRAM (DMA-reachable; CCM is not), word-aligned for the DMA.
#[repr(C, align(4))]
struct Frames([[u8; STEREO_FRAME_BYTES]; 2]);

static mut FRAMES: Frames = Frames([[0; STEREO_FRAME_BYTES]; 2]);

/// Buffer `i` has been handed to the frame task and not released yet.
static BUSY: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];

/// Frame ends seen since boot (whole or torn): a delivered buffer is intact while this has not
/// moved on (the DMA refills it only after the next frame end).
static FRAME_ENDS: AtomicU32 = AtomicU32::new(0);

/// A whole frame handed to the frame task.
#[derive(Debug, Clone, Copy)]
pub struct Delivered {
    /// Buffer index, 0 or 1.
    pub index: usize,
    /// End of the frame's read-out, on the board clock.
    pub capture: Instant,
    /// [`FRAME_ENDS`] when it was delivered.
    seq: u32,
}

/// Polls of the DMA's transfer-complete flag at a frame end while the last words are still on
/// their way from the DCMI FIFO (8 words) to memory.
const DRAIN_POLLS: u32 = 64;

// SAFETY (for every `unsafe { &*pac::X::ptr() }` below): DMA2 stream 1, the DCMI and TIM3
// belong to this module alone; its functions run in `init` or in the two interrupt handlers,
// which share one priority and so never preempt each other.
fn dma() -> &'static pac::dma2::RegisterBlock {
    // SAFETY: see above; the register block is always mapped.
    unsafe { &*pac::DMA2::ptr() }
}
fn dcmi() -> &'static pac::dcmi::RegisterBlock {
    // SAFETY: see above; the register block is always mapped.
    unsafe { &*pac::DCMI::ptr() }
}

/// Starts the cameras' master clock: TIM3 channel 2, PWM mode 1, [`board::CAMERA_CLOCK_HZ`]
/// at 50 % duty (PSC, ARR, CCR2 from the board). The pin (PA7, AF2) is set by the board table.
pub fn start_camera_clock() {
    // SAFETY: only TIM3's enable bit is touched here (see the module's ownership note).
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.apb1enr().modify(|_, w| w.tim3en().set_bit());
    // SAFETY: TIM3 belongs to this module.
    let tim = unsafe { &*pac::TIM3::ptr() };
    tim.cr1().write(|w| w.cen().clear_bit());
    tim.psc().write(|w| w.psc().set(board::CAMERA_CLOCK_PSC));
    tim.arr().write(|w| w.arr().set(board::CAMERA_CLOCK_ARR));
    tim.ccr2().write(|w| w.ccr().set(board::CAMERA_CLOCK_CCR));
    tim.ccmr1_output()
        .modify(|_, w| w.cc2s().output().oc2m().pwm_mode1().oc2pe().enabled());
    tim.ccer()
        .modify(|_, w| w.cc2p().clear_bit().cc2e().set_bit());
    tim.cr1().modify(|_, w| w.arpe().enabled());
    // Load PSC/ARR/CCR2 from their preload registers, then count.
    tim.egr().write(|w| w.ug().set_bit());
    tim.cr1().modify(|_, w| w.cen().set_bit());
}

/// Configures the DCMI (hardware sync, polarities and crop from the board, continuous capture,
/// 8-bit data) and DMA2 stream 1 (channel 1, words, double buffer, a frame per buffer) and
/// their interrupts, without starting capture.
pub fn configure() {
    // SAFETY: only the DMA2 and DCMI enable bits are touched here.
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.ahb1enr().modify(|_, w| w.dma2en().set_bit());
    rcc.ahb2enr().modify(|_, w| w.dcmien().set_bit());
    let dcmi = dcmi();
    dcmi.cr().write(|w| {
        w.cm().continuous();
        w.ess().hardware();
        w.fcrc().all();
        w.edm().bit_width8();
        w.crop().set_bit();
        if board::DCMI_PIXCLK_RISING {
            w.pckpol().rising_edge();
        } else {
            w.pckpol().falling_edge();
        }
        if board::DCMI_HSYNC_BLANKING_HIGH {
            w.hspol().active_high();
        } else {
            w.hspol().active_low();
        }
        if board::DCMI_VSYNC_BLANKING_HIGH {
            w.vspol().active_high()
        } else {
            w.vspol().active_low()
        }
    });
    // Crop window (RM0090 §15.5.7-8): counts minus one; CAPCNT in pixel clocks.
    dcmi.cwstrt().write(|w| {
        w.vst().set(board::CROP_FIRST_LINE);
        w.hoffcnt().set(board::CROP_FIRST_PIXEL_CLOCK)
    });
    dcmi.cwsize().write(|w| {
        w.vline().set(board::CROP_LINES - 1);
        w.capcnt().set(board::CROP_PIXEL_CLOCKS - 1)
    });
    dcmi.ier().write(|w| {
        w.frame_ie().set_bit();
        w.ovr_ie().set_bit();
        w.err_ie().set_bit();
        w.vsync_ie().set_bit()
    });

    let st = dma().st(usize::from(board::DCMI_DMA_STREAM));
    stop_stream();
    // SAFETY: the buffers are handed to the DMA here, once; the CPU reads a buffer only between
    // its delivery and `release`, while the DMA writes the other one (see the module docs).
    let (m0, m1) = unsafe {
        let frames = &raw mut FRAMES;
        (
            (*frames).0.as_mut_ptr() as u32,
            (*frames).0.as_mut_ptr().add(1) as u32,
        )
    };
    // SAFETY: the peripheral address is the DCMI data register, a valid DMA source.
    st.par()
        .write(|w| unsafe { w.pa().bits(dcmi.dr().as_ptr() as u32) });
    // SAFETY: frame buffer 0, a static of one frame that only the DMA writes (see above).
    st.m0ar().write(|w| unsafe { w.m0a().bits(m0) });
    // SAFETY: frame buffer 1, as buffer 0.
    st.m1ar().write(|w| unsafe { w.m1a().bits(m1) });
    // Direct mode (no FIFO), as the original: one word per DCMI request.
    st.fcr().write(|w| w.dmdis().enabled());
    st.cr().write(|w| {
        w.chsel().set(board::DCMI_DMA_CHANNEL);
        w.dir().peripheral_to_memory();
        w.psize().bits32();
        w.msize().bits32();
        w.pinc().fixed();
        w.minc().incremented();
        w.circ().enabled();
        w.dbm().enabled();
        w.pl().very_high();
        w.teie().enabled();
        w.dmeie().enabled()
    });
}

/// Disables stream 1 (waiting, bounded, for it to stop) and clears its flags.
fn stop_stream() {
    let st = dma().st(usize::from(board::DCMI_DMA_STREAM));
    st.cr().modify(|_, w| w.en().disabled());
    for _ in 0..10_000 {
        if st.cr().read().en().is_disabled() {
            break;
        }
    }
    clear_stream_flags();
}

fn clear_stream_flags() {
    dma().lifcr().write(|w| {
        w.ctcif1().set_bit();
        w.chtif1().set_bit();
        w.cteif1().set_bit();
        w.cdmeif1().set_bit();
        w.cfeif1().set_bit()
    });
}

/// (Re)starts capture: a full frame's count into the buffer the frame task does not hold,
/// stream on, DCMI flags cleared, DCMI on, CAPTURE set (capture begins at the next frame).
fn start_capture() {
    let st = dma().st(usize::from(board::DCMI_DMA_STREAM));
    let into_m1 = BUSY[0].load(Ordering::Acquire);
    st.ndtr().write(|w| w.ndt().set(FRAME_WORDS));
    st.cr().modify(|_, w| {
        if into_m1 {
            w.ct().memory1()
        } else {
            w.ct().memory0()
        }
    });
    st.cr().modify(|_, w| w.en().enabled());
    let dcmi = dcmi();
    dcmi.icr().write(|w| {
        w.frame_isc().set_bit();
        w.ovr_isc().set_bit();
        w.err_isc().set_bit();
        w.vsync_isc().set_bit();
        w.line_isc().set_bit()
    });
    dcmi.cr().modify(|_, w| w.enable().set_bit());
    dcmi.cr().modify(|_, w| w.capture().set_bit());
}

/// Starts capture for the first time, at `now`.
pub fn start(monitor: &mut CaptureMonitor, now: Instant) {
    start_capture();
    monitor.on_capture_started(now);
}

/// Stops and restarts capture (after a torn frame, an error, or a stopped camera).
pub fn rearm(monitor: &mut CaptureMonitor) {
    let dcmi = dcmi();
    dcmi.cr().modify(|_, w| w.capture().clear_bit());
    dcmi.cr().modify(|_, w| w.enable().clear_bit());
    stop_stream();
    start_capture();
    monitor.on_rearm();
}

/// DCMI interrupt at `now`: returns a whole frame to hand to the frame task, if one just
/// ended.
pub fn on_dcmi_interrupt(monitor: &mut CaptureMonitor, now: Instant) -> Option<Delivered> {
    let dcmi = dcmi();
    let mis = dcmi.mis().read();
    dcmi.icr().write(|w| {
        w.frame_isc().bit(mis.frame_mis().bit_is_set());
        w.ovr_isc().bit(mis.ovr_mis().bit_is_set());
        w.err_isc().bit(mis.err_mis().bit_is_set());
        w.vsync_isc().bit(mis.vsync_mis().bit_is_set())
    });
    if mis.vsync_mis().bit_is_set() {
        monitor.on_vsync(now);
    }
    let mut lost = false;
    if mis.ovr_mis().bit_is_set() {
        monitor.on_dcmi_overrun();
        lost = true;
    }
    if mis.err_mis().bit_is_set() {
        monitor.on_dcmi_sync_error();
        lost = true;
    }
    if mis.frame_mis().bit_is_set() {
        FRAME_ENDS.fetch_add(1, Ordering::AcqRel);
        let verdict = monitor.on_frame_end(dma_at_frame_end());
        dma().lifcr().write(|w| w.ctcif1().set_bit());
        if verdict == FrameEnd::Deliver && !lost {
            return deliver(now);
        }
        lost = true;
    }
    if lost {
        rearm(monitor);
    }
    None
}

/// The DMA's state at a frame end, once the last words of the frame have reached memory.
fn dma_at_frame_end() -> DmaAtFrameEnd {
    let st = dma().st(usize::from(board::DCMI_DMA_STREAM));
    let mut snapshot = DmaAtFrameEnd {
        transfer_complete: false,
        remaining_words: 0,
    };
    for _ in 0..DRAIN_POLLS {
        snapshot = DmaAtFrameEnd {
            transfer_complete: dma().lisr().read().tcif1().bit_is_set(),
            remaining_words: st.ndtr().read().ndt().bits(),
        };
        // Still draining: the buffer is all but full and has not switched yet.
        let draining = !snapshot.transfer_complete && snapshot.remaining_words <= 8;
        if !draining {
            break;
        }
    }
    snapshot
}

/// Hands the buffer the DMA just left to the frame task, its read-out ended at `capture`.
fn deliver(capture: Instant) -> Option<Delivered> {
    let writing = usize::from(
        dma()
            .st(usize::from(board::DCMI_DMA_STREAM))
            .cr()
            .read()
            .ct()
            .bit_is_set(),
    );
    let index = 1 - writing;
    BUSY.get(index)?.store(true, Ordering::Release);
    Some(Delivered {
        index,
        capture,
        seq: FRAME_ENDS.load(Ordering::Acquire),
    })
}

/// DMA2 stream 1 interrupt: transfer errors stop the stream (re-arm now); direct-mode errors
/// lose data (the frame in flight is torn at its end).
pub fn on_dma_interrupt(monitor: &mut CaptureMonitor) {
    let isr = dma().lisr().read();
    let transfer_error = isr.teif1().bit_is_set();
    if transfer_error || isr.dmeif1().bit_is_set() || isr.feif1().bit_is_set() {
        dma().lifcr().write(|w| {
            w.cteif1().set_bit();
            w.cdmeif1().set_bit();
            w.cfeif1().set_bit()
        });
        monitor.on_dma_error();
    }
    if transfer_error {
        rearm(monitor);
    }
}

/// The frame in a delivered buffer.
pub fn frame(d: &Delivered) -> Option<&'static [u8; STEREO_FRAME_BYTES]> {
    if !BUSY.get(d.index)?.load(Ordering::Acquire) {
        return None;
    }
    // SAFETY: a shared reference is only handed out for a buffer marked busy, which the DMA
    // does not write until the next frame end (checked by `intact` after use).
    unsafe { (*core::ptr::addr_of!(FRAMES)).0.get(d.index) }
}

/// True while the DMA has not begun to refill a delivered buffer: no frame has ended since.
pub fn intact(d: &Delivered) -> bool {
    FRAME_ENDS.load(Ordering::Acquire) == d.seq
}

/// The frame task is done with a delivered buffer.
pub fn release(d: &Delivered) {
    if let Some(b) = BUSY.get(d.index) {
        b.store(false, Ordering::Release);
    }
}
