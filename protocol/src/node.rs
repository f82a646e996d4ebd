//! The nodes of the pocket drone's links: the two boards and the host tools.

use serde::{Deserialize, Serialize};

/// Which board (or host tool) sent a message ([`crate::Heartbeat`], a parameter answer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Node {
    /// The stereo camera board running Edge-FS.
    StereoBoard,
    /// The autopilot.
    Autopilot,
    /// A host tool: simulator, HIL bridge or ground station.
    Host,
}
