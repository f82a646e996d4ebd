//! The stereo-board firmware binary.
//!
//! On `thumbv7em-none-eabihf` this is the RTIC 2 application in [`firmware`]; on the host it is
//! a stub so that `cargo test --workspace` and `cargo clippy --workspace` work everywhere.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod firmware;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("the stereo-board firmware only builds for thumbv7em-none-eabihf (run `cargo xtask fw camera`)");
    std::process::exit(2);
}
