//! `sim-host key`: the host link's key file, and signing for every tool that sends commands.
//!
//! A key file holds the 32-byte link key as 64 hexadecimal digits (one line), readable by its
//! owner only. `key new FILE` makes one from the operating system's random source; `key
//! provision` sends it to an autopilot that has no key yet (unsigned `SetKey`, accepted only
//! disarmed and keyless) or, with `--old-key`, signed with the key it has; the board saves it
//! in its parameter flash. Over SWD, `cargo xtask flash autopilot --key FILE` writes it there.
//! `monitor`, `param` and `hil` take `--key FILE` and then sign every message they send
//! ([`HostSigner`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, bail, Context};
use protocol::signing::{timestamp_from_unix_us, LinkKey, Signer, KEY_BYTES};
use protocol::{BoardToHost, Decoder, HostToBoard, Message as _};

/// `sim-host key` arguments.
#[derive(Debug, clap::Args)]
pub struct KeyArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: KeyAction,
}

/// `sim-host key` actions.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum KeyAction {
    /// Writes a new random key to FILE (mode 0600; an existing file is not overwritten).
    New {
        /// The key file to create.
        file: PathBuf,
    },
    /// Sends the key to the autopilot over its telemetry link and waits for its telemetry to
    /// report a keyed link.
    Provision {
        /// The autopilot's telemetry port: a serial device or `tcp:HOST:PORT`.
        #[arg(long)]
        port: String,
        /// Baud rate of a serial port.
        #[arg(long, default_value_t = autopilot::board::TELEMETRY_BAUD)]
        baud: u32,
        /// The key file to provision.
        #[arg(long)]
        key: PathBuf,
        /// The key the board has now, to sign the change with (a board with a key takes a
        /// new one only signed with it).
        #[arg(long)]
        old_key: Option<PathBuf>,
        /// Seconds to wait for the board to report the key.
        #[arg(long, default_value_t = 3.0)]
        timeout: f64,
    },
}

/// Runs `sim-host key`.
pub fn run(args: &KeyArgs) -> anyhow::Result<()> {
    match &args.action {
        KeyAction::New { file } => {
            new_key_file(file)?;
            println!("wrote a new link key to {}", file.display());
            Ok(())
        }
        KeyAction::Provision {
            port,
            baud,
            key,
            old_key,
            timeout,
        } => provision(port, *baud, key, old_key.as_deref(), *timeout),
    }
}

/// Creates `file` holding a new random key, readable and writable by its owner only.
pub fn new_key_file(file: &Path) -> anyhow::Result<LinkKey> {
    let mut key = [0u8; KEY_BYTES];
    rand::Rng::fill(&mut rand::rng(), &mut key[..]);
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut f = options
        .open(file)
        .with_context(|| format!("creating the key file {}", file.display()))?;
    writeln!(f, "{}", to_hex(&key))
        .with_context(|| format!("writing the key file {}", file.display()))?;
    Ok(LinkKey(key))
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Reads a key file: 64 hexadecimal digits, surrounding white space ignored.
pub fn load_key(file: &Path) -> anyhow::Result<LinkKey> {
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("reading the key file {}", file.display()))?;
    parse_key(&text).with_context(|| format!("the key file {} is not a link key", file.display()))
}

fn parse_key(text: &str) -> anyhow::Result<LinkKey> {
    LinkKey::from_hex(text).map_err(|e| anyhow!("{e}"))
}

/// The signing clock now: 10 µs units since 2015-01-01 UTC.
pub fn now_timestamp() -> u64 {
    let unix_us = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64);
    timestamp_from_unix_us(unix_us)
}

/// What a host tool does to each message it sends: nothing without a key, sign with one.
#[derive(Debug, Clone, Default)]
pub struct HostSigner {
    signer: Option<Signer>,
}

impl HostSigner {
    /// A signer for the key in `file` (none: messages go unsigned). `link_id` tells the host
    /// tools apart on the board's replay guard.
    pub fn from_file(file: Option<&Path>, link_id: u8) -> anyhow::Result<Self> {
        Ok(Self {
            signer: file
                .map(load_key)
                .transpose()?
                .map(|k| Signer::new(k, link_id)),
        })
    }

    /// A signer with `key`.
    pub fn with_key(key: LinkKey, link_id: u8) -> Self {
        Self {
            signer: Some(Signer::new(key, link_id)),
        }
    }

    /// `msg` as it goes on the wire: signed at the wall clock when there is a key.
    pub fn wrap(&mut self, msg: HostToBoard) -> anyhow::Result<HostToBoard> {
        match &mut self.signer {
            Some(s) => s
                .sign(&msg, now_timestamp())
                .map_err(|e| anyhow!("signing: {e}")),
            None => Ok(msg),
        }
    }

    /// `msg` signed (if keyed) and framed.
    pub fn frame(&mut self, msg: HostToBoard) -> anyhow::Result<Vec<u8>> {
        let msg = self.wrap(msg)?;
        let frame = protocol::encode_to_vec::<_, { HostToBoard::MAX_FRAME_BYTES }>(&msg)
            .map_err(|e| anyhow!("encoding: {e:?}"))?;
        Ok(frame.to_vec())
    }
}

/// Link ids of the host tools (any value works; distinct ones keep their replay checks apart).
pub mod link_id {
    /// `sim-host monitor`.
    pub const MONITOR: u8 = 1;
    /// `sim-host param`.
    pub const PARAM: u8 = 2;
    /// `sim-host hil`.
    pub const HIL: u8 = 3;
    /// `sim-host key provision`.
    pub const PROVISION: u8 = 4;
}

fn provision(
    port: &str,
    baud: u32,
    key_file: &Path,
    old_key: Option<&Path>,
    timeout_s: f64,
) -> anyhow::Result<()> {
    let key = load_key(key_file)?;
    let mut signer = HostSigner::from_file(old_key, link_id::PROVISION)?;
    let mut link = crate::transport::open_link(port, baud)?;
    let frame = signer.frame(HostToBoard::SetKey(key))?;
    link.write_all(&frame)
        .with_context(|| format!("writing the key to {port}"))?;
    link.flush()
        .with_context(|| format!("writing the key to {port}"))?;
    let mut decoder = Decoder::<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>::new();
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.max(0.1));
    let mut buf = [0u8; 256];
    while Instant::now() < deadline {
        let n = match link.read(&mut buf) {
            Ok(0) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(e) => return Err(e).with_context(|| format!("reading {port}")),
        };
        for &byte in buf.get(..n).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = decoder.push(byte) {
                if t.link_auth.keyed {
                    println!(
                        "the autopilot reports a keyed link ({} commands refused unsigned)",
                        t.link_auth.unsigned
                    );
                    return Ok(());
                }
            }
        }
    }
    bail!(
        "the autopilot on {port} did not report a keyed link within {timeout_s} s: it refuses a \
         key while armed, and an unsigned key once it has one (pass --old-key)"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_key_file_reads_back_and_is_private() {
        let dir = std::env::temp_dir().join(format!("key-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("link.key");
        let _ = std::fs::remove_file(&file);
        let key = new_key_file(&file).unwrap();
        assert_eq!(load_key(&file).unwrap(), key);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&file).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600);
        }
        assert!(
            new_key_file(&file).is_err(),
            "an existing key is not overwritten"
        );
        let other = dir.join("other.key");
        let _ = std::fs::remove_file(&other);
        assert_ne!(new_key_file(&other).unwrap(), key, "random keys");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_missing_or_malformed_key_file_is_named_in_the_error() {
        let missing = Path::new("/nonexistent/dir/link.key");
        let e = format!("{:#}", load_key(missing).unwrap_err());
        assert!(e.contains("/nonexistent/dir/link.key"), "{e}");
        let dir = std::env::temp_dir().join(format!("key-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bad = dir.join("bad.key");
        std::fs::write(&bad, "zz".repeat(32)).unwrap();
        let e = format!("{:#}", load_key(&bad).unwrap_err());
        assert!(
            e.contains("bad.key") && e.contains("not hexadecimal"),
            "{e}"
        );
        std::fs::write(&bad, "ab").unwrap();
        let e = format!("{:#}", load_key(&bad).unwrap_err());
        assert!(e.contains("64 hexadecimal digits"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
