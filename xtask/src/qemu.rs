//! `cargo xtask qemu`: build a firmware flavour and run it in QEMU with a timeout.
//!
//! ```text
//! cargo xtask qemu stereo-board|autopilot|both [--flavour qemu|hil] [--seconds N] [--no-build]
//! ```
//!
//! Runs `qemu-system-arm -M netduinoplus2 -nographic -semihosting-config
//! enable=on,target=native -icount shift=auto -kernel <elf>` (Debian's QEMU 7.2). The firmware's
//! semihosting log goes to stdout. USART1 (the board-to-board link) and USART2 (the host link)
//! are the first two `-serial` ports: for one board both are discarded; with `both`, the two
//! QEMUs' USART1s are joined through a loopback TCP socket, so the boards talk to each other.
//! QEMU is killed after `--seconds` (default 10) of wall time, and always on the way out,
//! whatever happens. A QEMU exit with a non-zero code (a semihosting failure exit: panic or
//! fatal error) is an error.

use crate::size::{build_firmwares, firmware_elf, Flavour};
use anyhow::{bail, Context, Result};
use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

/// Runs `cargo xtask qemu`.
pub fn run(args: &[String]) -> Result<()> {
    let mut which = None;
    let mut flavour = Flavour::Qemu;
    let mut seconds = 10u64;
    let mut build = true;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--flavour" | "--flavor" => {
                flavour = Flavour::parse(it.next().context("--flavour needs a value")?)?
            }
            "--seconds" => {
                seconds = it
                    .next()
                    .context("--seconds needs a value")?
                    .parse()
                    .context("--seconds: not a number")?
            }
            "--no-build" => build = false,
            "stereo-board" | "autopilot" | "both" => which = Some(arg.as_str()),
            other => bail!("cargo xtask qemu: unknown argument {other:?}"),
        }
    }
    let which = which.context(
        "usage: cargo xtask qemu stereo-board|autopilot|both [--flavour qemu|hil] [--seconds N] [--no-build]",
    )?;
    if flavour == Flavour::Real {
        bail!("the real flavour expects the board's crystal and sensors; use --flavour qemu");
    }
    let names: Vec<&str> = match which {
        "both" => vec!["stereo-board", "autopilot"],
        one => vec![one],
    };
    if build {
        build_firmwares(flavour, &names)?;
    }
    let limit = Duration::from_secs(seconds);
    let mut guards = Vec::new();
    if names.len() == 2 {
        let port = free_port()?;
        let stereo = firmware_elf(flavour, "stereo-board");
        let autopilot = firmware_elf(flavour, "autopilot");
        guards.push(QemuGuard::spawn(
            &stereo,
            &[
                format!("socket,id=link,host=127.0.0.1,port={port},server=on,wait=off"),
                "null,id=host".into(),
            ],
        )?);
        // Give the server a moment to listen; the client retries anyway.
        std::thread::sleep(Duration::from_millis(300));
        guards.push(QemuGuard::spawn(
            &autopilot,
            &[
                format!("socket,id=link,host=127.0.0.1,port={port},reconnect=1"),
                "null,id=host".into(),
            ],
        )?);
    } else {
        let elf = firmware_elf(flavour, names[0]);
        guards.push(QemuGuard::spawn(
            &elf,
            &["null,id=link".into(), "null,id=host".into()],
        )?);
    }
    let start = Instant::now();
    loop {
        for g in guards.iter_mut() {
            if let Some(status) = g.child.try_wait()? {
                if !status.success() {
                    bail!("QEMU ({}) exited with {status}", g.name);
                }
                println!("xtask qemu: {} exited successfully", g.name);
                return Ok(());
            }
        }
        if start.elapsed() >= limit {
            println!("xtask qemu: {seconds} s elapsed, stopping QEMU");
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A free loopback TCP port (bound and released; QEMU binds it right after).
pub fn free_port() -> Result<u16> {
    let l = TcpListener::bind("127.0.0.1:0").context("binding a loopback port")?;
    Ok(l.local_addr()?.port())
}

/// The QEMU command line for one firmware; `chardevs` are `-chardev` specs whose `id` becomes
/// the next `-serial` port (USART1, USART2, ... in the netduinoplus2 SoC's order).
pub fn qemu_command(elf: &Path, chardevs: &[String]) -> Command {
    let mut cmd = Command::new("qemu-system-arm");
    cmd.args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-icount", "shift=auto"])
        .arg("-kernel")
        .arg(elf);
    for spec in chardevs {
        let id = spec
            .split(',')
            .find_map(|kv| kv.strip_prefix("id="))
            .unwrap_or("none");
        cmd.args(["-chardev", spec]);
        cmd.args(["-serial", &format!("chardev:{id}")]);
    }
    cmd
}

/// A running QEMU that is killed when dropped.
pub struct QemuGuard {
    /// The QEMU process.
    pub child: Child,
    name: String,
}

impl QemuGuard {
    /// Starts QEMU on `elf` (see [`qemu_command`]).
    pub fn spawn(elf: &Path, chardevs: &[String]) -> Result<Self> {
        if !elf.exists() {
            bail!("{} not built", elf.display());
        }
        let child = qemu_command(elf, chardevs)
            .spawn()
            .context("starting qemu-system-arm (install it: apt-get install qemu-system-arm)")?;
        Ok(Self {
            child,
            name: elf
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        })
    }

    /// Kills QEMU (if still running) and reaps it.
    pub fn stop(&mut self) -> Option<ExitStatus> {
        let _ = self.child.kill();
        self.child.wait().ok()
    }
}

impl Drop for QemuGuard {
    fn drop(&mut self) {
        self.stop();
    }
}
