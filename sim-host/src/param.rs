//! Parameters: `sim-host param` (list, read, write and save a board's parameter table over its
//! telemetry link) and the parameter files `fly --params` reads.
//!
//! The link is the autopilot's telemetry port: a serial device or `tcp:HOST:PORT` (a virtual
//! board's `vboard serve autopilot`, a QEMU socket), the same ports `monitor` opens. One
//! request is in flight at a time; an answer that does not match it is skipped, and a request
//! with no answer within `--timeout` is sent again (twice) before the command fails.
//!
//! A parameter file is TOML with one table per board, keyed by the names
//! `sim-host param list` shows (and docs/parameters.md lists):
//!
//! ```toml
//! [autopilot]
//! guid_kp = 0.25
//! fsm_variant = 1          # turn until clear
//! fs_hover_land_us = 2000000
//! indi_adapt = false
//! ```
//!
//! An unknown board or name, a value of the wrong type, a value out of bounds or one that makes
//! the configuration inconsistent is an error naming the file, the key and the problem.

use crate::hil::{open_link, Link};
use anyhow::{anyhow, bail, Context as _};
use autopilot::app::AutopilotConfig;
use autopilot::params as ap_params;
use protocol::{
    BoardToHost, BoardToHostDecoder, HostToBoard, Message as _, Node, ParamEntry, ParamError,
    ParamKind, ParamName, ParamOp, ParamReply, ParamRequest, ParamValue,
};
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Which board's table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BoardArg {
    /// The autopilot (answers on its telemetry port).
    Autopilot,
    /// The camera board (through the autopilot).
    Camera,
}

impl BoardArg {
    fn node(self) -> Node {
        match self {
            BoardArg::Autopilot => Node::Autopilot,
            BoardArg::Camera => Node::StereoBoard,
        }
    }
}

/// Options of `sim-host param`.
#[derive(Debug, clap::Args)]
pub struct ParamArgs {
    /// The autopilot's telemetry port: a serial device (`/dev/ttyUSB0`, `COM3`) or
    /// `tcp:HOST:PORT`.
    #[arg(long)]
    pub port: String,
    /// Baud rate of a serial port.
    #[arg(long, default_value_t = autopilot::board::TELEMETRY_BAUD)]
    pub baud: u32,
    /// Whose table.
    #[arg(long, value_enum, default_value_t = BoardArg::Autopilot)]
    pub board: BoardArg,
    /// Seconds to wait for each answer.
    #[arg(long, default_value_t = 1.0)]
    pub timeout: f64,
    /// What to do.
    #[command(subcommand)]
    pub action: ParamAction,
}

/// `sim-host param` actions.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum ParamAction {
    /// Every parameter: name, value, unit, default, bounds.
    List,
    /// One parameter.
    Get {
        /// Its name.
        name: String,
    },
    /// Writes one parameter (refused while armed, out of bounds or of the wrong type).
    Set {
        /// Its name.
        name: String,
        /// The value: a number, or true / false.
        value: String,
    },
    /// Saves every value to the board's flash (refused while armed).
    Save,
}

/// A value as a user reads it.
pub fn format_value(v: ParamValue) -> String {
    v.to_string()
}

/// Parses `text` as a value of `kind`.
pub fn parse_value(kind: ParamKind, text: &str) -> Result<ParamValue, String> {
    let t = text.trim();
    match kind {
        ParamKind::F32 => t
            .parse::<f32>()
            .ok()
            .filter(|x| x.is_finite())
            .map(ParamValue::F32)
            .ok_or_else(|| format!("{t:?} is not a finite number (the parameter is an f32)")),
        ParamKind::U32 => t
            .parse::<u32>()
            .map(ParamValue::U32)
            .map_err(|_| format!("{t:?} is not a whole number >= 0 (the parameter is a u32)")),
        ParamKind::Bool => match t {
            "true" | "1" => Ok(ParamValue::Bool(true)),
            "false" | "0" => Ok(ParamValue::Bool(false)),
            _ => Err(format!(
                "{t:?} is not true or false (the parameter is a bool)"
            )),
        },
    }
}

/// One line of `list`.
pub fn format_entry(e: &ParamEntry) -> String {
    format!(
        "{:3} {:<24} {:>12} {:<8} default {:<10} [{} ..= {}]{}",
        e.index,
        e.name.as_str(),
        format_value(e.value),
        e.unit.as_str(),
        format_value(e.default),
        format_value(e.min),
        format_value(e.max),
        if e.writable { "" } else { " read-only" }
    )
}

/// A parameter session with one board over a telemetry link.
pub struct ParamClient {
    link: Box<dyn Link>,
    rx: mpsc::Receiver<Vec<u8>>,
    decoder: BoardToHostDecoder,
    board: Node,
    timeout: Duration,
    pending: std::collections::VecDeque<BoardToHost>,
}

impl ParamClient {
    /// Talks to `board` over `link`, waiting `timeout` for each answer.
    pub fn new(link: Box<dyn Link>, board: Node, timeout: Duration) -> anyhow::Result<Self> {
        let mut reader = link
            .try_clone_link()
            .context("cloning the link for reading")?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0u8; 1024];
            loop {
                match reader.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => {
                        if tx.send(buf[..n].to_vec()).is_err() {
                            return;
                        }
                    }
                    Err(e) if crate::hil::is_transient_read_error(&e) => {}
                    Err(_) => return,
                }
            }
        });
        Ok(Self {
            link,
            rx,
            decoder: BoardToHostDecoder::new(),
            board,
            timeout,
            pending: Default::default(),
        })
    }

    /// Opens `port` (serial at `baud`, or `tcp:HOST:PORT`).
    pub fn open(port: &str, baud: u32, board: Node, timeout: Duration) -> anyhow::Result<Self> {
        Self::new(open_link(port, baud)?, board, timeout)
    }

    fn send(&mut self, op: &ParamOp) -> anyhow::Result<()> {
        let msg = HostToBoard::Param(ParamRequest {
            board: self.board,
            op: op.clone(),
        });
        let frame = protocol::encode_to_vec::<_, { HostToBoard::MAX_FRAME_BYTES }>(&msg)
            .map_err(|e| anyhow!("encoding: {e:?}"))?;
        self.link.write_all(&frame).context("writing the request")?;
        self.link.flush().context("writing the request")
    }

    /// The next parameter answer, or `None` at the deadline.
    fn next_reply(&mut self, deadline: Instant) -> anyhow::Result<Option<ParamReply>> {
        loop {
            while let Some(m) = self.pending.pop_front() {
                if let BoardToHost::Param(r) = m {
                    if r.board == self.board {
                        return Ok(Some(r.reply));
                    }
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            match self.rx.recv_timeout(left) {
                Ok(bytes) => {
                    let pending = &mut self.pending;
                    self.decoder.feed(&bytes, |m| pending.push_back(m));
                }
                Err(mpsc::RecvTimeoutError::Timeout) => return Ok(None),
                Err(mpsc::RecvTimeoutError::Disconnected) => bail!("the link closed"),
            }
        }
    }

    /// Sends `op` and returns the answer that matches it (an entry for the index or name
    /// asked, an error, or `Saved` for a save), retrying twice on silence.
    pub fn request(&mut self, op: &ParamOp) -> anyhow::Result<ParamReply> {
        for _attempt in 0..3 {
            self.send(op)?;
            let deadline = Instant::now() + self.timeout;
            while let Some(reply) = self.next_reply(deadline)? {
                let matches = match (&reply, op) {
                    (ParamReply::Error(_), _) => true,
                    (ParamReply::Entry(e), ParamOp::List(i)) => e.index == *i,
                    (ParamReply::Entry(e), ParamOp::Get(n) | ParamOp::Set(n, _)) => e.name == *n,
                    (ParamReply::Saved, ParamOp::Save) => true,
                    _ => false,
                };
                if matches {
                    return Ok(reply);
                }
            }
        }
        bail!(
            "no answer from the {:?} to {op:?} after 3 tries of {:.1} s (is it running this \
             protocol version, {}?)",
            self.board,
            self.timeout.as_secs_f64(),
            protocol::PROTOCOL_VERSION
        )
    }

    fn entry(&mut self, op: &ParamOp, what: &str) -> anyhow::Result<ParamEntry> {
        match self.request(op)? {
            ParamReply::Entry(e) => Ok(e),
            ParamReply::Error(e) => bail!("{what}: {}", e.describe()),
            ParamReply::Saved => bail!("{what}: unexpected answer"),
        }
    }

    /// Every entry of the table, in order.
    pub fn list(&mut self) -> anyhow::Result<Vec<ParamEntry>> {
        let first = self.entry(&ParamOp::List(0), "parameter 0")?;
        let mut all = vec![first];
        for i in 1..all[0].count {
            all.push(self.entry(&ParamOp::List(i), &format!("parameter {i}"))?);
        }
        Ok(all)
    }

    /// The entry called `name`.
    pub fn get(&mut self, name: &str) -> anyhow::Result<ParamEntry> {
        let n = wire_name(name)?;
        self.entry(&ParamOp::Get(n), name)
    }

    /// Writes `name` (the text parsed as the parameter's kind); returns the entry now in use.
    pub fn set(&mut self, name: &str, value: &str) -> anyhow::Result<ParamEntry> {
        let current = self.get(name)?;
        let v = parse_value(current.value.kind(), value).map_err(|e| anyhow!("{name}: {e}"))?;
        self.set_value(name, v)
    }

    /// Writes `name` = `v`; returns the entry now in use.
    pub fn set_value(&mut self, name: &str, v: ParamValue) -> anyhow::Result<ParamEntry> {
        let n = wire_name(name)?;
        match self.request(&ParamOp::Set(n, v))? {
            ParamReply::Entry(e) => Ok(e),
            ParamReply::Error(ParamError::OutOfBounds) => {
                let e = self.get(name)?;
                bail!(
                    "{name}: {} is outside [{} ..= {}] {}",
                    format_value(v),
                    format_value(e.min),
                    format_value(e.max),
                    e.unit.as_str()
                )
            }
            ParamReply::Error(e) => bail!("{name}: {}", e.describe()),
            ParamReply::Saved => bail!("{name}: unexpected answer"),
        }
    }

    /// Saves the values to the board's flash.
    pub fn save(&mut self) -> anyhow::Result<()> {
        match self.request(&ParamOp::Save)? {
            ParamReply::Saved => Ok(()),
            ParamReply::Error(e) => bail!("save: {}", e.describe()),
            ParamReply::Entry(_) => bail!("save: unexpected answer"),
        }
    }
}

fn wire_name(name: &str) -> anyhow::Result<ParamName> {
    ParamName::try_from(name).map_err(|_| {
        anyhow!(
            "{name}: no parameter of that name (names are at most {} bytes)",
            protocol::params::PARAM_NAME_LEN
        )
    })
}

/// Runs `sim-host param`.
pub fn run(args: &ParamArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.timeout > 0.0 && args.timeout.is_finite(),
        "--timeout must be positive"
    );
    let mut c = ParamClient::open(
        &args.port,
        args.baud,
        args.board.node(),
        Duration::from_secs_f64(args.timeout),
    )?;
    match &args.action {
        ParamAction::List => {
            for e in c.list()? {
                println!("{}", format_entry(&e));
            }
        }
        ParamAction::Get { name } => println!("{}", format_entry(&c.get(name)?)),
        ParamAction::Set { name, value } => println!("{}", format_entry(&c.set(name, value)?)),
        ParamAction::Save => {
            c.save()?;
            println!("saved");
        }
    }
    Ok(())
}

/// The parameters a file sets, applied over the defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamFile {
    /// The autopilot's configuration.
    pub autopilot: AutopilotConfig,
    /// Whether the file set `fsm_variant` (which then wins over `fly --fsm`'s default).
    pub sets_fsm_variant: bool,
}

impl ParamFile {
    /// Reads `path` (see the module docs).
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading parameter file {}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses a parameter file's `text`; errors name `file`, the key and the problem.
    pub fn parse(text: &str, file: &str) -> anyhow::Result<Self> {
        let doc: toml::Table = toml::from_str(text).map_err(|e| anyhow!("{file}: {e}"))?;
        let mut autopilot = AutopilotConfig::default();
        let mut sets_fsm_variant = false;
        for (board, table) in &doc {
            let toml::Value::Table(table) = table else {
                bail!("{file}: `{board}` must be a table ([autopilot])");
            };
            match board.as_str() {
                "autopilot" => {}
                "camera" => bail!(
                    "{file}: [camera]: the camera board's parameters are not read from files yet \
                     (only [autopilot])"
                ),
                other => bail!("{file}: unknown board [{other}] (expected [autopilot])"),
            }
            for (key, value) in table {
                let at = |problem: String| anyhow!("{file}: [{board}] {key}: {problem}");
                let index = ap_params::index_of(key)
                    .ok_or_else(|| at("no such parameter (see `sim-host param list`)".into()))?;
                let spec = &ap_params::TABLE[index];
                let v = toml_value(spec.kind, value).map_err(at)?;
                ap_params::set(&mut autopilot, index, v).map_err(|r| at(r.to_string()))?;
                sets_fsm_variant |= key == "fsm_variant";
            }
        }
        Ok(Self {
            autopilot,
            sets_fsm_variant,
        })
    }
}

/// The autopilot's table as the markdown table docs/parameters.md holds (between its
/// `<!-- autopilot-table -->` markers; a test keeps the two equal).
pub fn autopilot_markdown_table() -> String {
    let d = AutopilotConfig::default();
    let mut out =
        String::from("| name | type | unit | default | min | max |\n|---|---|---|---|---|---|\n");
    for (i, s) in ap_params::TABLE.iter().enumerate() {
        let default = ap_params::get(&d, i).map_or(String::new(), format_value);
        out.push_str(&format!(
            "| `{}`{} | {} | {} | {} | {} | {} |\n",
            s.name,
            if s.writable { "" } else { " (read-only)" },
            s.kind.name(),
            s.unit,
            default,
            format_value(s.min),
            format_value(s.max)
        ));
    }
    out
}

fn toml_value(kind: ParamKind, v: &toml::Value) -> Result<ParamValue, String> {
    match (kind, v) {
        (ParamKind::F32, toml::Value::Float(x)) => Ok(ParamValue::F32(*x as f32)),
        (ParamKind::F32, toml::Value::Integer(x)) => Ok(ParamValue::F32(*x as f32)),
        (ParamKind::U32, toml::Value::Integer(x)) => u32::try_from(*x)
            .map(ParamValue::U32)
            .map_err(|_| format!("{x} is not a u32 (0 ..= {})", u32::MAX)),
        (ParamKind::Bool, toml::Value::Boolean(b)) => Ok(ParamValue::Bool(*b)),
        (kind, other) => Err(format!(
            "expected a {} value, got {} ({other})",
            kind.name(),
            other.type_str()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use autopilot::fsm::FsmVariant;

    #[test]
    fn a_file_sets_the_named_fields() {
        let f = ParamFile::parse(
            "[autopilot]\nguid_kp = 0.25\nfsm_variant = 1\nindi_adapt = false\nff_gain = 2\n",
            "p.toml",
        )
        .unwrap();
        assert_eq!(f.autopilot.guidance.kp, 0.25);
        assert_eq!(f.autopilot.fsm.variant, FsmVariant::TurnUntilClear);
        assert!(!f.autopilot.indi.adapt);
        assert_eq!(f.autopilot.force_field.gain, 2.0);
        assert!(f.sets_fsm_variant);
        let empty = ParamFile::parse("", "p.toml").unwrap();
        assert_eq!(empty.autopilot, AutopilotConfig::default());
    }

    #[test]
    fn file_errors_name_the_file_key_and_problem() {
        let err = |text: &str| ParamFile::parse(text, "p.toml").unwrap_err().to_string();
        let e = err("[autopilot]\nguid_kq = 0.25\n");
        assert!(
            e.contains("p.toml") && e.contains("guid_kq") && e.contains("no such"),
            "{e}"
        );
        let e = err("[autopilot]\nguid_kp = true\n");
        assert!(e.contains("guid_kp") && e.contains("expected a f32"), "{e}");
        let e = err("[autopilot]\nfs_imu_timeout_us = -5\n");
        assert!(
            e.contains("fs_imu_timeout_us") && e.contains("not a u32"),
            "{e}"
        );
        let e = err("[autopilot]\ntarget_height = 9.0\n");
        assert!(e.contains("target_height") && e.contains("outside"), "{e}");
        let e = err("[autopilot]\nindi_rate_hz = 400.0\n");
        assert!(e.contains("read-only"), "{e}");
        let e = err("[autopilot]\nheight_hover_thrust = 0.1\n");
        assert!(e.contains("inconsistent"), "{e}");
        let e = err("[autopilto]\nguid_kp = 0.2\n");
        assert!(e.contains("unknown board"), "{e}");
        let e = err("guid_kp = 0.2\n");
        assert!(e.contains("must be a table"), "{e}");
    }

    #[test]
    fn the_docs_list_the_table() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/parameters.md");
        let docs = std::fs::read_to_string(path).unwrap();
        let marker = "<!-- autopilot-table -->\n";
        let table = docs.split(marker).nth(1).unwrap_or("");
        let want = autopilot_markdown_table();
        if table != want {
            let gen = std::env::temp_dir().join("autopilot-parameters.md");
            std::fs::write(&gen, &want).unwrap();
            panic!(
                "docs/parameters.md's table differs from autopilot::params::TABLE: paste {} between its markers",
                gen.display()
            );
        }
    }

    #[test]
    fn values_parse_by_kind() {
        assert_eq!(parse_value(ParamKind::F32, "0.5"), Ok(ParamValue::F32(0.5)));
        assert!(parse_value(ParamKind::F32, "nan").is_err());
        assert_eq!(parse_value(ParamKind::U32, "7"), Ok(ParamValue::U32(7)));
        assert!(parse_value(ParamKind::U32, "-7").is_err());
        assert_eq!(
            parse_value(ParamKind::Bool, "true"),
            Ok(ParamValue::Bool(true))
        );
        assert!(parse_value(ParamKind::Bool, "yes").is_err());
    }
}
