//! Host tools for the pocket drone: the closed-loop simulator (`fly`), the Edge-FS evaluation on
//! recorded stereo data (`eval`) and the hardware-in-the-loop bridge (`hil`), and their MCAP flight logs (`log`).
#![warn(missing_docs)]

pub mod eval;
pub mod fly;
pub mod hil;
pub mod key;
pub mod log;
pub mod monitor;
pub mod param;
pub mod plot_font;
pub mod sim;
pub mod suite;
pub mod transport;

/// Installs the process's Ctrl-C (SIGINT) handler and returns the flag it sets: a long-running
/// command (`fly`, `hil`, `monitor`) polls it, stops, and still finishes its MCAP file and
/// writes its CSV. A second Ctrl-C exits at once (status 130), for a command stuck elsewhere.
pub fn interrupt_flag() -> anyhow::Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    use std::sync::atomic::{AtomicBool, Ordering};
    let flag = std::sync::Arc::new(AtomicBool::new(false));
    let set = flag.clone();
    ctrlc::set_handler(move || {
        if set.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    })
    .map_err(|e| anyhow::anyhow!("installing the Ctrl-C handler: {e}"))?;
    Ok(flag)
}
