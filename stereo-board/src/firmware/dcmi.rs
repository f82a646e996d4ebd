//! A small DCMI driver on the PAC (stm32f4xx-hal has none): 8-bit parallel camera with
//! hardware synchronisation, DMA2 stream 1 channel 1 in double-buffer mode, one interrupt per
//! complete frame.
//!
//! The stereo camera delivers left and right pixels interleaved (`[L0 R0 L1 R1 ...]`, 256 bytes
//! per line, 96 lines) with pixel clock, HSYNC and VSYNC. The DCMI packs four bytes into each
//! 32-bit data-register read; the DMA moves `STEREO_FRAME_BYTES / 4` words per frame into one
//! of two SRAM buffers and switches to the other on its own (double-buffer mode, `CT` tells
//! which one it is writing). The transfer-complete interrupt therefore marks a frame as
//! complete in the buffer the DMA just left; the frame task reads it while the next frame
//! streams into the other buffer, and [`release`]s it when done.
//!
//! Pins (alternate function 13): HSYNC PA4, PIXCLK PA6, VSYNC PB7, D0..D7 = PC6, PC7, PC8,
//! PC9, PC11, PB6, PE5, PE6. Camera master clock: MCO1 on PA8 (the 12 MHz HSE).

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use protocol::STEREO_FRAME_BYTES;
use stm32f4xx_hal::gpio::{Alternate, PA4, PA6, PA8, PB6, PB7, PC11, PC6, PC7, PC8, PC9, PE5, PE6};
use stm32f4xx_hal::pac;

/// 32-bit words per frame (the DMA's item count; must stay below 65,536).
const FRAME_WORDS: u16 = (STEREO_FRAME_BYTES / 4) as u16;
const _: () = assert!(STEREO_FRAME_BYTES.is_multiple_of(4) && STEREO_FRAME_BYTES / 4 < 65_536);

/// Two frame buffers in SRAM (DMA-reachable; CCM is not), word-aligned for the DMA.
#[repr(C, align(4))]
struct Frames([[u8; STEREO_FRAME_BYTES]; 2]);

static mut FRAMES: Frames = Frames([[0; STEREO_FRAME_BYTES]; 2]);

/// Buffer `i` is being read by the frame task.
static BUSY: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];

/// Frames lost since the frame task last looked: overruns and frames arriving while busy.
pub static DROPPED: AtomicU32 = AtomicU32::new(0);

/// DMA transfer errors since boot.
pub static DMA_ERRORS: AtomicU32 = AtomicU32::new(0);

/// The DCMI pins, in their alternate function (owned so nothing else can reconfigure them).
#[allow(missing_docs, dead_code)]
pub struct Pins {
    pub hsync: PA4<Alternate<13>>,
    pub pixclk: PA6<Alternate<13>>,
    pub vsync: PB7<Alternate<13>>,
    pub d0: PC6<Alternate<13>>,
    pub d1: PC7<Alternate<13>>,
    pub d2: PC8<Alternate<13>>,
    pub d3: PC9<Alternate<13>>,
    pub d4: PC11<Alternate<13>>,
    pub d5: PB6<Alternate<13>>,
    pub d6: PE5<Alternate<13>>,
    pub d7: PE6<Alternate<13>>,
    pub xclk: PA8<Alternate<0>>,
}

/// Signal polarities of the camera (from its datasheet).
#[derive(Debug, Clone, Copy)]
pub struct Polarity {
    /// Sample data on the rising pixel-clock edge.
    pub pixclk_rising: bool,
    /// HSYNC is high during blanking (the DCMI's "active high").
    pub hsync_high: bool,
    /// VSYNC is high during blanking.
    pub vsync_high: bool,
}

/// Configures MCO1 (camera clock), DCMI and DMA2 stream 1 and starts continuous capture.
/// The pins are taken to prove they are in the right mode.
pub fn start(dcmi: pac::DCMI, dma2: pac::DMA2, _pins: Pins, polarity: Polarity) {
    // SAFETY: RCC is only touched here after `freeze`, for enable bits no HAL driver owns.
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.ahb1enr().modify(|_, w| w.dma2en().set_bit());
    rcc.ahb2enr().modify(|_, w| w.dcmien().set_bit());
    // Camera master clock: MCO1 = HSE, undivided.
    rcc.cfgr().modify(|_, w| w.mco1().hse().mco1pre().div1());

    dcmi.cr().write(|w| {
        w.cm().continuous();
        w.ess().hardware();
        w.fcrc().all();
        w.edm().bit_width8();
        if polarity.pixclk_rising {
            w.pckpol().rising_edge();
        } else {
            w.pckpol().falling_edge();
        }
        if polarity.hsync_high {
            w.hspol().active_high();
        } else {
            w.hspol().active_low();
        }
        if polarity.vsync_high {
            w.vspol().active_high()
        } else {
            w.vspol().active_low()
        }
    });

    let st = dma2.st(1);
    st.cr().modify(|_, w| w.en().disabled());
    while st.cr().read().en().is_enabled() {}
    dma2.lifcr().write(|w| {
        w.ctcif1().set_bit();
        w.chtif1().set_bit();
        w.cteif1().set_bit();
        w.cdmeif1().set_bit();
        w.cfeif1().set_bit()
    });
    // SAFETY: the buffers are only handed to the DMA here, once; the CPU reads a buffer only
    // between a transfer-complete interrupt and `release` (see the module docs).
    let (m0, m1) = unsafe {
        let frames = &raw mut FRAMES;
        (
            (*frames).0.as_mut_ptr() as u32,
            (*frames).0.as_mut_ptr().add(1) as u32,
        )
    };
    let dr = dcmi.dr().as_ptr() as u32;
    // SAFETY: the DCMI data register is a valid DMA source.
    st.par().write(|w| unsafe { w.pa().bits(dr) });
    // SAFETY: `m0` and `m1` are the two static frame buffers (above), each FRAME_WORDS long.
    st.m0ar().write(|w| unsafe { w.m0a().bits(m0) });
    // SAFETY: as for `m0ar`.
    st.m1ar().write(|w| unsafe { w.m1a().bits(m1) });
    st.ndtr().write(|w| w.ndt().set(FRAME_WORDS));
    // FIFO on (DCMI needs it), threshold full.
    st.fcr().write(|w| w.dmdis().enabled().fth().full());
    st.cr().write(|w| {
        w.chsel().set(1);
        w.dir().peripheral_to_memory();
        w.psize().bits32();
        w.msize().bits32();
        w.pinc().fixed();
        w.minc().incremented();
        w.circ().enabled();
        w.dbm().enabled();
        w.ct().memory0();
        w.pl().very_high();
        w.tcie().enabled();
        w.teie().enabled()
    });
    st.cr().modify(|_, w| w.en().enabled());

    dcmi.cr().modify(|_, w| w.enable().enabled());
    dcmi.cr().modify(|_, w| w.capture().set_bit());
}

/// Handles the DMA2 stream 1 interrupt: returns the index of the buffer holding a complete
/// frame and its time stamp (`now_us`: end of read-out), or `None` for an error interrupt.
pub fn on_transfer_complete(now_us: u64) -> Option<(usize, u64)> {
    // SAFETY: only this interrupt handler reads and clears stream 1's flags.
    let dma = unsafe { &*pac::DMA2::ptr() };
    let isr = dma.lisr().read();
    if isr.teif1().bit_is_set() {
        dma.lifcr().write(|w| w.cteif1().set_bit());
        DMA_ERRORS.fetch_add(1, Ordering::Relaxed);
    }
    if isr.tcif1().bit_is_clear() {
        return None;
    }
    dma.lifcr().write(|w| w.ctcif1().set_bit());
    // CT names the buffer the DMA writes now; the other one was just filled.
    let writing = usize::from(dma.st(1).cr().read().ct().bit_is_set());
    let done = 1 - writing;
    if BUSY.get(writing).is_some_and(|b| b.load(Ordering::Acquire)) {
        // The frame task was still reading the buffer the DMA now overwrites.
        DROPPED.fetch_add(1, Ordering::Relaxed);
    }
    BUSY.get(done)?.store(true, Ordering::Release);
    Some((done, now_us))
}

/// The complete frame in buffer `index` (after [`on_transfer_complete`] returned it).
pub fn frame(index: usize) -> Option<&'static [u8; STEREO_FRAME_BYTES]> {
    if !BUSY.get(index)?.load(Ordering::Acquire) {
        return None;
    }
    // SAFETY: the DMA writes the other buffer until this one is released (double-buffer
    // mode); a shared reference is only handed out for a buffer marked busy.
    unsafe { (*core::ptr::addr_of!(FRAMES)).0.get(index) }
}

/// The frame task is done with buffer `index`.
pub fn release(index: usize) {
    if let Some(b) = BUSY.get(index) {
        b.store(false, Ordering::Release);
    }
}
