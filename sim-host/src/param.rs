//! Parameters: `sim-host param` (list, read, write and save a board's parameter table over its
//! telemetry link) and the parameter files `fly --params` reads.
//!
//! The link is the autopilot's telemetry port (it passes the camera board's requests on): a serial device or `tcp:HOST:PORT` (a virtual
//! board's `vboard serve autopilot`, a QEMU socket), the same ports `monitor` opens. The first
//! request waits for the autopilot's telemetry (a board still booting would lose it). One
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
//!
//! [camera]
//! stereo_shift = -2        # the camera pair's calibration, px
//! ```
//!
//! An unknown board or name, a value of the wrong type, a value out of bounds or one that makes
//! the configuration inconsistent is an error naming the file, the key and the problem.

use crate::transport::{open_link, Link};
use anyhow::{anyhow, bail, Context as _};
use autopilot::params as ap_params;
use autopilot::AutopilotConfig;
use protocol::params::{ParamTable, RecordError, StorageStatus};
use protocol::{
    BoardToHost, BoardToHostDecoder, HostToBoard, Node, ParamEntry, ParamError, ParamKind,
    ParamName, ParamOp, ParamReply, ParamRequest, ParamValue,
};
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use stereo_board::edge_fs::EdgeFsParams;
use stereo_board::params as cam_params;

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
    /// The link key file (`sim-host key new`): requests and heartbeats are signed with it.
    #[arg(long)]
    pub key: Option<std::path::PathBuf>,
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
        /// The value: a number (negative ones too: `set stereo_shift -4`), or true / false.
        #[arg(allow_negative_numbers = true)]
        value: String,
    },
    /// Saves every value to the board's flash (refused while armed). The board stalls for the
    /// flash's erase, a second or two: the answer is waited for at least 5 s.
    Save,
    /// What the board's parameter storage holds: whether the boot loaded a saved record (or
    /// why it runs on the defaults), and the saves since.
    Storage,
    /// Accepts that the boot could not load the saved record, so that the board arms on the
    /// defaults in use (a failed load blocks arming until then, or until a save succeeds).
    Ack,
}

/// The shortest wait for the answer to a save: the erase of a 128 KiB flash sector takes up
/// to 2 s (x32), during which the board answers nothing.
pub const SAVE_TIMEOUT: Duration = Duration::from_secs(5);

/// A storage status as a user reads it.
pub fn format_storage(s: &StorageStatus) -> String {
    let loaded = match s.loaded {
        Ok(()) => "the saved parameters are in use".to_owned(),
        Err(e) => format!("defaults in use: {}", describe_record_error(e)),
    };
    let blocked = if s.blocks_arming() {
        "; arming blocked until `ack` or a save"
    } else if s.acknowledged {
        "; acknowledged"
    } else {
        ""
    };
    format!(
        "{loaded}; saves since boot: {}, failed: {}{blocked}",
        s.saves, s.failed_saves
    )
}

/// Why a flash record was not loaded, for a user.
pub fn describe_record_error(e: RecordError) -> String {
    match e {
        RecordError::Blank => "nothing saved (erased flash)".to_owned(),
        RecordError::BadMagic => "the flash holds no parameter record".to_owned(),
        RecordError::FormatVersion(v) => format!("record of another format (version {v})"),
        RecordError::TableChanged => {
            "record of another parameter table (names or types changed)".to_owned()
        }
        RecordError::Length => "record cut short".to_owned(),
        RecordError::BadCrc => "corrupt record (bad CRC)".to_owned(),
        RecordError::BadValue(i) => format!("stored value {i} out of bounds or inconsistent"),
    }
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
        ParamKind::I32 => t
            .parse::<i32>()
            .map(ParamValue::I32)
            .map_err(|_| format!("{t:?} is not a whole number (the parameter is an i32)")),
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

/// Where a [`ParamClient`] gets the board's decoded messages: the next one within the
/// wait it is given, `Ok(None)` on silence, `Err` once the link closed.
pub type MessageSource<'a> =
    Box<dyn FnMut(Duration) -> Result<Option<BoardToHost>, LinkClosed> + 'a>;

/// The board's link closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkClosed;

/// A parameter session with one board over a telemetry link.
pub struct ParamClient<'a> {
    out: Box<dyn std::io::Write + 'a>,
    source: MessageSource<'a>,
    board: Node,
    timeout: Duration,
    /// When the session began (the heartbeat's uptime counts from it).
    started: Instant,
    /// When the last host heartbeat was sent (`None`: none yet).
    last_heartbeat: Option<Instant>,
    /// Signs what is sent when the host has the link key.
    signer: crate::key::HostSigner,
}

/// How often a host tool sends its heartbeat: the autopilot's heartbeat rate (its host
/// timeout, `fs_host_timeout_us`, is several of these).
pub const HOST_HEARTBEAT_PERIOD: Duration =
    Duration::from_micros(autopilot::tasks::HEARTBEAT_PERIOD.as_micros());

impl ParamClient<'static> {
    /// Talks to `board` over `link`, waiting `timeout` for each answer.
    pub fn new(link: Box<dyn Link>, board: Node, timeout: Duration) -> anyhow::Result<Self> {
        let mut reader = link
            .try_clone_link()
            .context("cloning the link for reading")?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0u8; 1024];
            let mut decoder = BoardToHostDecoder::new();
            loop {
                match reader.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => {
                        let mut open = true;
                        decoder.feed(&buf[..n], |m| open &= tx.send(m).is_ok());
                        if !open {
                            return;
                        }
                    }
                    Err(e) if crate::transport::is_transient_read_error(&e) => {}
                    Err(_) => return,
                }
            }
        });
        let source: MessageSource<'static> = Box::new(move |wait| match rx.recv_timeout(wait) {
            Ok(m) => Ok(Some(m)),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(LinkClosed),
        });
        let mut client = ParamClient::with_source(Box::new(link), source, board, timeout);
        client.hear_the_board()?;
        Ok(client)
    }

    /// Waits, at most one timeout, for the autopilot's first message on the link (it streams
    /// telemetry from boot): a request sent to a board still booting would be lost, and only
    /// its retry, a timeout later, answered.
    fn hear_the_board(&mut self) -> anyhow::Result<()> {
        match (self.source)(self.timeout) {
            Ok(_) => Ok(()),
            Err(LinkClosed) => bail!("the link closed before the board sent anything"),
        }
    }

    /// Opens `port` (serial at `baud`, or `tcp:HOST:PORT`).
    pub fn open(port: &str, baud: u32, board: Node, timeout: Duration) -> anyhow::Result<Self> {
        Self::new(open_link(port, baud)?, board, timeout)
    }
}

impl<'a> ParamClient<'a> {
    /// Talks to `board`, writing requests to `out` and taking the board's messages from
    /// `source` (for a caller that already decodes the link, such as `hil`); messages other
    /// than this board's parameter answers are dropped.
    pub fn with_source(
        out: Box<dyn std::io::Write + 'a>,
        source: MessageSource<'a>,
        board: Node,
        timeout: Duration,
    ) -> Self {
        Self {
            out,
            source,
            board,
            timeout,
            started: Instant::now(),
            last_heartbeat: None,
            signer: crate::key::HostSigner::default(),
        }
    }

    /// Sends the host's heartbeat if one is due: the autopilot refuses to arm without it and
    /// counts a silent host as a lost telemetry link.
    fn keep_alive(&mut self) -> anyhow::Result<()> {
        if self
            .last_heartbeat
            .is_some_and(|t| t.elapsed() < HOST_HEARTBEAT_PERIOD)
        {
            return Ok(());
        }
        self.last_heartbeat = Some(Instant::now());
        let uptime_ms = self.started.elapsed().as_millis() as u32;
        let msg = HostToBoard::Heartbeat(protocol::Heartbeat::new(Node::Host, uptime_ms));
        let frame = self.signer.frame(msg)?;
        self.out
            .write_all(&frame)
            .context("writing the heartbeat")?;
        self.out.flush().context("writing the heartbeat")
    }

    /// Signs every request and heartbeat from now on (a board with a link key refuses
    /// unsigned writes and saves).
    pub fn sign_with(&mut self, signer: crate::key::HostSigner) {
        self.signer = signer;
    }

    fn send(&mut self, op: &ParamOp) -> anyhow::Result<()> {
        self.keep_alive()?;
        let msg = HostToBoard::Param(ParamRequest {
            board: self.board,
            op: op.clone(),
        });
        let frame = self.signer.frame(msg)?;
        self.out.write_all(&frame).context("writing the request")?;
        self.out.flush().context("writing the request")
    }

    /// The next parameter answer, or `None` at the deadline.
    fn next_reply(&mut self, deadline: Instant) -> anyhow::Result<Option<ParamReply>> {
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.keep_alive()?;
            match (self.source)(left.min(HOST_HEARTBEAT_PERIOD)) {
                Ok(Some(BoardToHost::Param(r))) if r.board == self.board => {
                    return Ok(Some(r.reply))
                }
                Ok(Some(_)) | Ok(None) => {}
                Err(LinkClosed) => bail!("the link closed"),
            }
        }
    }

    /// Sends `op` and returns the answer that matches it (an entry for the index or name
    /// asked, an error, or `Saved` for a save), retrying twice on silence.
    pub fn request(&mut self, op: &ParamOp) -> anyhow::Result<ParamReply> {
        let timeout = match op {
            ParamOp::Save => self.timeout.max(SAVE_TIMEOUT),
            _ => self.timeout,
        };
        for _attempt in 0..3 {
            self.send(op)?;
            let deadline = Instant::now() + timeout;
            while let Some(reply) = self.next_reply(deadline)? {
                let matches = match (&reply, op) {
                    (ParamReply::Error(_), _) => true,
                    (ParamReply::Entry(e), ParamOp::List(i)) => e.index == *i,
                    (ParamReply::Entry(e), ParamOp::Get(n) | ParamOp::Set(n, _)) => e.name == *n,
                    (ParamReply::Saved, ParamOp::Save) => true,
                    (ParamReply::Storage(_), ParamOp::Storage | ParamOp::Acknowledge) => true,
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
            timeout.as_secs_f64(),
            protocol::PROTOCOL_VERSION
        )
    }

    fn entry(&mut self, op: &ParamOp, what: &str) -> anyhow::Result<ParamEntry> {
        match self.request(op)? {
            ParamReply::Entry(e) => Ok(e),
            ParamReply::Error(e) => bail!("{what}: {}", e.describe()),
            ParamReply::Saved | ParamReply::Storage(_) => bail!("{what}: unexpected answer"),
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
            ParamReply::Saved | ParamReply::Storage(_) => bail!("{name}: unexpected answer"),
        }
    }

    /// Saves the values to the board's flash.
    pub fn save(&mut self) -> anyhow::Result<()> {
        match self.request(&ParamOp::Save)? {
            ParamReply::Saved => Ok(()),
            ParamReply::Error(e) => bail!("save: {}", e.describe()),
            ParamReply::Entry(_) | ParamReply::Storage(_) => bail!("save: unexpected answer"),
        }
    }

    /// The board's parameter storage status.
    pub fn storage(&mut self) -> anyhow::Result<StorageStatus> {
        self.storage_op(&ParamOp::Storage)
    }

    /// Acknowledges a failed load ([`ParamOp::Acknowledge`]); the storage status after it.
    pub fn acknowledge(&mut self) -> anyhow::Result<StorageStatus> {
        self.storage_op(&ParamOp::Acknowledge)
    }

    fn storage_op(&mut self, op: &ParamOp) -> anyhow::Result<StorageStatus> {
        match self.request(op)? {
            ParamReply::Storage(s) => Ok(s),
            ParamReply::Error(e) => bail!("storage: {}", e.describe()),
            ParamReply::Entry(_) | ParamReply::Saved => bail!("storage: unexpected answer"),
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
    c.sign_with(crate::key::HostSigner::from_file(
        args.key.as_deref(),
        crate::key::link_id::PARAM,
    )?);
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
        ParamAction::Storage => println!("{}", format_storage(&c.storage()?)),
        ParamAction::Ack => println!("{}", format_storage(&c.acknowledge()?)),
    }
    Ok(())
}

/// The parameters a file sets, applied over the defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamFile {
    /// The autopilot's configuration.
    pub autopilot: AutopilotConfig,
    /// The camera board's Edge-FS configuration.
    pub camera: EdgeFsParams,
}

impl Default for ParamFile {
    fn default() -> Self {
        Self {
            autopilot: AutopilotConfig::default(),
            camera: EdgeFsParams::default_config(),
        }
    }
}

/// One board's section of a parameter file: the board it names and each `key = value`
/// (sorted by name), checked against that board's table.
#[derive(Debug, Clone, PartialEq)]
pub struct FileSection {
    /// The board.
    pub board: Node,
    /// `(name, value)`, each of the parameter's kind and within its bounds.
    pub values: Vec<(String, ParamValue)>,
}

impl ParamFile {
    /// Reads `path` (see the module docs).
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        Ok(Self::load_sections(path)?.0)
    }

    /// Reads `path` and also returns its sections as written (what `hil --params` sends).
    pub fn load_sections(path: &Path) -> anyhow::Result<(Self, Vec<FileSection>)> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading parameter file {}", path.display()))?;
        Self::parse_sections(&text, &path.display().to_string())
    }

    /// Parses a parameter file's `text`; errors name `file`, the key and the problem.
    pub fn parse(text: &str, file: &str) -> anyhow::Result<Self> {
        Ok(Self::parse_sections(text, file)?.0)
    }

    /// [`ParamFile::parse`], also returning the sections as written.
    pub fn parse_sections(text: &str, file: &str) -> anyhow::Result<(Self, Vec<FileSection>)> {
        let doc: toml::Table = toml::from_str(text).map_err(|e| anyhow!("{file}: {e}"))?;
        let mut out = Self::default();
        let mut sections = Vec::new();
        for (board, table) in &doc {
            let toml::Value::Table(table) = table else {
                bail!("{file}: `{board}` must be a table ([autopilot] or [camera])");
            };
            let section = match board.as_str() {
                "autopilot" => {
                    let s = apply_section(&ap_params::AUTOPILOT, &mut out.autopilot, table)
                        .map_err(|(key, problem)| anyhow!("{file}: [{board}] {key}: {problem}"))?;
                    FileSection {
                        board: Node::Autopilot,
                        values: s,
                    }
                }
                "camera" => FileSection {
                    board: Node::StereoBoard,
                    values: apply_section(&cam_params::CAMERA, &mut out.camera, table)
                        .map_err(|(key, problem)| anyhow!("{file}: [{board}] {key}: {problem}"))?,
                },
                other => {
                    bail!("{file}: unknown board [{other}] (expected [autopilot] or [camera])")
                }
            };
            sections.push(section);
        }
        Ok((out, sections))
    }
}

impl FileSection {
    /// The section's name in a file: `autopilot` or `camera`.
    pub fn name(&self) -> &'static str {
        match self.board {
            Node::StereoBoard => "camera",
            _ => "autopilot",
        }
    }

    /// Sends every value to the board with `set` through `c` (a client for this section's
    /// board), then reads each back with `get`. The first refusal, silence or read-back that
    /// differs from what was sent is an error naming `file`, the section and the key.
    pub fn send_and_verify(&self, c: &mut ParamClient<'_>, file: &str) -> anyhow::Result<()> {
        let board = self.name();
        for (key, v) in &self.values {
            c.set_value(key, *v)
                .with_context(|| format!("{file}: [{board}] {key}: the board refused the set"))?;
        }
        for (key, v) in &self.values {
            let e = c
                .get(key)
                .with_context(|| format!("{file}: [{board}] {key}: reading it back"))?;
            check_read_back(file, board, key, *v, e.value)?;
        }
        Ok(())
    }
}

/// `Ok` when a board reads back the value that was `sent`; otherwise the error naming the
/// file, the section and the key.
pub fn check_read_back(
    file: &str,
    board: &str,
    key: &str,
    sent: ParamValue,
    read: ParamValue,
) -> anyhow::Result<()> {
    if sent == read {
        Ok(())
    } else {
        bail!(
            "{file}: [{board}] {key}: set to {}, but the board reads back {}",
            format_value(sent),
            format_value(read)
        )
    }
}

/// Applies one section's keys to `cfg` through `table`; an error is `(key, problem)`.
fn apply_section<C: Copy>(
    table: &ParamTable<C>,
    cfg: &mut C,
    section: &toml::Table,
) -> Result<Vec<(String, ParamValue)>, (String, String)> {
    let mut values = Vec::new();
    for (key, value) in section {
        let at = |problem: String| (key.clone(), problem);
        let index = table
            .index_of(key)
            .ok_or_else(|| at("no such parameter (see `sim-host param list`)".into()))?;
        let v = toml_value(table.specs[index].kind, value).map_err(at)?;
        table.set(cfg, index, v).map_err(|r| at(r.to_string()))?;
        values.push((key.clone(), v));
    }
    Ok(values)
}

/// A board's table as the markdown table docs/parameters.md holds (between its
/// `<!-- NAME-table -->` markers; a test keeps the two equal).
pub fn markdown_table<C: Copy>(table: &ParamTable<C>) -> String {
    let d = (table.defaults)();
    let mut out =
        String::from("| name | type | unit | default | min | max |\n|---|---|---|---|---|---|\n");
    for (i, s) in table.specs.iter().enumerate() {
        let default = table.get(&d, i).map_or(String::new(), format_value);
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

/// The autopilot's table as markdown (see [`markdown_table`]).
pub fn autopilot_markdown_table() -> String {
    markdown_table(&ap_params::AUTOPILOT)
}

/// The camera board's table as markdown (see [`markdown_table`]).
pub fn camera_markdown_table() -> String {
    markdown_table(&cam_params::CAMERA)
}

fn toml_value(kind: ParamKind, v: &toml::Value) -> Result<ParamValue, String> {
    match (kind, v) {
        (ParamKind::F32, toml::Value::Float(x)) => Ok(ParamValue::F32(*x as f32)),
        (ParamKind::F32, toml::Value::Integer(x)) => Ok(ParamValue::F32(*x as f32)),
        (ParamKind::U32, toml::Value::Integer(x)) => u32::try_from(*x)
            .map(ParamValue::U32)
            .map_err(|_| format!("{x} is not a u32 (0 ..= {})", u32::MAX)),
        (ParamKind::I32, toml::Value::Integer(x)) => i32::try_from(*x)
            .map(ParamValue::I32)
            .map_err(|_| format!("{x} is not an i32 ({} ..= {})", i32::MIN, i32::MAX)),
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
        let empty = ParamFile::parse("", "p.toml").unwrap();
        assert_eq!(empty, ParamFile::default());

        let (f, sections) = ParamFile::parse_sections(
            "[camera]\nstereo_shift = -3\nmax_horizon = 4\n[autopilot]\nguid_kp = 0.25\n",
            "p.toml",
        )
        .unwrap();
        assert_eq!(f.camera.stereo_shift_px, -3);
        assert_eq!(f.camera.max_horizon, 4);
        assert_eq!(f.autopilot.guidance.kp, 0.25);
        let camera = sections
            .iter()
            .find(|s| s.board == Node::StereoBoard)
            .unwrap();
        assert_eq!(
            camera.values,
            vec![
                ("max_horizon".to_string(), ParamValue::U32(4)),
                ("stereo_shift".to_string(), ParamValue::I32(-3)),
            ]
        );
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
        let e = err("[camera]\nstereo_shift = 25\n");
        assert!(
            e.contains("[camera] stereo_shift") && e.contains("[-20 ..= 20] px"),
            "{e}"
        );
        let e = err("[camera]\nguid_kp = 0.2\n");
        assert!(e.contains("[camera] guid_kp: no such parameter"), "{e}");
        let e = err("[camera]\nhalf_window = 2.5\n");
        assert!(e.contains("expected a u32"), "{e}");
        let e = err("guid_kp = 0.2\n");
        assert!(e.contains("must be a table"), "{e}");
    }

    #[test]
    fn the_docs_list_both_tables() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/parameters.md");
        let docs = std::fs::read_to_string(path).unwrap();
        for (board, want) in [
            ("autopilot", autopilot_markdown_table()),
            ("camera", camera_markdown_table()),
        ] {
            let open = format!("<!-- {board}-table -->\n");
            let close = format!("<!-- /{board}-table -->");
            let table = docs
                .split(&open)
                .nth(1)
                .and_then(|rest| rest.split(&close).next())
                .unwrap_or("");
            if table != want {
                let gen = std::env::temp_dir().join(format!("{board}-parameters.md"));
                std::fs::write(&gen, &want).unwrap();
                panic!(
                    "docs/parameters.md's {board} table differs from the board's table: paste {} between its markers {open:?} and {close:?}",
                    gen.display()
                );
            }
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
