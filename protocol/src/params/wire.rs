//! The parameter messages: what a host asks a board's table ([`ParamRequest`]) and what the
//! board answers ([`ParamResponse`]).

use serde::{Deserialize, Serialize};

use super::error::ParamError;
use super::store::StorageStatus;
use super::value::{ParamName, ParamUnit, ParamValue};
use crate::node::Node;

/// What a host asks a board's parameter table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamOp {
    /// The entry at this index (answered with [`ParamReply::Entry`], which carries the count).
    List(u16),
    /// The entry of this name.
    Get(ParamName),
    /// Writes this value (checked against the kind and bounds; refused while the motors may
    /// run). Answered with the entry holding the value now in use.
    Set(ParamName, ParamValue),
    /// Saves every value to flash (refused while the motors may run).
    Save,
    /// What the board's parameter storage holds (answered with [`ParamReply::Storage`]).
    Storage,
    /// Accepts that the boot's record failed to load, so that the defaults in use may fly
    /// ([`StorageStatus::blocks_arming`]); answered with [`ParamReply::Storage`].
    Acknowledge,
}

/// A parameter request to one board (host -> autopilot; the autopilot answers for itself and
/// passes a request for the camera board on over the board-to-board link, and its answer back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamRequest {
    /// The board whose table is meant.
    pub board: Node,
    /// What to do.
    pub op: ParamOp,
}

/// One parameter as a board reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamEntry {
    /// Index in the board's table.
    pub index: u16,
    /// Number of entries in the table.
    pub count: u16,
    /// Name.
    pub name: ParamName,
    /// Unit.
    pub unit: ParamUnit,
    /// The value in use.
    pub value: ParamValue,
    /// The firmware's default.
    pub default: ParamValue,
    /// Smallest accepted value.
    pub min: ParamValue,
    /// Largest accepted value.
    pub max: ParamValue,
    /// False: shown, not settable.
    pub writable: bool,
}

/// A board's answer to one [`ParamRequest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamReply {
    /// The entry asked for (or written).
    Entry(ParamEntry),
    /// Every value was saved to flash.
    Saved,
    /// The request failed; nothing changed.
    Error(ParamError),
    /// The board's parameter storage: what the boot loaded, and the saves since.
    Storage(StorageStatus),
}

/// A parameter answer (board -> host).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamResponse {
    /// The board whose table the answer is about (the request's).
    pub board: Node,
    /// The answer.
    pub reply: ParamReply,
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::params::value::{PARAM_NAME_LEN, PARAM_UNIT_LEN};

    #[test]
    fn the_largest_messages_fit_their_frames() {
        use crate::{
            encode, AutopilotToStereo, BoardToHost, HostToBoard, Message, StereoToAutopilot,
        };
        let name = ParamName::try_from("n".repeat(PARAM_NAME_LEN).as_str()).unwrap();
        let unit = ParamUnit::try_from("u".repeat(PARAM_UNIT_LEN).as_str()).unwrap();
        // Values whose encodings are the longest (u32::MAX is a 5-byte varint).
        let big = ParamValue::U32(u32::MAX);
        let answer = BoardToHost::Param(ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Entry(ParamEntry {
                index: u16::MAX,
                count: u16::MAX,
                name: name.clone(),
                unit,
                value: big,
                default: big,
                min: big,
                max: big,
                writable: true,
            }),
        });
        let mut buf = [0u8; 1024];
        let n = encode(&answer, &mut buf).unwrap();
        assert!(n <= BoardToHost::MAX_FRAME_BYTES, "{n} bytes");
        let BoardToHost::Param(response) = answer else {
            unreachable!()
        };
        let n = encode(&StereoToAutopilot::Param(response), &mut buf).unwrap();
        assert!(n <= StereoToAutopilot::MAX_FRAME_BYTES, "{n} bytes");
        let req = ParamRequest {
            board: Node::StereoBoard,
            op: ParamOp::Set(name, big),
        };
        let n = encode(&HostToBoard::Param(req.clone()), &mut buf).unwrap();
        assert!(n <= HostToBoard::MAX_FRAME_BYTES, "{n} bytes");
        let n = encode(&AutopilotToStereo::Param(req), &mut buf).unwrap();
        assert!(n <= AutopilotToStereo::MAX_FRAME_BYTES, "{n} bytes");
    }
}
