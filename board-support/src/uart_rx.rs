//! UART receive by the RXNE interrupt into a lock-free queue, with back-pressure (MCU only).
//!
//! The receive interrupt moves bytes from the data register into a `heapless::spsc` queue and
//! wakes the decoding task, which runs at a lower priority and drains the queue with
//! [`take`]. When the queue is full the interrupt does not read the data register: it masks its
//! own NVIC line and leaves the byte where it is. The decoding task unmasks it
//! ([`RxFlow::take`], [`RxFlow::resume`]) after it has made room, and the pending RXNE fires again.
//!
//! * In QEMU this is lossless: the USART model delivers the next byte only after the guest has
//!   read the previous one, so a host that streams faster than the firmware decodes (a whole
//!   camera frame, 25 kB, in one burst) is simply slowed down.
//! * On hardware the line does not wait: while paused, a second byte overruns the first, the
//!   next read reports the overrun and the byte is counted as lost, the same as if it had been
//!   dropped at a full queue. The protocol's CRC then rejects the damaged frame and counts it.
//!
//! Every byte that is lost (overrun, framing or noise error) is added to a caller's counter.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use heapless::spsc::{Consumer, Producer};
use stm32f4xx_hal::prelude::_embedded_hal_serial_nb_Read as _;
use stm32f4xx_hal::{nb, pac, serial};

/// At most this many bytes are moved per interrupt (a few can be pending in the USART; the
/// bound keeps the interrupt short however fast bytes come).
const MAX_BYTES_PER_INTERRUPT: usize = 64;

/// Back-pressure state of one receive interrupt.
pub struct RxFlow {
    irq: pac::Interrupt,
    paused: AtomicBool,
}

impl RxFlow {
    /// The flow state of the receive interrupt `irq` (e.g. `pac::Interrupt::USART2`).
    pub const fn new(irq: pac::Interrupt) -> Self {
        Self {
            irq,
            paused: AtomicBool::new(false),
        }
    }

    /// Masks the interrupt until [`RxFlow::resume`] (called from the interrupt itself).
    fn pause(&self) {
        cortex_m::peripheral::NVIC::mask(self.irq);
        self.paused.store(true, Ordering::Release);
    }

    /// Unmasks the interrupt if it paused itself (called by the decoding task after it took
    /// bytes out of the queue).
    pub fn resume(&self) {
        if self.paused.swap(false, Ordering::AcqRel) {
            // SAFETY: the interrupt was enabled before it masked itself in `pause`; unmasking
            // it again breaks no critical section (RTIC's locks use BASEPRI, not NVIC masks).
            unsafe { cortex_m::peripheral::NVIC::unmask(self.irq) };
        }
    }

    /// The decoding task's side: [`take`], then [`RxFlow::resume`] if bytes were taken.
    pub fn take(&self, queue: &mut Consumer<'static, u8>, buf: &mut [u8]) -> usize {
        let n = take(queue, buf);
        if n > 0 {
            self.resume();
        }
        n
    }
}

/// A UART's receive side as its interrupt sees it: the RXNE path of this module (the HAL's
/// `Rx`), or a circular DMA ([`crate::uart_dma::DmaRx`], which never pauses).
pub trait Receiver {
    /// The receive interrupt's body: moves the bytes received since the last call into
    /// `queue` and counts lost ones in `lost` (the caller then wakes the decoding task).
    fn receive(&mut self, queue: &mut Producer<'static, u8>, flow: &RxFlow, lost: &AtomicU32);
}

/// A receiver the board may not have (an RC receiver port left unused): receives nothing.
impl<R: Receiver> Receiver for Option<R> {
    fn receive(&mut self, queue: &mut Producer<'static, u8>, flow: &RxFlow, lost: &AtomicU32) {
        if let Some(rx) = self {
            rx.receive(queue, flow, lost);
        }
    }
}

impl<U: serial::Instance> Receiver for serial::Rx<U> {
    /// [`drain`].
    fn receive(&mut self, queue: &mut Producer<'static, u8>, flow: &RxFlow, lost: &AtomicU32) {
        drain(self, queue, flow, lost);
    }
}

/// The receive interrupt's body: moves the pending bytes of `rx` into `queue`, pausing the
/// interrupt when the queue is full, and counts lost bytes in `lost` (the caller then wakes the
/// decoding task).
pub fn drain<U: serial::Instance>(
    rx: &mut serial::Rx<U>,
    queue: &mut Producer<'static, u8>,
    flow: &RxFlow,
    lost: &AtomicU32,
) {
    for _ in 0..MAX_BYTES_PER_INTERRUPT {
        if !queue.ready() {
            flow.pause();
            break;
        }
        match rx.read() {
            Ok(byte) => {
                // Cannot fail: `ready` said there is room and only this interrupt enqueues.
                if queue.enqueue(byte).is_err() {
                    lost.fetch_add(1, Ordering::Relaxed);
                }
            }
            // Overrun, framing or noise error: the HAL read the data register to clear it.
            Err(nb::Error::Other(_)) => {
                lost.fetch_add(1, Ordering::Relaxed);
            }
            Err(nb::Error::WouldBlock) => break,
        }
    }
}

/// Empties a receiver that was not served yet (its interrupt not running: during `init`),
/// returns how many bytes and errors it held. What a peer sent while the firmware was booting
/// is not data lost in operation: a second byte into an unread receiver sets the overrun flag,
/// which the first interrupt would otherwise count in the caller's `lost`. The decoders join
/// the stream at the next frame delimiter either way.
pub fn discard_pending<U: serial::Instance>(rx: &mut serial::Rx<U>) -> u32 {
    let mut discarded = 0;
    for _ in 0..MAX_BYTES_PER_INTERRUPT {
        match rx.read() {
            Ok(_) | Err(nb::Error::Other(_)) => discarded += 1,
            Err(nb::Error::WouldBlock) => break,
        }
    }
    discarded
}

/// Takes up to `buf.len()` bytes out of `queue` into `buf`; returns how many. (A decoding
/// task whose interrupt can pause itself uses [`RxFlow::take`] instead.)
pub fn take(queue: &mut Consumer<'static, u8>, buf: &mut [u8]) -> usize {
    let mut n = 0;
    for slot in buf.iter_mut() {
        match queue.dequeue() {
            Some(b) => {
                *slot = b;
                n += 1;
            }
            None => break,
        }
    }
    n
}
