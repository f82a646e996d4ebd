//! The board-to-board link's line settings, shared by both firmwares (and readable on the host,
//! e.g. by the virtual-board bench that joins the two UARTs).

/// Baud rate of the link between the camera board and the autopilot (8N1), and the default of
/// each board's host link: 115,200 Bd, what the original harness runs (camera board UART4 and
/// Lisa/MX UART2 in the paper's era: ../shared/hardware/original-boards.md, [SB-17] edgeFS.h,
/// \[PZ\] airframe xml). A faster rate is this one line; both firmwares follow it.
pub const LINK_BAUD: u32 = 115_200;

/// Baud rate of a board's host link: in the `hil` flavour 921,600 Bd (`sim-host hil`'s default:
/// IMU samples and motor commands at 512 Hz, camera frames), otherwise [`LINK_BAUD`] (the
/// autopilot's telemetry modem runs at 115,200 Bd on the original board).
#[cfg(feature = "hil")]
pub const HOST_BAUD: u32 = 921_600;
/// Baud rate of a board's host link (see the `hil` flavour's).
#[cfg(not(feature = "hil"))]
pub const HOST_BAUD: u32 = LINK_BAUD;
