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
