//! The parameter tables the tests of several files share: a plain table of specs, and a
//! configuration with its table declared by [`crate::param_table!`].

use super::table::{Conflict, ParamTable};
use super::value::{ParamKind, ParamSpec, ParamValue};

/// Three specs, one of each kind but `i32`.
pub(super) const TABLE: &[ParamSpec] = &[
    ParamSpec {
        name: "gain",
        kind: ParamKind::F32,
        unit: "-",
        min: ParamValue::F32(0.0),
        max: ParamValue::F32(2.0),
        writable: true,
    },
    ParamSpec {
        name: "timeout_us",
        kind: ParamKind::U32,
        unit: "us",
        min: ParamValue::U32(10),
        max: ParamValue::U32(1_000_000),
        writable: true,
    },
    ParamSpec {
        name: "adapt",
        kind: ParamKind::Bool,
        unit: "-",
        min: ParamValue::Bool(false),
        max: ParamValue::Bool(true),
        writable: true,
    },
];

/// A configuration of four fields: a float, a signed and two unsigned integers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Cfg {
    pub(super) gain: f32,
    pub(super) shift: i8,
    pub(super) lo: u8,
    pub(super) hi: u8,
}

/// The configuration's defaults.
pub(super) const CFG_DEFAULT: Cfg = Cfg {
    gain: 1.0,
    shift: -2,
    lo: 1,
    hi: 5,
};

crate::param_table! {
    /// The configuration's specs (`hi` read-only).
    pub(super) CFG_SPECS, CFG_ACCESS: Cfg {
        "gain": F32 ["-"] 0.0, 2.0, true => |c| c.gain;
        "shift": I32 ["px"] -20, 20, true => |c| c.shift;
        "lo": U32 ["-"] 0, 10, true => |c| c.lo;
        "hi": U32 ["-"] 0, 10, false => |c| c.hi;
    }
}

/// The configuration's table: `lo` must not exceed `hi`.
pub(super) const CFG_TABLE: ParamTable<Cfg> = ParamTable {
    specs: CFG_SPECS,
    access: CFG_ACCESS,
    defaults: || CFG_DEFAULT,
    consistent: |c| {
        if c.lo > c.hi {
            Err(Conflict::new("lo", "hi", "must not exceed"))
        } else {
            Ok(())
        }
    },
};
