//! Wire protocol shared by the stereo board, the autopilot and the host tools.
//!
//! * [`messages`]: one enum per direction, serde + postcard, SI units documented on every field.
//! * [`framing`]: COBS frames carrying a version byte, the postcard payload and a CRC; an
//!   encoder into a caller-provided buffer and a streaming [`Decoder`] with a bounded buffer
//!   that never panics, resynchronises at the next delimiter and counts errors by kind.
//! * [`params`]: named, typed parameter tables, their messages and their flash record.
//! * [`signing`]: the signed envelope of host commands (keyed MAC, anti-replay timestamp).
//!
//! `no_std`, no heap. Enable the `defmt` feature for `defmt::Format` on every type.
#![no_std]
#![warn(missing_docs)]

pub mod envelope;
pub mod messages;
pub mod node;
pub mod params;
pub mod signing;

pub use params::{
    ParamEntry, ParamError, ParamKind, ParamName, ParamOp, ParamReply, ParamRequest, ParamResponse,
    ParamSpec, ParamUnit, ParamValue,
};

pub use messages::*;
pub mod framing;

pub use framing::{
    decode_frame, encode, encode_to_vec, AutopilotToStereoDecoder, BoardToHostDecoder, Decoder,
    EncodeError, FrameError, HostToBoardDecoder, StereoToAutopilotDecoder, DELIMITER,
};
