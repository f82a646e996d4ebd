//! The autopilot: adaptive INDI attitude control, height control, velocity guidance, median-5
//! filter, wall force field, avoidance FSM and failsafes. `no_std`, no heap, time passed in: the
//! firmware and `sim-host` run exactly this code.
#![no_std]
#![warn(missing_docs)]
