//! Named, typed parameters: the table a board publishes, the messages that list, read, write
//! and save them, and the flash record they are saved in.
//!
//! Each board has one const table of [`ParamSpec`]s (name, kind, unit, bounds, writable); its
//! values live in the board's configuration struct. A host lists the table entry by entry
//! ([`ParamOp::List`] with an index, answered with a [`ParamEntry`] that carries the count),
//! reads and writes by name (names survive a reordered table; indices need not), and asks for a
//! save. Every request is answered with one [`ParamResponse`].
//!
//! The flash record ([`encode_record`], [`decode_record`]) holds the values in table order
//! behind a magic, a format version, the table's [`table_hash`] (names and kinds) and a save
//! sequence number, closed by a CRC-32: a blank, corrupt, older-format or other-table record
//! decodes to an error. A board with a host link key saves it in every record
//! ([`ParamStorage::key`], format [`RECORD_FORMAT_KEYED`]: the [`KeyRecord`] before the CRC);
//! records without one keep format [`RECORD_FORMAT_VERSION`] and load as before. The key is
//! read back with [`ParamTable::load_link_key`], and put beside the saved configuration
//! without saving the one in use with [`ParamTable::save_link_key`] (the board, for a key
//! provisioned over its link) or [`ParamTable::record_with_key`] (the SWD flashing tool). A board's storage is a [`RecordStore`] (its flash sectors in the
//! firmware, a [`MemStore`] or [`MemSlots`] on the host) of one or two separately erased
//! slots. [`ParamTable::load`] reads every slot at boot and takes the good record with the
//! highest sequence number; [`ParamTable::save`] writes the next number into the slot that
//! does not hold it and reads it back, so with two slots a power loss at any point of a save
//! leaves the last complete record to boot on. A board whose boot found no good record (other
//! than a blank store) runs on its defaults and reports why; [`StorageStatus::blocks_arming`]
//! holds until a save succeeds or the failure is acknowledged ([`ParamOp::Acknowledge`]).
//! [`ParamOp::Storage`] reports what the boot loaded and the saves since.
//!
//! The files: `value` (kinds, values, specs, [`ParamField`]), `table` ([`ParamAccess`], the
//! [`crate::param_table!`] macro, [`ParamTable`]), `wire` (the request and reply messages),
//! `error` ([`ParamError`]), `store` ([`RecordStore`], [`ParamStorage`]) and `record` (the
//! flash record format).
//!
//! [`KeyRecord`]: crate::envelope::KeyRecord

mod error;
#[cfg(test)]
mod fixtures;
mod record;
mod store;
mod table;
mod value;
mod wire;

pub use error::ParamError;
pub use record::{
    decode_record, encode_record, record_bytes, record_link_key, record_sequence, KeySaveError,
    RecordError, MAX_PARAMS, MAX_RECORD_BYTES, RECORD_FORMAT_KEYED, RECORD_FORMAT_VERSION,
    RECORD_HEADER_BYTES, RECORD_MAGIC,
};
pub use store::{MemSlots, MemStore, ParamStorage, RecordStore, StorageStatus};
pub use table::{Conflict, ParamAccess, ParamTable, Rejected};
pub use value::{
    find_param, table_hash, ParamField, ParamKind, ParamName, ParamSpec, ParamUnit, ParamValue,
    PARAM_NAME_LEN, PARAM_UNIT_LEN,
};
pub use wire::{ParamEntry, ParamOp, ParamReply, ParamRequest, ParamResponse};
