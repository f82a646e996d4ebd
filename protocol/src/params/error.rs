//! Why a parameter request failed: the one error a value check, a write, a store and a save
//! return, and the one a board's reply carries.

use serde::{Deserialize, Serialize};

/// Why a parameter request failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamError {
    /// No parameter of that name.
    UnknownName,
    /// Index past the end of the table.
    UnknownIndex,
    /// The value is not of the parameter's kind.
    WrongKind,
    /// The value is outside the parameter's bounds (or not finite).
    OutOfBounds,
    /// The parameter cannot be set at run time.
    ReadOnly,
    /// The motors may run (armed, flying, landing): set and save wait for the ground.
    Armed,
    /// The value is within its bounds but the configuration it makes is inconsistent (e.g. a
    /// minimum above its maximum); the previous value stays.
    Inconsistent,
    /// This board does not serve that board's table.
    NoSuchBoard,
    /// The flash could not be written or read back.
    SaveFailed,
    /// This build has no parameter storage.
    NoStorage,
}

impl ParamError {
    /// A short sentence for a user.
    pub fn describe(self) -> &'static str {
        match self {
            ParamError::UnknownName => "no parameter of that name",
            ParamError::UnknownIndex => "index past the end of the table",
            ParamError::WrongKind => "value of the wrong type",
            ParamError::OutOfBounds => "value outside the parameter's bounds",
            ParamError::ReadOnly => "the parameter is read-only",
            ParamError::Armed => "refused while armed (the motors may run)",
            ParamError::Inconsistent => "the configuration would be inconsistent",
            ParamError::NoSuchBoard => "this board does not serve that board's parameters",
            ParamError::SaveFailed => "writing the flash failed",
            ParamError::NoStorage => "this build has no parameter storage",
        }
    }
}
