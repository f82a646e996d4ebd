//! UART transmit that never blocks and never panics: whole frames go into a byte queue and the
//! UART's own interrupt moves them into the data register, one byte per TXE (MCU only).
//!
//! * [`TxQueue::split`] hands out the two ends. The [`TxWriter`] is what tasks write to (an
//!   RTIC shared resource when several tasks send on one UART). The [`TxPump`] belongs to the
//!   UART's interrupt handler, which also serves its receive side: it calls [`TxPump::pump`]
//!   on every entry.
//! * [`TxWriter::send`] copies a frame into the queue if all of it fits, otherwise drops all
//!   of it and counts it (a partial frame would only be rejected by the peer's CRC). It then
//!   pends the UART's interrupt; it never waits for the line, so a task holding the writer's
//!   lock holds it for the copy only (about a microsecond for a telemetry frame).
//! * Only the interrupt touches the TXE interrupt enable: [`TxPump::pump`] writes bytes while
//!   the data register is empty, leaves TXEIE on while bytes remain and turns it off when the
//!   queue is empty. A frame queued after that pends the interrupt again, so no byte is left
//!   behind and no read-modify-write of CR1 races between priorities.

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::NVIC;
use heapless::spsc::{Consumer, Producer, Queue};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::_embedded_hal_serial_nb_Write as _;
use stm32f4xx_hal::serial::{self, Tx, TxListen as _};

/// Bytes [`TxPump::pump`] writes per interrupt at most. On hardware the data register takes one
/// byte per TXE (two when the shift register is idle); an emulator whose TXE never clears would
/// otherwise empty the whole queue in one interrupt.
const MAX_BYTES_PER_INTERRUPT: usize = 32;

/// The byte queue of one UART's transmit side (`N` bytes, a `static` or an RTIC `init` local).
pub struct TxQueue<const N: usize> {
    queue: Queue<u8, N>,
}

impl<const N: usize> Default for TxQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> TxQueue<N> {
    /// An empty queue.
    pub const fn new() -> Self {
        Self {
            queue: Queue::new(),
        }
    }

    /// The two ends: the writer for tasks and the pump for the UART interrupt `irq` (which must
    /// be the interrupt the pump runs in, e.g. `pac::Interrupt::USART1`). `tx` is the HAL's
    /// transmit half of the configured UART.
    pub fn split<U: serial::Instance>(
        &'static mut self,
        tx: Tx<U>,
        irq: pac::Interrupt,
    ) -> (TxWriter, TxPump<U>) {
        let (producer, consumer) = self.queue.split();
        (
            TxWriter {
                producer,
                irq,
                dropped_frames: AtomicU32::new(0),
            },
            TxPump { tx, consumer, irq },
        )
    }
}

/// The task side of a transmit queue.
pub struct TxWriter {
    producer: Producer<'static, u8>,
    irq: pac::Interrupt,
    dropped_frames: AtomicU32,
}

impl TxWriter {
    /// Queues a whole frame for transmission; returns `false` (and counts the frame in
    /// [`TxWriter::dropped_frames`]) if the queue has no room for all of it. Never blocks.
    pub fn send(&mut self, frame: &[u8]) -> bool {
        let free = self.producer.capacity() - self.producer.len();
        if frame.len() > free {
            self.dropped_frames.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        for &byte in frame {
            // Cannot fail: the room was checked and only this writer enqueues.
            if self.producer.enqueue(byte).is_err() {
                self.dropped_frames.fetch_add(1, Ordering::Relaxed);
                break;
            }
        }
        NVIC::pend(self.irq);
        true
    }

    /// Encodes `msg` into a frame of at most `N` bytes and queues it (see [`TxWriter::send`]).
    /// Returns `false` if it was dropped (no room, or it does not encode into `N` bytes).
    pub fn send_message<M: protocol::Message, const N: usize>(&mut self, msg: &M) -> bool {
        let mut buf = [0u8; N];
        match protocol::encode(msg, &mut buf) {
            Ok(n) => self.send(buf.get(..n).unwrap_or(&[])),
            Err(_) => {
                self.dropped_frames.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Frames dropped since boot (queue full or not encodable).
    pub fn dropped_frames(&self) -> u32 {
        self.dropped_frames.load(Ordering::Relaxed)
    }

    /// Bytes waiting in the queue.
    pub fn queued(&self) -> usize {
        self.producer.len()
    }
}

/// The interrupt side of a transmit queue.
pub struct TxPump<U: serial::Instance> {
    tx: Tx<U>,
    consumer: Consumer<'static, u8>,
    irq: pac::Interrupt,
}

impl<U: serial::Instance> TxPump<U> {
    /// Moves queued bytes into the data register while it is empty; keeps the TXE interrupt on
    /// while bytes remain, off when the queue is empty. Call on every entry of the UART's
    /// interrupt handler (whatever raised it).
    pub fn pump(&mut self) {
        for _ in 0..MAX_BYTES_PER_INTERRUPT {
            let Some(&byte) = self.consumer.peek() else {
                self.tx.unlisten();
                return;
            };
            if self.tx.write(byte).is_err() {
                // The data register is still full: TXE will interrupt when it empties.
                self.tx.listen();
                return;
            }
            let _ = self.consumer.dequeue();
        }
        // The per-interrupt bound was reached with the data register still taking bytes (an
        // emulated UART without line timing): come back for the rest.
        if self.consumer.ready() {
            self.tx.listen();
            NVIC::pend(self.irq);
        } else {
            self.tx.unlisten();
        }
    }
}
