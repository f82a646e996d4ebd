//! The camera board: Edge-FS velocity and obstacle estimation on 128x96 stereo frames, and the
//! board's hardware-free task logic. `no_std`, no heap: the firmware and `sim-host` run exactly
//! this code.
#![no_std]
#![warn(missing_docs)]

pub mod app;
pub mod board;
pub mod camera;
pub mod edge_fs;
pub mod params;
