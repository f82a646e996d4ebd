//! The fault path both firmwares share: on a panic, a HardFault, an NMI or any exception or
//! interrupt the firmware does not handle (an unbound IRQ reaches `DefaultHandler`) the board's
//! actuators are forced off first, then the fault is logged, then the board waits for the
//! independent watchdog to reset it (MCU only).
//!
//! A board installs the handlers with [`fault_handlers!`], naming its actuator stop: a plain
//! `fn()` that writes the output registers directly (no lock, no allocation, no HAL state; it
//! must be safe to call at any instant, also before the outputs were configured). The order:
//!
//! 1. interrupts off (`cpsid i`), so that no higher-priority task can drive the outputs again;
//! 2. the board's stop;
//! 3. the independent watchdog started if it was not yet (an early fault still resets, within
//!    the watchdog's reset-default period of 512 ms);
//! 4. one defmt line (skipped when the fault happened inside the logger itself, or when a
//!    second fault arrives while the first is being logged);
//! 5. wait (WFI) until the watchdog resets the part. In the `qemu` flavour the fault is printed
//!    through semihosting and QEMU exits with a failure code instead.
//!
//! After the reset nothing is remembered: the firmware starts from its reset state, outputs
//! off, until it is armed again.

use core::sync::atomic::{AtomicBool, Ordering};

/// Set by the first fault; a fault while it is being handled (a panic inside the logger)
/// skips logging and goes straight to the wait.
static FAULTED: AtomicBool = AtomicBool::new(false);

/// Installs the panic handler, the HardFault handler, the NMI handler (`NonMaskableInt`) and
/// the `DefaultHandler` (every exception or interrupt without a handler of its own: an IRQ
/// enabled without an RTIC binding, a spurious one) of a firmware. `$stop` is the path of the
/// board's `fn()` that forces every actuator output off at the registers.
///
/// The HardFault handler is entered through [`hard_fault_entry!`]'s instructions, which need no
/// stack: a HardFault from a stack overflow arrives with the stack pointer below the stack
/// region (flip-link puts the stack at the bottom of SRAM, so the push that overflowed left
/// SRAM and faulted), where every push faults again and locks the core up with the motors
/// running. The entry reads the faulting instruction's address from the exception frame if the
/// frame lies in the stack region, then moves the stack pointer to the top of the region (what
/// was on the stack is dead: the fault path never returns) and only then calls the Rust half.
#[macro_export]
macro_rules! fault_handlers {
    ($stop:path) => {
        #[panic_handler]
        fn board_support_panic(info: &core::panic::PanicInfo) -> ! {
            $crate::fault::on_panic($stop, info)
        }

        /// The HardFault path's Rust half, on a fresh stack: `pc` the faulting instruction's
        /// address (0 if the frame was lost), `stack_lost` 1 if the stack pointer had left the
        /// stack region.
        extern "C" fn board_support_hard_fault(pc: u32, stack_lost: u32) -> ! {
            $crate::fault::on_hard_fault($stop, pc, stack_lost != 0)
        }

        $crate::hard_fault_entry!(board_support_hard_fault);

        /// An NMI (clock security system, or a pended NMI): nothing of ours raises one, so
        /// it is a fault.
        #[no_mangle]
        extern "C" fn NonMaskableInt() -> ! {
            $crate::fault::on_unexpected($stop, 2)
        }

        /// Every exception or interrupt without a handler of its own (cortex-m-rt's vector
        /// table points them here).
        #[no_mangle]
        extern "C" fn DefaultHandler() -> ! {
            $crate::fault::on_unexpected($stop, $crate::fault::active_vector())
        }
    };
}

/// The `HardFault` vector's instructions (see [`fault_handlers!`]), calling `$entry(pc,
/// stack_lost)`. The firmwares run every context on the main stack (RTIC), so the frame is on
/// MSP. `_stack_end` and `_stack_start` bound the stack region (flip-link's layout, checked by
/// `cargo xtask size`).
#[macro_export]
macro_rules! hard_fault_entry {
    ($entry:ident) => {
        core::arch::global_asm!(
            ".section .HardFault.user, \"ax\"",
            ".global HardFault",
            ".type HardFault,%function",
            ".thumb_func",
            "HardFault:",
            // The frame: eight words from MSP, readable only inside the stack region.
            "mrs r0, MSP",
            "ldr r1, =_stack_end",
            "ldr r2, =_stack_start",
            "cmp r0, r1",
            "blo 1f",
            "subs r3, r2, #32",
            "cmp r0, r3",
            "bhi 1f",
            // The stacked PC (ARMv7-M ARM B1.5.6: the seventh word of the frame).
            "ldr r0, [r0, #24]",
            "movs r1, #0",
            "b 2f",
            "1:",
            "movs r0, #0",
            "movs r1, #1",
            "2:",
            // A fresh stack at the top of the region, then the Rust half (which never returns).
            "msr MSP, r2",
            "b {entry}",
            ".ltorg",
            ".size HardFault, . - HardFault",
            entry = sym $entry,
        );
    };
}

/// The panic path (see the module documentation).
pub fn on_panic(stop: fn(), info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    stop();
    start_watchdog();
    if !FAULTED.swap(true, Ordering::AcqRel) {
        defmt::error!("panic: {}", defmt::Display2Format(info));
        #[cfg(feature = "qemu")]
        {
            cortex_m_semihosting::hprintln!("panic: {}", info);
            cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        }
    }
    wait_for_watchdog()
}

/// The HardFault path (see the module documentation); `pc` is the faulting instruction's
/// address from the exception frame, `stack_lost` whether the stack pointer had left the stack
/// region (a stack overflow: the frame, and `pc`, are lost).
pub fn on_hard_fault(stop: fn(), pc: u32, stack_lost: bool) -> ! {
    cortex_m::interrupt::disable();
    stop();
    start_watchdog();
    if !FAULTED.swap(true, Ordering::AcqRel) {
        if stack_lost {
            defmt::error!("HardFault: stack overflow (the stack pointer left the stack region)");
        } else {
            defmt::error!("HardFault at pc={=u32:#010x}", pc);
        }
        #[cfg(feature = "qemu")]
        {
            cortex_m_semihosting::hprintln!(
                "HardFault at pc={:#010x} (stack lost: {})",
                pc,
                stack_lost
            );
            cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        }
    }
    wait_for_watchdog()
}

/// The path of an NMI or an exception or interrupt without a handler (`vector`: its number
/// in the vector table, 16 and up for IRQ 0 and up): the same as a HardFault's.
pub fn on_unexpected(stop: fn(), vector: u32) -> ! {
    cortex_m::interrupt::disable();
    stop();
    start_watchdog();
    if !FAULTED.swap(true, Ordering::AcqRel) {
        defmt::error!("unhandled exception or interrupt: vector {=u32}", vector);
        #[cfg(feature = "qemu")]
        {
            cortex_m_semihosting::hprintln!("unhandled exception or interrupt: vector {}", vector);
            cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        }
    }
    wait_for_watchdog()
}

/// The number of the exception being handled (`ICSR.VECTACTIVE`, ARMv7-M ARM B3.2.4).
pub fn active_vector() -> u32 {
    // SAFETY: a read of the SCB's ICSR, which has no side effect.
    let icsr = unsafe { (*cortex_m::peripheral::SCB::PTR).icsr.read() };
    icsr & 0x1FF
}

/// Starts the watchdog and waits for its reset: the end of a set-up error that has no
/// actuator to stop ([`crate::log::fatal`]).
pub fn reset_by_watchdog() -> ! {
    cortex_m::interrupt::disable();
    start_watchdog();
    wait_for_watchdog()
}

/// Starts the independent watchdog (key 0xCCCC, RM0090 section 21.3.2). If the firmware had
/// started it, this changes nothing; if not, it runs with its reset prescaler and reload
/// (/4, 0xFFF at 32 kHz: 512 ms).
fn start_watchdog() {
    #[cfg(not(feature = "qemu"))]
    {
        // SAFETY: a write of the start key to IWDG_KR; the watchdog cannot be stopped, so
        // this cannot undo anything the firmware set.
        let iwdg = unsafe { &*stm32f4xx_hal::pac::IWDG::ptr() };
        // SAFETY: 0xCCCC is a valid key value (the start key).
        iwdg.kr().write(|w| unsafe { w.key().bits(0xCCCC) });
    }
}

/// Sleeps until the watchdog resets the part (interrupts are off, so WFI only idles).
fn wait_for_watchdog() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// What caused the last reset, from the RCC's reset flags (RM0090 section 7.3.21).
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// The independent watchdog expired (a hung task or a fault waiting for it).
    Watchdog,
    /// The window watchdog expired.
    WindowWatchdog,
    /// Software reset (`SYSRESETREQ`, e.g. a debugger).
    Software,
    /// Low-power management reset.
    LowPower,
    /// Power-on or brown-out.
    PowerOn,
    /// The NRST pin (button or probe).
    Pin,
    /// No flag set.
    Unknown,
}

/// Reads and clears the reset flags: call once at boot (to log, and to report in status).
pub fn take_reset_cause() -> ResetCause {
    // SAFETY: RCC_CSR's reset flags are read and cleared here only, once at boot.
    let rcc = unsafe { &*stm32f4xx_hal::pac::RCC::ptr() };
    let csr = rcc.csr().read();
    let cause = if csr.wdgrstf().bit_is_set() {
        ResetCause::Watchdog
    } else if csr.wwdgrstf().bit_is_set() {
        ResetCause::WindowWatchdog
    } else if csr.sftrstf().bit_is_set() {
        ResetCause::Software
    } else if csr.lpwrrstf().bit_is_set() {
        ResetCause::LowPower
    } else if csr.porrstf().bit_is_set() || csr.borrstf().bit_is_set() {
        ResetCause::PowerOn
    } else if csr.padrstf().bit_is_set() {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    };
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    cause
}
