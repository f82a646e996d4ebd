//! `cargo xtask flash autopilot --key FILE`: the host link key into the autopilot's parameter
//! flash over SWD, every saved parameter kept.
//!
//! The board keeps its parameters in two flash slots, each holding one record with a sequence
//! number (`board_support::param_flash`, `protocol::params`). The key goes into the record
//! beside them: [`key_write`] takes the newest good record of the slots as read (the
//! autopilot library's own decode, `autopilot::params::record_with_key`; the defaults on
//! erased flash), puts the key in, numbers the record one after it and aims it at the other
//! slot, so the record the board booted on stays whole until the new one is. A board whose
//! slots hold only bad records (corrupt, or of another parameter table) is refused: writing the
//! defaults there would hide the loss the firmware reports. [`key_write`], [`load_key_file`]
//! and [`parse_read_output`] are tested here.
//!
//! The probe-rs calls around them ([`read_slots`], [`program`]) need a board and are not
//! tested: `probe-rs read b8` prints the slots' first bytes, `probe-rs download
//! --binary-format bin --base-address A --verify` erases the one sector it writes, programs
//! the record and reads it back.

use anyhow::{anyhow, bail, Context, Result};
use protocol::params::{ParamError, RecordStore, MAX_RECORD_BYTES};
use protocol::signing::{KeyRecord, LinkKey};
use std::path::Path;
use std::process::Command;

/// First addresses of the autopilot's parameter slots, slot 0 first (sectors 11 and 10;
/// `board_support::param_flash::SLOTS`, which builds for the board only).
pub const SLOT_ADDRESSES: [u32; 2] = [0x080E_0000, 0x080C_0000];

/// Bytes read from the start of each slot: the longest record a board can hold.
pub const READ_BYTES: usize = MAX_RECORD_BYTES;

/// A record to program and where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeyWrite {
    /// The slot it goes to (0 or 1).
    pub slot: usize,
    /// The slot's first address.
    pub address: u32,
    /// The record's sequence number.
    pub sequence: u32,
    /// The record (parameters and key).
    pub record: Vec<u8>,
}

/// The two slots as read over SWD: read-only.
struct SlotImages<'a>([&'a [u8]; 2]);

impl RecordStore for SlotImages<'_> {
    fn bytes(&self) -> &[u8] {
        self.0[0]
    }

    fn write(&mut self, _record: &[u8]) -> Result<(), ParamError> {
        Err(ParamError::SaveFailed)
    }

    fn slots(&self) -> usize {
        2
    }

    fn slot(&self, slot: usize) -> &[u8] {
        self.0.get(slot).copied().unwrap_or(&[])
    }
}

/// Reads a key file (`sim-host key new`: 64 hexadecimal digits); an error names the file.
pub fn load_key_file(path: &Path) -> Result<LinkKey> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the key file {}", path.display()))?;
    LinkKey::from_hex(&text)
        .map_err(|e| anyhow!("the key file {} is not a link key: {e}", path.display()))
}

/// The record that puts `key` (replay floor `min_timestamp`, signing-clock units) into the
/// slots as read (`slots[0]` from [`SLOT_ADDRESSES`]`[0]`, each at least the record's length).
pub fn key_write(key: LinkKey, slots: [&[u8]; 2], min_timestamp: u64) -> Result<KeyWrite> {
    let record = KeyRecord { key, min_timestamp };
    let images = SlotImages(slots);
    let mut out = vec![0u8; MAX_RECORD_BYTES];
    let (slot, n) =
        autopilot::params::record_with_key(&images, &record, &mut out).map_err(|e| {
            let why = |i: usize| autopilot::params::decode_record(slots[i]).1;
            anyhow!(
                "no parameter record on the board to keep ({e:?}; slot 0: {:?}, slot 1: {:?}): \
             boot the firmware, save its parameters (`sim-host param save`) or erase both \
             parameter sectors, then flash the key",
                why(0),
                why(1)
            )
        })?;
    out.truncate(n);
    Ok(KeyWrite {
        slot,
        address: SLOT_ADDRESSES[slot],
        sequence: protocol::params::record_sequence(&out).unwrap_or(0),
        record: out,
    })
}

/// The bytes `probe-rs read b8 ADDRESS N` printed: hexadecimal bytes separated by white
/// space; exactly `expected` of them.
pub fn parse_read_output(text: &str, expected: usize) -> Result<Vec<u8>> {
    let bytes = text
        .split_whitespace()
        .map(|t| u8::from_str_radix(t, 16).map_err(|_| anyhow!("{t:?} is not a byte")))
        .collect::<Result<Vec<u8>>>()
        .context("reading probe-rs read's output")?;
    if bytes.len() != expected {
        bail!(
            "probe-rs read printed {} bytes, {expected} expected",
            bytes.len()
        );
    }
    Ok(bytes)
}

/// Reads the first [`READ_BYTES`] of both slots of the board on the probe.
pub fn read_slots(chip: &str) -> Result<[Vec<u8>; 2]> {
    let read = |address: u32| -> Result<Vec<u8>> {
        let out = Command::new("probe-rs")
            .args(["read", "--chip", chip, "b8"])
            .arg(format!("{address:#010x}"))
            .arg(READ_BYTES.to_string())
            .output()
            .context("starting probe-rs (cargo install probe-rs-tools --locked)")?;
        if !out.status.success() {
            bail!(
                "probe-rs read at {address:#010x} failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        parse_read_output(&String::from_utf8_lossy(&out.stdout), READ_BYTES)
    };
    Ok([read(SLOT_ADDRESSES[0])?, read(SLOT_ADDRESSES[1])?])
}

/// Programs `write` into its slot (the sector erased first) and verifies it. The record holds
/// the key: its file is private and removed afterwards.
pub fn program(chip: &str, write: &KeyWrite) -> Result<()> {
    let file = std::env::temp_dir().join(format!("pocket-drone-key-{}.bin", std::process::id()));
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let written = options
        .open(&file)
        .and_then(|mut f| std::io::Write::write_all(&mut f, &write.record))
        .with_context(|| format!("writing {}", file.display()));
    let status = written.and_then(|()| {
        Command::new("probe-rs")
            .args(["download", "--chip", chip, "--binary-format", "bin"])
            .arg("--base-address")
            .arg(format!("{:#010x}", write.address))
            .arg("--verify")
            .arg(&file)
            .status()
            .context("starting probe-rs download")
    });
    let _ = std::fs::remove_file(&file);
    let status = status?;
    if !status.success() {
        bail!("probe-rs download failed with {status}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use autopilot::params::{self, set_by_name};
    use autopilot::AutopilotConfig;
    use protocol::params::{
        record_link_key, record_sequence, MemSlots, ParamReply, ParamStorage, ParamValue,
        RecordError, StorageStatus,
    };

    const KEY: LinkKey = LinkKey([0xA5; 32]);

    fn erased() -> Vec<u8> {
        vec![0xff; READ_BYTES]
    }

    /// Both slots after the board saved `saves` in turn (its own save path).
    fn board_after(saves: &[AutopilotConfig]) -> [Vec<u8>; 2] {
        let mut store = MemSlots::<READ_BYTES>::blank();
        let mut status = StorageStatus::booted(Err(RecordError::Blank));
        for cfg in saves {
            let storage = ParamStorage::of(Some(&mut store), Some(&mut status)).unwrap();
            assert_eq!(params::AUTOPILOT.save(cfg, storage), ParamReply::Saved);
        }
        store.bytes.map(|b| b.to_vec())
    }

    fn tuned() -> AutopilotConfig {
        let mut c = AutopilotConfig::default();
        set_by_name(&mut c, "guid_kp", ParamValue::F32(0.3)).unwrap();
        set_by_name(&mut c, "fs_host_action", ParamValue::U32(1)).unwrap();
        c
    }

    #[test]
    fn the_key_joins_every_saved_parameter_in_the_other_slot() {
        // Five saves: slot 0 holds the newest record (5, tuned), slot 1 an older one (4).
        let d = AutopilotConfig::default();
        let [newest, older] = board_after(&[d, d, d, d, tuned()]);
        assert_eq!(record_sequence(&newest), Some(5));
        let w = key_write(KEY, [&newest, &older], 777).unwrap();
        assert_eq!((w.slot, w.address, w.sequence), (1, 0x080C_0000, 6));
        assert_eq!(record_sequence(&w.record), Some(6));
        assert_eq!(params::decode_record(&w.record), (tuned(), Ok(())));
        let key = record_link_key(&w.record).unwrap().unwrap();
        assert_eq!((key.key, key.min_timestamp), (KEY, 777));
        // The board then boots on it: every parameter and the key.
        let mut after = w.record.clone();
        after.resize(READ_BYTES, 0xff);
        let (ap, loaded) = autopilot::Autopilot::from_store(&SlotImages([&newest, &after]));
        assert_eq!((ap.config(), loaded), (&tuned(), Ok(())));
        assert!(ap.link_keyed());
        // With the newest in slot 1, the key goes to slot 0.
        let [older, newest] = board_after(&[d, tuned()]);
        let w = key_write(KEY, [&older, &newest], 1).unwrap();
        assert_eq!((w.slot, w.address, w.sequence), (0, 0x080E_0000, 3));
        assert_eq!(params::decode_record(&w.record).0, tuned());
    }

    #[test]
    fn erased_flash_gets_the_defaults_and_the_key() {
        let w = key_write(KEY, [&erased(), &erased()], 9).unwrap();
        assert_eq!((w.slot, w.sequence), (0, 1));
        assert_eq!(
            w.record.len(),
            params::RECORD_BYTES + protocol::signing::KEY_RECORD_BYTES
        );
        assert_eq!(
            params::decode_record(&w.record),
            (AutopilotConfig::default(), Ok(()))
        );
        assert_eq!(
            record_link_key(&w.record).unwrap().map(|k| k.key),
            Some(KEY)
        );
    }

    #[test]
    fn slots_of_bad_records_only_are_refused_with_why() {
        let [mut corrupt, _] = board_after(&[tuned()]);
        corrupt[40] ^= 0x01;
        let e = format!(
            "{:#}",
            key_write(KEY, [&corrupt, &erased()], 1).unwrap_err()
        );
        assert!(
            e.contains("BadCrc") && e.contains("slot 1: Err(Blank)"),
            "{e}"
        );
        // A good record beside a corrupt one is the one kept.
        let [mut corrupt, good] = board_after(&[AutopilotConfig::default(), tuned()]);
        corrupt[40] ^= 0x01;
        let w = key_write(KEY, [&corrupt, &good], 1).unwrap();
        assert_eq!((w.slot, w.sequence), (0, 3));
        assert_eq!(params::decode_record(&w.record).0, tuned());
    }

    #[test]
    fn a_malformed_or_missing_key_file_is_refused_naming_it() {
        let dir = std::env::temp_dir().join(format!("xtask-key-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bad = dir.join("short.key");
        std::fs::write(&bad, "abcd\n").unwrap();
        let e = format!("{:#}", load_key_file(&bad).unwrap_err());
        assert!(
            e.contains("short.key") && e.contains("64 hexadecimal digits"),
            "{e}"
        );
        let good = dir.join("good.key");
        std::fs::write(&good, format!("{}\n", "a5".repeat(32))).unwrap();
        assert_eq!(load_key_file(&good).unwrap(), KEY);
        let missing = dir.join("missing.key");
        let e = format!("{:#}", load_key_file(&missing).unwrap_err());
        assert!(e.contains("missing.key"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn probe_rs_read_output_is_parsed_and_counted() {
        assert_eq!(
            parse_read_output("ff 00 1a\n", 3).unwrap(),
            vec![0xff, 0x00, 0x1a]
        );
        assert!(parse_read_output("ff 00", 3).is_err());
        assert!(parse_read_output("ff zz 00", 3).is_err());
    }
}
