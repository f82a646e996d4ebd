//! One UART link of a firmware as one bundle (MCU only): its receive queue, its transmit queue
//! and the wake-up of its decoding task, split at start-up into the ends the RTIC app hands to
//! its tasks.
//!
//! * [`TxWriter`]: the tasks' side of the transmit queue ([`crate::uart_tx`]), a shared
//!   resource when several tasks send.
//! * [`LinkInterrupt`]: the UART's interrupt handler's, [`LinkInterrupt::serve`]: queued bytes
//!   out, received bytes into the queue (by RXNE with back-pressure, [`crate::uart_rx`], or by
//!   DMA, [`crate::uart_dma`]), the decoding task woken.
//! * [`LinkReader`]: the decoding task's: [`LinkReader::woken`], then [`LinkReader::take`]
//!   until the queue is empty.
//!
//! [`ReceiveLink`] is the same for a receive-only UART (an RC receiver): a [`RxInterrupt`] and a
//! [`LinkReader`].

use crate::uart_rx::{Receiver, RxFlow};
use crate::uart_tx::{TxPump, TxQueue, TxWriter};
use core::mem::MaybeUninit;
use core::sync::atomic::AtomicU32;
use heapless::spsc::{Consumer, Producer, Queue};
use rtic_sync::channel::{self, Channel};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::serial::{self, Tx};

/// The storage of a receive-only link: `RX` bytes of receive queue, the decoding task's wake-up
/// and the interrupt's back-pressure state (a `static`, e.g. an RTIC `init` local). All zero
/// until [`ReceiveLink::split`], so the static takes no flash for an initial image.
pub struct ReceiveLink<const RX: usize> {
    received: Queue<u8, RX>,
    wake: Channel<(), 1>,
    /// Written by `split`, which runs once (it takes the `'static` borrow).
    flow: MaybeUninit<RxFlow>,
}

impl<const RX: usize> Default for ReceiveLink<RX> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const RX: usize> ReceiveLink<RX> {
    /// Empty storage.
    pub const fn new() -> Self {
        Self {
            received: Queue::new(),
            wake: Channel::new(),
            flow: MaybeUninit::uninit(),
        }
    }

    /// The interrupt's and the decoding task's ends of the link whose UART raises `irq` (e.g.
    /// `pac::Interrupt::UART5`), `rx` receiving; lost bytes (overrun, framing, noise; a DMA's
    /// full queue) are counted in `lost`.
    pub fn split<R: Receiver>(
        &'static mut self,
        irq: pac::Interrupt,
        rx: R,
        lost: &'static AtomicU32,
    ) -> (RxInterrupt<R>, LinkReader) {
        let Self {
            received,
            wake,
            flow,
        } = self;
        let flow: &'static RxFlow = flow.write(RxFlow::new(irq));
        let (queue_in, queue_out) = received.split();
        let (wake_tx, wake_rx) = wake.split();
        (
            RxInterrupt {
                rx,
                queue: queue_in,
                wake: wake_tx,
                flow,
                lost,
            },
            LinkReader {
                queue: queue_out,
                wake: wake_rx,
                flow,
            },
        )
    }
}

/// The storage of a link: `RX` bytes of receive queue, `TX` of transmit queue, the decoding
/// task's wake-up and the interrupt's back-pressure state (a `static`, e.g. an RTIC `init`
/// local; all zero until [`UartLink::split`]).
pub struct UartLink<const RX: usize, const TX: usize> {
    receive: ReceiveLink<RX>,
    transmit: TxQueue<TX>,
}

impl<const RX: usize, const TX: usize> Default for UartLink<RX, TX> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const RX: usize, const TX: usize> UartLink<RX, TX> {
    /// Empty storage.
    pub const fn new() -> Self {
        Self {
            receive: ReceiveLink::new(),
            transmit: TxQueue::new(),
        }
    }

    /// The tasks', the interrupt's and the decoding task's ends of the link whose UART raises
    /// `irq` (e.g. `pac::Interrupt::USART2`): `tx` is the HAL's transmit half of the configured
    /// UART, `rx` its receiver; lost bytes are counted in `lost`.
    pub fn split<U: serial::Instance, R: Receiver>(
        &'static mut self,
        irq: pac::Interrupt,
        tx: Tx<U>,
        rx: R,
        lost: &'static AtomicU32,
    ) -> (TxWriter, LinkInterrupt<U, R>, LinkReader) {
        let Self { receive, transmit } = self;
        let (writer, pump) = transmit.split(tx, irq);
        let (rx, reader) = receive.split(irq, rx, lost);
        (writer, LinkInterrupt { pump, rx }, reader)
    }
}

/// A receive interrupt's end of a link.
pub struct RxInterrupt<R> {
    rx: R,
    queue: Producer<'static, u8>,
    wake: channel::Sender<'static, (), 1>,
    flow: &'static RxFlow,
    lost: &'static AtomicU32,
}

impl<R: Receiver> RxInterrupt<R> {
    /// The interrupt's body: the received bytes into the queue (pausing the interrupt at a
    /// full queue), the decoding task woken.
    pub fn serve(&mut self) {
        self.rx.receive(&mut self.queue, self.flow, self.lost);
        let _ = self.wake.try_send(());
    }
}

/// A UART interrupt's end of a link: both directions.
pub struct LinkInterrupt<U: serial::Instance, R> {
    pump: TxPump<U>,
    rx: RxInterrupt<R>,
}

impl<U: serial::Instance, R: Receiver> LinkInterrupt<U, R> {
    /// The interrupt's body, whatever raised it: queued bytes out ([`TxPump::pump`]), then
    /// [`RxInterrupt::serve`].
    pub fn serve(&mut self) {
        self.pump.pump();
        self.rx.serve();
    }
}

/// The decoding task's end of a link.
pub struct LinkReader {
    queue: Consumer<'static, u8>,
    wake: channel::Receiver<'static, (), 1>,
    flow: &'static RxFlow,
}

impl LinkReader {
    /// Waits until the interrupt has received bytes since the task last took them all. `false`
    /// when the interrupt's end is gone (never in a firmware, where it is an RTIC resource).
    pub async fn woken(&mut self) -> bool {
        self.wake.recv().await.is_ok()
    }

    /// Takes up to `buf.len()` received bytes into `buf` and resumes a paused interrupt
    /// ([`RxFlow::take`]); returns how many (0: the queue is empty).
    pub fn take(&mut self, buf: &mut [u8]) -> usize {
        self.flow.take(&mut self.queue, buf)
    }
}
