//! Stack use, measured by painting: how close the firmware has come to overflowing its stack.
//!
//! The stack region is what cortex-m-rt's linker script leaves of SRAM: from `_stack_end` (the
//! end of `.bss` and `.uninit`, the bottom) up to `_stack_start` (the end of the RAM region, the
//! initial stack pointer). Every context runs on this one main stack: the RTIC tasks and all
//! interrupt handlers nest on it. Nothing guards its bottom, so an overflow silently writes into
//! the statics below it (RTIC's queues, the frame buffers) instead of faulting.
//!
//! Method:
//!
//! * [`paint`], first thing in RTIC `init` (interrupts still off), fills the region from the
//!   bottom up to [`MARGIN_BYTES`] below the current stack pointer with [`PATTERN`], word by
//!   word, with volatile writes.
//! * Code that uses stack writes its frames over the pattern. [`free_bytes`] scans up from the
//!   bottom for the first word that is no longer the pattern: the words below it were never
//!   written since painting, so it is the low-water headroom of the whole run so far (every
//!   task and interrupt, at their worst nesting so far), not the current free stack.
//!
//! Limits:
//!
//! * Only what ran after [`paint`] is seen. The reset code and RTIC's start-up ran before it,
//!   higher up the stack; the words above the painted region (the caller's frames and the
//!   margin) are never inspected, so a run that never went deeper than `init` reads as
//!   "painted region free".
//! * The figure is the worst case *observed*, not a bound: an interrupt nesting or a code path
//!   that did not happen during the run is not in it. Measure under the heaviest realistic load
//!   (the HIL closed-loop test flies both boards).
//! * A frame that reserves stack without writing its lowest words (an uninitialised buffer
//!   that is only partly filled), or that writes a word equal to the pattern, makes the figure
//!   slightly optimistic; keep a few KiB of headroom rather than a few bytes.
//! * It sees an overflow only after the fact: a stack that went below `_stack_end` has already
//!   corrupted the statics there (the figure then reads 0). It is a measurement, not a guard.
//! * [`free_bytes`] reads every free word once (about 20,000 words with ~80 KiB free, well under
//!   a millisecond at 168 MHz): call it from a low-priority periodic task, not a fast loop.

use core::sync::atomic::{AtomicUsize, Ordering};

/// The word the unused stack is painted with (unlikely as an address, a small integer or a
/// float in flight code).
pub const PATTERN: u32 = 0x57AC_C0DE;

/// Bytes just below the stack pointer at painting time that [`paint`] leaves alone: room for
/// its own frame and anything its caller might still have live there.
pub const MARGIN_BYTES: usize = 256;

/// The address just above the painted region (0: [`paint`] has not run).
static PAINTED_TOP: AtomicUsize = AtomicUsize::new(0);

extern "C" {
    /// Bottom of the stack region (cortex-m-rt: the end of `.uninit`, 4-byte aligned).
    static _stack_end: u32;
    /// Top of the stack region (cortex-m-rt: the end of RAM, the initial stack pointer).
    static _stack_start: u32;
}

/// Address of the bottom of the stack region.
fn bottom() -> usize {
    core::ptr::addr_of!(_stack_end) as usize
}

/// Address of the top of the stack region.
fn top() -> usize {
    core::ptr::addr_of!(_stack_start) as usize
}

/// The current stack pointer.
#[inline(always)]
fn current_sp() -> usize {
    let sp: usize;
    // SAFETY: reads a register only.
    unsafe {
        core::arch::asm!("mov {}, sp", out(reg) sp, options(nomem, nostack, preserves_flags));
    }
    sp
}

/// Paints the unused part of the stack region with [`PATTERN`]: from `_stack_end` up to
/// [`MARGIN_BYTES`] below the current stack pointer. Call it once, first thing in RTIC `init`;
/// [`free_bytes`] then measures from that moment on.
///
/// Everything below the stack pointer is dead (the Cortex-M ABI keeps no data below it, and an
/// interrupt taken meanwhile only pushes frames it has popped again before painting resumes),
/// so painting it is safe at any time. If the stack pointer is not inside the stack region (a
/// process stack), nothing is painted and [`free_bytes`] reports 0.
#[inline(never)]
pub fn paint() {
    let (bottom, sp) = (bottom(), current_sp());
    if sp <= bottom || sp > top() {
        return;
    }
    let end = sp.saturating_sub(MARGIN_BYTES) & !3;
    let mut at = bottom;
    while at < end {
        // SAFETY: `at` is word aligned (`_stack_end` is, by cortex-m-rt's assertion) and lies
        // in the stack region below the stack pointer, memory no live frame or static uses.
        unsafe { core::ptr::write_volatile(at as *mut u32, PATTERN) };
        at += 4;
    }
    PAINTED_TOP.store(end.max(bottom), Ordering::Release);
}

/// Bytes at the bottom of the stack that were never written since [`paint`]: the low-water
/// headroom. 0 if [`paint`] has not run (or the stack reached its very bottom).
pub fn free_bytes() -> u32 {
    let end = PAINTED_TOP.load(Ordering::Acquire);
    let bottom = bottom();
    let mut at = bottom;
    while at < end {
        // SAFETY: a word-aligned read inside the stack region (below the painted top, so below
        // the stack pointer at painting time and above `_stack_end`).
        if unsafe { core::ptr::read_volatile(at as *const u32) } != PATTERN {
            break;
        }
        at += 4;
    }
    (at - bottom) as u32
}

/// Bytes of the whole stack region, `_stack_start - _stack_end` (what SRAM the statics leave).
pub fn size_bytes() -> u32 {
    top().saturating_sub(bottom()) as u32
}
