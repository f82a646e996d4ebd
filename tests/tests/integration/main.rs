//! Cross-crate integration tests: closed loop, data set, firmware task tables, instruction
//! counts.
//!
//! Each file here is a module of one test binary, built and linked once, whose tests share
//! one thread pool. One module: `cargo test --test integration MODULE::`.

mod config_space;
mod eval_default;
mod eval_errors;
mod eval_paper;
mod eval_tune;
mod firmware_task_tables;
mod import_circles;
mod insns_determinism;
mod link_settings;
mod replay;
mod sim_camera;
mod sim_flight;
mod sim_plain_walls;
mod time_to_contact;
