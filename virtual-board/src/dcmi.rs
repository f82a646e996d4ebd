//! The digital camera interface, RM0090 rev 22 section 15 (rigless has no model for it).
//!
//! Not modelled yet: this is the slot [`crate::soc::Soc`] answers the DCMI's registers from; its
//! registers are stored and nothing is captured. The camera board's model (hardware sync, crop,
//! frame/line/overrun events, the DMA2 stream 1 request) replaces it.

use rigless::device::Device;
use rigless::soc::stm32f427::generated::dcmi::Register;

/// The DCMI's model.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Dcmi;

impl Device for Dcmi {
    type Register = Register;
}
