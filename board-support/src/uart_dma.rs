//! USART1 receive by DMA with the IDLE-line interrupt (hardware flavours; QEMU has no DMA
//! model, so the `qemu` flavour takes bytes from the RXNE interrupt instead).
//!
//! DMA2 stream 2, channel 4 copies every received byte into a circular SRAM buffer without
//! CPU work. Three events hand the new bytes on: the line going idle after a burst (the end of
//! a message, usually), and the DMA's half- and full-transfer interrupts (so a long burst never
//! laps the buffer). Each handler copies the bytes between the last read position and the
//! DMA's write position into the decoding task's queue. Both interrupts run at the same
//! priority, so they never preempt each other and share the read position safely.

use core::sync::atomic::{AtomicUsize, Ordering};
use heapless::spsc::Producer;
use stm32f4xx_hal::pac;

/// Circular receive buffer, bytes (11 ms of a 921,600 Bd line per half).
const BUF: usize = 1024;

static mut RX: [u8; BUF] = [0; BUF];

/// Next buffer index to hand on.
static READ: AtomicUsize = AtomicUsize::new(0);

/// Starts the circular DMA on USART1 RX (after the HAL configured the USART) and enables the
/// IDLE interrupt.
pub fn start() {
    // SAFETY: stream 2 of DMA2 and USART1's CR1/CR3 DMA and IDLE bits are only touched here
    // and in `on_interrupt`; other DMA2 streams belong to other drivers (the camera board's DCMI
    // uses stream 1).
    let dma = unsafe { &*pac::DMA2::ptr() };
    // SAFETY: as above, USART1's DMA and IDLE bits belong to this driver.
    let usart = unsafe { &*pac::USART1::ptr() };
    // SAFETY: one read-modify-write of AHB1ENR at start-up, before interrupts are enabled.
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.ahb1enr().modify(|_, w| w.dma2en().set_bit());
    let st = dma.st(2);
    st.cr().modify(|_, w| w.en().disabled());
    while st.cr().read().en().is_enabled() {}
    dma.lifcr().write(|w| {
        w.ctcif2().set_bit();
        w.chtif2().set_bit();
        w.cteif2().set_bit();
        w.cdmeif2().set_bit();
        w.cfeif2().set_bit()
    });
    let buf = (&raw mut RX) as u32;
    // SAFETY: the peripheral address is USART1's data register, a valid DMA source.
    st.par()
        .write(|w| unsafe { w.pa().bits(usart.dr().as_ptr() as u32) });
    // SAFETY: `RX` is a static buffer of `BUF` bytes that only the DMA writes.
    st.m0ar().write(|w| unsafe { w.m0a().bits(buf) });
    st.ndtr().write(|w| w.ndt().set(BUF as u16));
    st.fcr().write(|w| w.dmdis().disabled());
    st.cr().write(|w| {
        w.chsel().set(4);
        w.dir().peripheral_to_memory();
        w.psize().bits8();
        w.msize().bits8();
        w.pinc().fixed();
        w.minc().incremented();
        w.circ().enabled();
        w.pl().high();
        w.htie().enabled();
        w.tcie().enabled()
    });
    st.cr().modify(|_, w| w.en().enabled());
    usart.cr3().modify(|_, w| w.dmar().set_bit());
    usart
        .cr1()
        .modify(|_, w| w.rxneie().clear_bit().idleie().set_bit());
}

/// USART1 (IDLE) or DMA2 stream 2 (half/full) interrupt: clears the event and moves the new
/// bytes into `queue`. Returns how many bytes did not fit.
pub fn on_interrupt(queue: &mut Producer<'static, u8>) -> u32 {
    // SAFETY: see `start`.
    let dma = unsafe { &*pac::DMA2::ptr() };
    // SAFETY: see `start`.
    let usart = unsafe { &*pac::USART1::ptr() };
    let isr = dma.lisr().read();
    if isr.htif2().bit_is_set() || isr.tcif2().bit_is_set() {
        dma.lifcr()
            .write(|w| w.chtif2().set_bit().ctcif2().set_bit());
    }
    if usart.sr().read().idle().bit_is_set() {
        // IDLE clears by reading SR then DR (the DMA owns the data; this read is discarded).
        let _ = usart.dr().read();
    }
    let write = BUF - usize::from(dma.st(2).ndtr().read().ndt().bits()).min(BUF);
    let write = write % BUF;
    let mut read = READ.load(Ordering::Relaxed);
    let mut lost = 0;
    while read != write {
        // SAFETY: the DMA writes at `write` and beyond; the bytes from `read` up to it are
        // complete (a burst of more than BUF bytes between interrupts cannot happen: the
        // half-transfer interrupt fires every BUF/2 bytes).
        let byte = unsafe { (*core::ptr::addr_of!(RX)).get(read).copied().unwrap_or(0) };
        if queue.enqueue(byte).is_err() {
            lost += 1;
        }
        read = (read + 1) % BUF;
    }
    READ.store(read, Ordering::Relaxed);
    lost
}
