//! The virtual-board bench's tests: the unmodified firmware images on emulated STM32F4s
//! wired as the boards.
//!
//! Each file here is a module of one test binary, built and linked once, whose tests share
//! one thread pool. One module: `cargo test --test vboard MODULE::`.

mod autopilot_faults;
mod autopilot_imu;
mod battery;
mod boot;
mod camera;
mod camera_faults;
mod clock_wrap;
mod closed_loop;
mod hil;
mod hil_outputs;
mod link;
mod monitor;
mod params;
mod pins;
mod signing;
