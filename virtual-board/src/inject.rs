//! Faults the bench injects at an exact instruction of an unmodified image.
//!
//! The bench has no hold on the core's registers, only on its memory, so a [`ReturnHijack`]
//! makes one function return into a few instructions of the bench's: at the next arrival at
//! the function's entry (a `PUSH` that saves `LR`), once that push has landed, the saved return
//! address is replaced with the address of the instructions, which the bench writes into dead
//! stack when the core gets there. Two payloads ([`Payload`]):
//!
//! - [`Payload::RunawayRecursion`], a stack overflow: `PUSH {r0-r7}`, `B` back to it (32 bytes
//!   of stack a turn, without end). When the function returns, the context it ran in descends
//!   through the whole stack region until a push leaves SRAM. Linked with flip-link, the stack region is the bottom of SRAM, so that push is a bus
//!   fault (nothing is mapped below `0x2000_0000`) and the statics above the stack are never
//!   touched; what the firmware's HardFault path does with a stack that is used up is what a
//!   test then watches.
//! - [`Payload::UnboundInterrupt`]: enables and pends IRQ 0 (the window watchdog, `WWDG`, which
//!   neither firmware uses) in the NVIC (`ISER0`, `ISPR0`, ARMv7-M ARM B3.4), then spins. At its
//!   reset priority (0, the highest) it is taken at once, through whatever vector the image's
//!   table holds for it: what a test then watches is the `DefaultHandler` path.
//!
//! The instructions go near the top of the stack region, in the frames of the contexts the
//! hijacked one interrupted (they never resume: the runaway never returns, and it starts below
//! them and only descends); they are written as the core arrives there.

use rigless::emulator::{Hit, HitKind, Host, Watch};
use rigless::machine::Board;
use rigless::session::Session;
use rigless::soc::Width;

use crate::firmware::Firmware;

/// `PUSH {r0-r7}` (T1, ARMv7-M ARM A7.7.99) then `B` to it (T2, A7.7.12: imm11 = -3, to
/// PC + 4 - 6), as one little-endian word.
const RUNAWAY: [u32; 1] = [0xE7FD_B4FF];

/// Pends IRQ 0, as little-endian words (Thumb, ARMv7-M ARM A7.7):
///
/// ```text
/// +0   4802      LDR   r0, [pc, #8]      ; the literal at +12: NVIC_ISER0
/// +2   2101      MOVS  r1, #1            ; IRQ 0's bit
/// +4   6001      STR   r1, [r0]          ; enabled (ISER0)
/// +6   f8c0 1100 STR.W r1, [r0, #0x100]  ; pending (ISPR0, 0xE000_E200)
/// +10  e7fe      B     .                 ; spins (never reached: the IRQ is taken first)
/// +12  e000e100                          ; NVIC_ISER0
/// ```
const PEND_IRQ0: [u32; 4] = [0x2101_4802, 0xF8C0_6001, 0xE7FE_1100, 0xE000_E100];

/// The number of the exception an IRQ 0 is taken as (the exception number the firmware's
/// `DefaultHandler` reports: 16 plus the IRQ number).
pub const UNBOUND_IRQ_VECTOR: u32 = 16;

/// What the hijacked return runs into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Payload {
    /// A push without end: the stack overflows.
    RunawayRecursion,
    /// IRQ 0, which has no handler of the image's own, enabled and pended.
    UnboundInterrupt,
}

impl Payload {
    fn words(self) -> &'static [u32] {
        match self {
            Self::RunawayRecursion => &RUNAWAY,
            Self::UnboundInterrupt => &PEND_IRQ0,
        }
    }
}

/// Where the injection stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Not armed yet.
    Idle,
    /// Waiting for the core to arrive at the function's entry.
    Armed,
    /// At the entry (the instruction count of the arrival): waiting for its push to land.
    Entered(u64),
    /// The return address is replaced: waiting for the return, to write the runaway's
    /// instructions as the core arrives at them.
    Returning,
    /// The runaway runs (from this virtual time, ns).
    Installed(u64),
}

/// A payload injected through one function's saved return address.
#[derive(Debug, Clone)]
pub struct ReturnHijack {
    payload: Payload,
    entry: u64,
    /// Bytes from the push's lowest address to the saved `LR`, and the push's size.
    lr_offset: u64,
    push_bytes: u64,
    stack_bottom: u64,
    stack_top: u64,
    state: State,
}

impl ReturnHijack {
    /// `payload` through the function whose symbol is `name` (exactly), found in `firmware`
    /// with flip-link's stack region (`_stack_end` up to `_stack_start`).
    ///
    /// # Errors
    /// No such symbol, no stack region, or the function does not begin with a push of `LR`.
    pub fn new(firmware: &Firmware, name: &str, payload: Payload) -> Result<Self, String> {
        let entry = firmware
            .symbol(name)
            .ok_or_else(|| format!("no symbol {name}"))?;
        let (bottom, top) = (
            firmware.symbol("_stack_end").ok_or("no _stack_end")?,
            firmware.symbol("_stack_start").ok_or("no _stack_start")?,
        );
        if bottom >= top {
            return Err(format!(
                "no stack region below the statics: _stack_end {bottom:#x}, _stack_start {top:#x}"
            ));
        }
        let code = firmware
            .bytes_at(entry, 4)
            .ok_or_else(|| format!("{name} at {entry:#x} is outside the image"))?;
        let first = u16::from_le_bytes([code[0], code[1]]);
        let second = u16::from_le_bytes([code[2], code[3]]);
        let (lr_offset, push_bytes) = if first & 0xFE00 == 0xB400 && first & 0x0100 != 0 {
            // PUSH (T1): r0-r7 in bits 7:0, LR in bit 8; stored in register order upward.
            let low = u64::from((first & 0xFF).count_ones());
            (4 * low, 4 * (low + 1))
        } else if first == 0xE92D && second & 0x4000 != 0 {
            // PUSH.W (T2, STMDB SP!): the register list in the second halfword, LR bit 14.
            let below = u64::from((second & 0x3FFF).count_ones());
            (4 * below, 4 * u64::from(second.count_ones()))
        } else {
            return Err(format!(
                "{name} begins with {first:#06x} {second:#06x}, not a push of LR"
            ));
        };
        Ok(Self {
            payload,
            entry,
            lr_offset,
            push_bytes,
            stack_bottom: bottom,
            stack_top: top,
            state: State::Idle,
        })
    }

    /// The stack region, `[bottom, top)`.
    #[must_use]
    pub fn stack(&self) -> (u64, u64) {
        (self.stack_bottom, self.stack_top)
    }

    /// Where the payload's instructions go: the top 16 bytes of the stack region.
    fn runaway_at(&self) -> u64 {
        (self.stack_top - 16) & !3
    }

    /// The watch on every store into the stack region (what finds the push's address).
    fn stack_watch(&self) -> Watch {
        Watch::Writes {
            address: self.stack_bottom,
            length: self.stack_top - self.stack_bottom,
        }
    }

    /// Arms the injection: from now on, the next arrival at the function. Call it at a stop
    /// (watches asked there take effect before the next instruction).
    pub fn arm<B: Board + ?Sized>(&mut self, session: &mut Session<B>) {
        if self.state == State::Idle {
            session.watch(Watch::Instruction(self.entry));
            session.watch(self.stack_watch());
            self.state = State::Armed;
        }
    }

    /// When the payload began to run, ns.
    #[must_use]
    pub fn installed_at(&self) -> Option<u64> {
        match self.state {
            State::Installed(at) => Some(at),
            _ => None,
        }
    }

    /// A hit on what the injection watches (the bench's [`crate::bench::Probe::hit`]); other
    /// hits are ignored.
    pub fn hit<B: Board + ?Sized>(
        &mut self,
        hit: &Hit,
        session: &mut Session<B>,
        host: &mut dyn Host,
    ) {
        match (self.state, hit.kind) {
            (State::Armed | State::Entered(_), HitKind::Instruction)
                if hit.address == self.entry =>
            {
                self.state = State::Entered(hit.instruction_count);
            }
            (State::Entered(arrived), HitKind::Write) => {
                // The function's own push is the first instruction after the arrival; a store
                // of anything else (an interrupt taken in between) waits for the next arrival.
                self.state = State::Armed;
                if hit.instruction_count > arrived + 1 {
                    return;
                }
                let lowest = hit.address;
                let runaway = self.runaway_at();
                if lowest + self.push_bytes > runaway {
                    return;
                }
                // What the push saved as LR: a return address into the code (Thumb bit set).
                let saved = host.read(lowest + self.lr_offset, Width::W32).unwrap_or(0);
                if saved & 1 == 0 || !(0x0800_0000..0x0810_0000).contains(&saved) {
                    return;
                }
                if host
                    .write(lowest + self.lr_offset, Width::W32, runaway | 1)
                    .is_ok()
                {
                    session.unwatch(Watch::Instruction(self.entry));
                    session.unwatch(self.stack_watch());
                    session.watch(Watch::Instruction(runaway));
                    self.state = State::Returning;
                }
            }
            // The function returns: the instructions go where the core is about to fetch
            // them. (Written any earlier, they could be overwritten meanwhile: the words above
            // the function's frame hold the interrupted contexts' frames, whose floating-point
            // part is stacked lazily, at the handler's first floating-point instruction.)
            (State::Returning, HitKind::Instruction) if hit.address == self.runaway_at() => {
                let placed = self.payload.words().iter().zip(0u64..).all(|(&word, i)| {
                    host.write(self.runaway_at() + 4 * i, Width::W32, u64::from(word))
                        .is_ok()
                });
                if placed {
                    session.unwatch(Watch::Instruction(self.runaway_at()));
                    self.state = State::Installed(hit.at.0);
                }
            }
            _ => {}
        }
    }
}
