//! Virtual boards: the unmodified `real` firmware images of both boards on emulated STM32F4s
//! (rigless's STM32F427 core and peripheral models), wired as the original boards
//! (`../shared/hardware/original-boards.md`), with models of the chips on them.
//!
//! * [`soc`]: our SoC type. rigless's STM32F427 models plus what it lacks (EXTI, SYSCFG, a DCMI
//!   slot), and the part the board really carries ([`soc::Part`]: F407 camera board, F415
//!   autopilot), so a run that touches a peripheral or memory the real part lacks fails.
//! * chip models: [`mpu6000`] (IMU), rigless's own MS5611 (barometer), the camera board's
//!   [`tcm8230`] sensors behind the [`cpld`] on the [`dcmi`].
//! * [`boards`]: the two boards, each wired as its original; [`clock_timer`]: a timer that only
//!   generates a clock, woken only when something can see its events.
//! * [`link`]: two boards' UARTs joined byte for byte, [`bench`](mod@bench): the harness that loads the
//!   ELFs, runs them in virtual time (two boards in lockstep), reads their defmt logs over RTT
//!   ([`rtt`]) and watches for panics and faults, and the stack's low-water mark ([`stack`]); [`motors`] reads PWM duties off timer channels.
//! * [`pilot`]: what a user does to fly the autopilot (height fixes, `Arm`), and schedules on
//!   the bench's stops.
//!
//! * [`flash`]: what the boards' flash holds beside the firmware at power-on (saved
//!   parameters), and what of the flash interface rigless models.
//! * [`serve`]: a board's host UART on a TCP socket, for ground tools (`sim-host monitor`).
//! * [`world`]: sim-host's simulated world (dynamics, barometer, renderer) stepped in lockstep
//!   with the boards: its state on the IMU, barometer and cameras, the motor duties on its
//!   dynamics.
//!
//! Virtual time is rigless's: 4 ns per instruction at 168 MHz by default (250 M instructions per
//! virtual second; [`timing`] sets the pessimistic 8.93 ns and the watchdog's LSI corners), and
//! a core in WFI skips to its next event.

pub mod bench;
pub mod boards;
pub mod clock_timer;
pub mod clocks;
pub mod cpld;
pub mod dcmi;
pub mod exti;
pub mod firmware;
pub mod flash;
pub mod frames;
pub mod host;
pub mod inject;
pub mod link;
pub mod motors;
pub mod mpu6000;
pub mod ms5611;
pub mod pilot;
pub mod pins;
pub mod rtt;
pub mod serve;
pub mod soc;
pub mod stack;
pub mod syscfg;
pub mod tcm8230;
pub mod timing;
pub mod world;
