//! The `sim-host` commands as a user runs them: `fly`, `monitor`, `param`, `suite merge`, the
//! live view, the MCAP log, Ctrl-C.
//!
//! Each file here is a module of one test binary, built and linked once, whose tests share
//! one thread pool. One module: `cargo test --test commands MODULE::`.

mod fly_csv;
mod interrupt;
mod live_view;
mod mcap_log;
mod monitor;
mod param;
mod suite_merge;
