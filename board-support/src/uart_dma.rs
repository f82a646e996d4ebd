//! UART receive by circular DMA with the IDLE-line interrupt, for a line too fast for a
//! receive interrupt per byte (MCU only; QEMU has no DMA model).
//!
//! A USART holds one received byte: the next one overruns it unless the RXNE interrupt has
//! read it within one byte time, 10.85 µs at 921,600 Bd. Logging holds every interrupt off for
//! longer: defmt-rtt writes a whole log frame inside a critical section, 20 µs for the
//! autopilot's status line and 27 µs for the camera board's (measured on the virtual boards).
//! So the `hil` flavour's host links, at `link::HOST_BAUD`, take their bytes by DMA, which needs
//! no CPU per byte.
//!
//! A DMA stream copies every received byte into a circular buffer. Three events hand the new
//! bytes on: the line going idle after a burst (IDLE, the end of a message, usually) and the
//! stream's half- and full-transfer interrupts (so a long burst never laps the buffer). The
//! stream's interrupt only acknowledges its flags and pends the UART's ([`RxStream::acknowledge`]),
//! so all the work is in one handler, [`DmaRx::drain`]: it copies the bytes between the last
//! read position and the DMA's write position into the decoding task's queue. A full queue
//! loses the bytes that do not fit, counted: the line does not wait, and a DMA cannot be paused
//! by a queue.

use core::marker::PhantomData;
use core::sync::atomic::{AtomicU32, Ordering};
use heapless::spsc::Producer;
use stm32f4xx_hal::pac;

/// A DMA controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Controller {
    /// DMA1 (APB1 peripherals' requests, RM0090 table 42).
    Dma1,
    /// DMA2 (APB2 peripherals' requests, RM0090 table 43).
    Dma2,
}

/// The DMA stream and channel that serve one UART's receive requests (RM0090 tables 42 and 43).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RxStream {
    /// The controller.
    pub controller: Controller,
    /// The stream, 0..=7.
    pub stream: u8,
    /// The channel (request) selected on the stream, 0..=7.
    pub channel: u8,
}

impl RxStream {
    fn registers(self) -> &'static pac::dma2::RegisterBlock {
        let block = match self.controller {
            Controller::Dma1 => pac::DMA1::ptr(),
            Controller::Dma2 => pac::DMA2::ptr(),
        };
        // SAFETY: the DMA controllers' register blocks live for the program; this driver
        // touches only its own stream's registers and flags (see `DmaRx::start`).
        unsafe { &*block }
    }

    /// The stream's flags in LISR/LIFCR (streams 0-3) or HISR/HIFCR (4-7): the shift of its
    /// six-bit group (RM0090 10.5.1-10.5.4).
    fn flag_shift(self) -> u32 {
        [0, 6, 16, 22][usize::from(self.stream % 4)]
    }

    /// Clears the stream's flags in `mask` (bits of the six-bit group).
    fn clear(self, mask: u32) {
        let dma = self.registers();
        let bits = mask << self.flag_shift();
        if self.stream < 4 {
            // SAFETY: ones in the interrupt flag clear register clear only those flags of
            // this stream; zeros leave every other flag.
            dma.lifcr().write(|w| unsafe { w.bits(bits) });
        } else {
            // SAFETY: as above, for streams 4 to 7.
            dma.hifcr().write(|w| unsafe { w.bits(bits) });
        }
    }

    /// The stream's interrupt: clears its half- and full-transfer flags. The caller then pends
    /// the UART's interrupt, whose handler takes the bytes ([`DmaRx::drain`]).
    pub fn acknowledge(self) {
        self.clear(HTIF | TCIF);
    }
}

/// Half transfer, transfer complete (within a stream's six-bit group).
const HTIF: u32 = 1 << 4;
const TCIF: u32 = 1 << 5;
/// Every flag of a stream: FIFO, direct mode and transfer errors, half, complete.
const ALL_FLAGS: u32 = 0b11_1101;

/// The receiver of USART `U` on a circular DMA stream.
pub struct DmaRx<U> {
    usart: &'static pac::usart1::RegisterBlock,
    /// The USART whose registers `usart` are.
    _usart: PhantomData<U>,
    stream: RxStream,
    /// The circular buffer: written by the DMA only, read here only behind its write position.
    buf: *const u8,
    len: usize,
    /// Next buffer index to hand on.
    read: usize,
}

// SAFETY: the buffer is only read, behind the DMA's write position, by the one handler that
// owns this value (an RTIC resource moved into that handler); the registers are MMIO.
unsafe impl<U> Send for DmaRx<U> {}

impl<U: stm32f4xx_hal::Ptr<RB = pac::usart1::RegisterBlock>> DmaRx<U> {
    /// Starts circular DMA on USART `U`'s receiver into `buf` (at most 65,535 bytes; the stream's
    /// half-transfer interrupt fires every `buf.len() / 2` bytes) and enables the IDLE interrupt
    /// in place of RXNE. Call after the UART is configured (baud, receiver on) and before its
    /// interrupt is unmasked.
    ///
    /// # Safety
    /// No other code reads `U`'s receive side from here on; `stream` serves that USART's
    /// receive requests and no other driver uses it; `buf` lies in memory the DMA controller
    /// reaches (SRAM, not CCM).
    pub unsafe fn start(stream: RxStream, buf: &'static mut [u8]) -> Self {
        // SAFETY: a USART's register block lives for the program.
        let usart = unsafe { &*U::ptr() };
        let len = buf.len().min(usize::from(u16::MAX));
        // SAFETY: one read-modify-write of AHB1ENR (the DMA clock), before the stream runs.
        let rcc = unsafe { &*pac::RCC::ptr() };
        rcc.ahb1enr().modify(|_, w| match stream.controller {
            Controller::Dma1 => w.dma1en().set_bit(),
            Controller::Dma2 => w.dma2en().set_bit(),
        });
        let st = stream.registers().st(usize::from(stream.stream));
        st.cr().modify(|_, w| w.en().disabled());
        while st.cr().read().en().is_enabled() {}
        stream.clear(ALL_FLAGS);
        // SAFETY: the peripheral address is the USART's data register, a valid DMA source.
        st.par()
            .write(|w| unsafe { w.pa().bits(usart.dr().as_ptr() as u32) });
        // SAFETY: `buf` is the caller's `len` bytes, from here on written only by the DMA.
        st.m0ar()
            .write(|w| unsafe { w.m0a().bits(buf.as_mut_ptr() as u32) });
        st.ndtr().write(|w| w.ndt().set(len as u16));
        // Direct mode (DMDIS = 0): each byte goes to memory as it comes. In FIFO mode the
        // stream holds bytes until its threshold (a quarter of the FIFO, four bytes), so a
        // message's last bytes would wait for the next message (RM0090 10.3.11, 10.3.12).
        st.fcr().write(|w| w.dmdis().enabled());
        st.cr().write(|w| {
            w.chsel().set(stream.channel);
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
        Self {
            usart,
            _usart: PhantomData,
            stream,
            buf: buf.as_ptr(),
            len,
            read: 0,
        }
    }

    /// The UART's interrupt (IDLE, or pended by the stream's [`RxStream::acknowledge`]):
    /// clears the events and moves the bytes the DMA wrote since the last call into `queue`;
    /// bytes that do not fit are added to `lost`.
    pub fn drain(&mut self, queue: &mut Producer<'static, u8>, lost: &AtomicU32) {
        self.stream.acknowledge();
        if self.usart.sr().read().idle().bit_is_set() {
            // IDLE clears by a read of SR then DR. The DMA has taken every byte (it serves
            // RXNE within a few cycles), so this read returns one already in the buffer.
            let _ = self.usart.dr().read();
        }
        let st = self.stream.registers().st(usize::from(self.stream.stream));
        let left = usize::from(st.ndtr().read().ndt().bits()).min(self.len);
        let write = (self.len - left) % self.len.max(1);
        let mut dropped = 0;
        while self.read != write {
            // SAFETY: `read` < `len`, inside the buffer; the DMA writes at `write` and beyond,
            // so the bytes from `read` up to it are complete (the half-transfer interrupt
            // fires every `len / 2` bytes, long before a burst could lap the buffer).
            let byte = unsafe { core::ptr::read_volatile(self.buf.add(self.read)) };
            if queue.enqueue(byte).is_err() {
                dropped += 1;
            }
            self.read = (self.read + 1) % self.len;
        }
        if dropped > 0 {
            lost.fetch_add(dropped, Ordering::Relaxed);
        }
    }
}

impl<U: stm32f4xx_hal::Ptr<RB = pac::usart1::RegisterBlock>> crate::uart_rx::Receiver for DmaRx<U> {
    /// [`DmaRx::drain`]: a DMA never pauses, so `flow` is not used.
    fn receive(
        &mut self,
        queue: &mut Producer<'static, u8>,
        _flow: &crate::uart_rx::RxFlow,
        lost: &AtomicU32,
    ) {
        self.drain(queue, lost);
    }
}
