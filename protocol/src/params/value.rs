//! Parameter kinds, values and specs: the entries of a board's table, the checks of a value
//! against its entry, the table's hash and the configuration fields seen as values.

use serde::{Deserialize, Serialize};

use super::error::ParamError;

/// Longest parameter name, bytes.
pub const PARAM_NAME_LEN: usize = 24;
/// Longest unit string, bytes.
pub const PARAM_UNIT_LEN: usize = 8;

/// A parameter name on the wire.
pub type ParamName = heapless::String<PARAM_NAME_LEN>;
/// A unit string on the wire.
pub type ParamUnit = heapless::String<PARAM_UNIT_LEN>;

/// The type of a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamKind {
    /// 32-bit float.
    F32,
    /// Unsigned integer (durations in µs, counts, enum choices).
    U32,
    /// Flag.
    Bool,
    /// Signed integer (calibration offsets).
    I32,
}

impl ParamKind {
    /// Lower-case name for tables and files.
    pub fn name(self) -> &'static str {
        match self {
            ParamKind::F32 => "f32",
            ParamKind::U32 => "u32",
            ParamKind::Bool => "bool",
            ParamKind::I32 => "i32",
        }
    }
}

/// A parameter's value, tagged with its kind.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamValue {
    /// A float.
    F32(f32),
    /// An unsigned integer.
    U32(u32),
    /// A flag.
    Bool(bool),
    /// A signed integer.
    I32(i32),
}

impl ParamValue {
    /// The value's kind.
    pub fn kind(self) -> ParamKind {
        match self {
            ParamValue::F32(_) => ParamKind::F32,
            ParamValue::U32(_) => ParamKind::U32,
            ParamValue::Bool(_) => ParamKind::Bool,
            ParamValue::I32(_) => ParamKind::I32,
        }
    }

    /// The 32 bits the flash record stores (f32 bit pattern, the integer (two's complement
    /// for a signed one), 0 / 1).
    pub fn to_bits(self) -> u32 {
        match self {
            ParamValue::F32(x) => x.to_bits(),
            ParamValue::U32(x) => x,
            ParamValue::Bool(b) => u32::from(b),
            ParamValue::I32(x) => u32::from_le_bytes(x.to_le_bytes()),
        }
    }

    /// The value of `kind` stored as `bits`; `None` for a flag other than 0 / 1.
    pub fn from_bits(kind: ParamKind, bits: u32) -> Option<Self> {
        match kind {
            ParamKind::F32 => Some(ParamValue::F32(f32::from_bits(bits))),
            ParamKind::U32 => Some(ParamValue::U32(bits)),
            ParamKind::Bool => match bits {
                0 => Some(ParamValue::Bool(false)),
                1 => Some(ParamValue::Bool(true)),
                _ => None,
            },
            ParamKind::I32 => Some(ParamValue::I32(i32::from_le_bytes(bits.to_le_bytes()))),
        }
    }
}

impl core::fmt::Display for ParamValue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamValue::F32(x) => write!(f, "{x}"),
            ParamValue::U32(x) => write!(f, "{x}"),
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::I32(x) => write!(f, "{x}"),
        }
    }
}

/// One entry of a board's parameter table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSpec {
    /// Name, `snake_case`, at most [`PARAM_NAME_LEN`] bytes (tested per table).
    pub name: &'static str,
    /// Kind of the value.
    pub kind: ParamKind,
    /// Unit (SI, `us` for microseconds, `-` for none), at most [`PARAM_UNIT_LEN`] bytes.
    pub unit: &'static str,
    /// Smallest accepted value (same kind; a flag's bounds are `false..=true`).
    pub min: ParamValue,
    /// Largest accepted value.
    pub max: ParamValue,
    /// False for a value the board shows but does not take at run time (fixed by hardware).
    pub writable: bool,
}

impl ParamSpec {
    /// Checks that `value` has this parameter's kind and lies within its bounds (a float must
    /// also be finite).
    pub fn check(&self, value: ParamValue) -> Result<(), ParamError> {
        if value.kind() != self.kind {
            return Err(ParamError::WrongKind);
        }
        let inside = match (value, self.min, self.max) {
            (ParamValue::F32(x), ParamValue::F32(lo), ParamValue::F32(hi)) => {
                x.is_finite() && x >= lo && x <= hi
            }
            (ParamValue::U32(x), ParamValue::U32(lo), ParamValue::U32(hi)) => x >= lo && x <= hi,
            (ParamValue::I32(x), ParamValue::I32(lo), ParamValue::I32(hi)) => x >= lo && x <= hi,
            (ParamValue::Bool(_), _, _) => true,
            _ => false,
        };
        if inside {
            Ok(())
        } else {
            Err(ParamError::OutOfBounds)
        }
    }
}

/// Index of the parameter called `name` in `table`.
pub fn find_param(table: &[ParamSpec], name: &str) -> Option<usize> {
    table.iter().position(|s| s.name == name)
}

/// FNV-1a hash of every name and kind of `table`, in order: the table version a flash record
/// is bound to (a renamed, retyped, added or moved parameter changes it).
pub const fn table_hash(table: &[ParamSpec]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    let mut i = 0;
    while i < table.len() {
        let name = table[i].name.as_bytes();
        let mut j = 0;
        while j < name.len() {
            h = (h ^ name[j] as u32).wrapping_mul(0x0100_0193);
            j += 1;
        }
        let kind = match table[i].kind {
            ParamKind::F32 => 1u32,
            ParamKind::U32 => 2,
            ParamKind::Bool => 3,
            ParamKind::I32 => 4,
        };
        // A separator and the kind after each name.
        h = (h ^ (0x100 | kind)).wrapping_mul(0x0100_0193);
        i += 1;
    }
    h
}

/// A configuration field's type, seen as a parameter value (`u8`..`u64` as [`ParamKind::U32`],
/// `i8`..`i32` as [`ParamKind::I32`]; a board implements it for its own enum choices).
pub trait ParamField: Sized + Copy {
    /// The field as a parameter value (an unsigned field above `u32::MAX` saturates).
    fn to_param(self) -> ParamValue;
    /// The field of value `v`; `None` for another kind or a value the field cannot hold.
    fn from_param(v: ParamValue) -> Option<Self>;
}

impl ParamField for f32 {
    fn to_param(self) -> ParamValue {
        ParamValue::F32(self)
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::F32(x) => Some(x),
            _ => None,
        }
    }
}

impl ParamField for bool {
    fn to_param(self) -> ParamValue {
        ParamValue::Bool(self)
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        match v {
            ParamValue::Bool(x) => Some(x),
            _ => None,
        }
    }
}

macro_rules! integer_field {
    ($variant:ident, $wide:ty, $sat:expr; $($t:ty),*) => {$(
        impl ParamField for $t {
            fn to_param(self) -> ParamValue {
                ParamValue::$variant(<$wide>::try_from(self).unwrap_or($sat))
            }
            fn from_param(v: ParamValue) -> Option<Self> {
                match v {
                    ParamValue::$variant(x) => <$t>::try_from(x).ok(),
                    _ => None,
                }
            }
        }
    )*};
}
integer_field!(U32, u32, u32::MAX; u8, u16, u32, u64);
integer_field!(I32, i32, i32::MAX; i8, i16, i32);

/// A duration is a [`ParamKind::U32`] of whole microseconds (above `u32::MAX` µs it saturates).
impl ParamField for timebase::Duration {
    fn to_param(self) -> ParamValue {
        self.as_micros().to_param()
    }
    fn from_param(v: ParamValue) -> Option<Self> {
        u64::from_param(v).map(Self::from_micros)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::params::fixtures::{CFG_SPECS, TABLE};

    #[test]
    fn signed_values_keep_their_sign_bounds_and_bits() {
        let spec = &CFG_SPECS[1];
        assert_eq!(spec.check(ParamValue::I32(-20)), Ok(()));
        assert_eq!(
            spec.check(ParamValue::I32(-21)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(spec.check(ParamValue::U32(3)), Err(ParamError::WrongKind));
        for x in [i32::MIN, -1, 0, 7, i32::MAX] {
            let v = ParamValue::I32(x);
            assert_eq!(ParamValue::from_bits(ParamKind::I32, v.to_bits()), Some(v));
        }
        // A narrow field refuses what it cannot hold instead of wrapping.
        assert_eq!(<i8 as ParamField>::from_param(ParamValue::I32(200)), None);
        assert_eq!(
            <i8 as ParamField>::from_param(ParamValue::I32(-7)),
            Some(-7)
        );
        assert_eq!(<u8 as ParamField>::from_param(ParamValue::I32(3)), None);
    }

    #[test]
    fn bounds_and_kinds_are_checked() {
        assert_eq!(TABLE[0].check(ParamValue::F32(2.0)), Ok(()));
        assert_eq!(
            TABLE[0].check(ParamValue::F32(2.01)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(
            TABLE[0].check(ParamValue::F32(f32::NAN)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(
            TABLE[0].check(ParamValue::U32(1)),
            Err(ParamError::WrongKind)
        );
        assert_eq!(
            TABLE[1].check(ParamValue::U32(9)),
            Err(ParamError::OutOfBounds)
        );
        assert_eq!(TABLE[2].check(ParamValue::Bool(false)), Ok(()));
    }

    #[test]
    fn the_table_hash_follows_names_kinds_and_order() {
        let h = table_hash(TABLE);
        let mut t = TABLE.to_vec();
        t.swap(0, 1);
        assert_ne!(table_hash(&t), h);
        let mut t = TABLE.to_vec();
        t[2].kind = ParamKind::U32;
        assert_ne!(table_hash(&t), h);
        let mut t = TABLE.to_vec();
        t[0].unit = "m";
        t[0].max = ParamValue::F32(9.0);
        assert_eq!(
            table_hash(&t),
            h,
            "units and bounds are not part of the layout"
        );
    }
}
