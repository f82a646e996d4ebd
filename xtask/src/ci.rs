//! `cargo xtask test`: the CI test command, runnable on a fresh machine.
//!
//! 1. Installs what a fresh machine lacks: the `thumbv7em-none-eabihf` target (rustup),
//!    `flip-link` (the firmware linker; cargo install), a nightly toolchain and `cargo-fuzz`
//!    (for the bounded fuzz run), `qemu-system-arm` (the instruction-count benchmark, `cargo
//!    xtask insns`, which a host test runs; and python3-pip if there is no pip) from Debian's
//!    main archive (apt-get), and the `mcap` and `mcap-protobuf-support` Python packages (pip),
//!    the independent reader the flight-log test checks MCAP files with.
//! 2. Checks formatting and runs clippy with warnings denied on the host (the workspace and the
//!    virtual-board bench, its own workspace) and on thumbv7em, builds the docs of both
//!    workspaces with rustdoc's warnings denied (a link to a renamed item fails), runs all host
//!    tests, builds both firmwares in release, runs them (and their `hil` images) on the virtual
//!    boards (what `cargo xtask vboard` runs), and fuzzes the protocol decoder and encoder
//!    briefly (after fmt and clippy in `fuzz/`, its own workspace). The bench's lints, docs and
//!    build, then the fuzz run, go beside the main workspace's steps: they use their own target
//!    directories, and the main workspace's steps leave a core idle part of the time.
//! 3. Prints a one-line summary, each step's wall time and a closing `N passed, N failed`
//!    line.
//!
//! Options: `--fuzz-seconds N` (default 60; 0 skips the fuzz run, for local iteration only).

use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::cargo::{cargo, cargo_test, run_checked, workspace_root, FIRMWARE_TARGET};
use crate::size::{build_firmware, Flavour, FIRMWARES};

/// The Python MCAP reader the flight-log test uses, and its protobuf decoder for Foxglove's
/// well-known types (pip requirements).
const MCAP_PYTHON: [&str; 2] = ["mcap>=1.1,<2", "mcap-protobuf-support>=0.5,<1"];

/// Runs `cargo xtask test`.
pub fn run(args: &[String]) -> Result<()> {
    let mut fuzz_seconds: u64 = 60;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--fuzz-seconds" => {
                fuzz_seconds = it
                    .next()
                    .context("--fuzz-seconds needs a value")?
                    .parse()
                    .context("--fuzz-seconds must be a number")?
            }
            other => bail!("unknown option {other} (expected --fuzz-seconds N)"),
        }
    }
    let started = Instant::now();
    let mut steps = Steps::new();

    install_prerequisites(fuzz_seconds > 0)?;
    steps.done("install");

    cargo(&["fmt", "--all", "--", "--check"]).context("cargo fmt --check failed: run cargo fmt")?;
    // The virtual-board bench is its own workspace (rigless builds on our toolchain only with
    // `--ignore-rust-version`), which the main workspace's fmt and clippy do not reach.
    let bench = crate::vboard::bench_dir();
    run_checked(
        Command::new("cargo")
            .args(["fmt", "--all", "--", "--check"])
            .current_dir(&bench),
    )
    .context("cargo fmt --check failed in virtual-board/: run cargo fmt there")?;
    steps.done("fmt(workspace, virtual-board)");

    // The virtual-board bench is its own workspace and target directory: its lints, its docs,
    // its release build and the `hil` and `qemu` firmware images are made beside the main
    // workspace's steps, into a log printed when they are joined. Then, on the same thread, the
    // fuzz targets (their own workspace and toolchain, one libFuzzer process at a time): the
    // main workspace's last steps (the tail of its tests, the firmwares' single-threaded LTO)
    // leave a core idle, while the virtual boards after them keep both busy.
    let bench_log = workspace_root().join("target").join("ci-bench.log");
    let bench = {
        let log = bench_log.clone();
        std::thread::spawn(move || {
            let start = Instant::now();
            let built = prepare_bench(&log).map(|()| start.elapsed().as_secs_f64());
            let fuzzed = (built.is_ok() && fuzz_seconds > 0).then(|| {
                let start = Instant::now();
                fuzz_run(fuzz_seconds).map(|name| (name, start.elapsed().as_secs_f64()))
            });
            (built, fuzzed)
        })
    };

    cargo(&[
        "clippy",
        "--workspace",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ])?;
    steps.done("clippy(host)");
    // One invocation per firmware package: each selects its own part's HAL feature, and cargo
    // unifies features within an invocation (insns-firmware builds both libraries for QEMU's
    // STM32F405).
    for flavour in ["", "qemu", "hil"] {
        for package in ["protocol", "stereo-board", "autopilot", "insns-firmware"] {
            let mut clippy = vec!["clippy", "--target", FIRMWARE_TARGET, "-p", package];
            let features = format!("{package}/{flavour}");
            if !flavour.is_empty() {
                if package == "protocol" || package == "insns-firmware" {
                    continue;
                }
                clippy.extend(["--features", &features]);
            }
            clippy.extend(["--", "-D", "warnings"]);
            cargo(&clippy)?;
        }
    }
    steps.done("clippy(thumbv7em: real, qemu, hil)");

    // Docs whose links point nowhere have drifted from the code: rustdoc's lints catch them.
    run_checked(
        Command::new("cargo")
            .args(["doc", "--no-deps", "--workspace"])
            .env("RUSTDOCFLAGS", "-D warnings"),
    )
    .context("cargo doc failed")?;
    steps.done("doc(workspace; rustdoc warnings denied)");

    let (passed, failed) = cargo_test(&["test", "--workspace"])?;
    steps.done(format!("tests({passed} passed)"));

    cargo(&["xtask", "fw"]).context("firmware build (cargo xtask fw) failed")?;
    steps.done("firmware(stereo-board, autopilot)");
    let (bench_built, fuzzed) = bench.join().expect("the bench thread does not panic");
    let bench_output = std::fs::read_to_string(&bench_log)
        .with_context(|| format!("reading {}", bench_log.display()))?;
    eprintln!(
        "xtask: output of the virtual-board preparation ({}):",
        bench_log.display()
    );
    eprint!("{bench_output}");
    let bench_seconds = bench_built.context("preparing the virtual-board bench failed")?;
    steps.push_beside(
        "clippy, doc and release build in virtual-board/, hil and qemu firmwares",
        bench_seconds,
        "the main workspace",
    );
    if let Some(fuzzed) = fuzzed {
        let (name, seconds) = fuzzed?;
        steps.push_beside(name, seconds, "the main workspace, after the bench");
    }
    steps.done("waiting for the virtual-board build and the fuzz run");
    // The images are built: the real ones by `xtask fw` above, the qemu ones by the bench's
    // thread. Checking them without a build keeps the shared target directory from switching
    // flavour and rebuilding the boards' crates.
    for flavour in ["real", "qemu"] {
        run_checked(Command::new("cargo").args([
            "xtask",
            "size",
            "--no-build",
            "--flavour",
            flavour,
        ]))
        .with_context(|| format!("firmware layout or size check ({flavour}) failed"))?;
    }
    steps.done("size and start-up layout (real, qemu)");

    // The virtual boards run the real images just built, and `sim-host` as the tests built it.
    let (vb_passed, vb_failed) = crate::vboard::run_built_tests(&[])?;
    steps.done(format!("vboard({vb_passed} passed)"));
    let (passed, failed) = (passed + vb_passed, failed + vb_failed);

    println!(
        "xtask test: OK in {:.0} s: {}",
        started.elapsed().as_secs_f64(),
        steps.summary()
    );
    steps.print_table();
    println!("{passed} passed, {failed} failed");
    Ok(())
}

/// The virtual-board bench made ready to run: clippy and rustdoc (warnings denied) in its
/// workspace, its tests built in release, and both firmwares in the `hil` flavour (which the
/// bench flies) and the `qemu` one (which the size step checks; the images build in the main
/// workspace's target directory, sharing its release dependencies with the `real` images, see
/// [`build_firmware`]). Every command's output goes to `log`.
fn prepare_bench(log: &Path) -> Result<()> {
    let log = std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
    let bench = crate::vboard::bench_dir();
    let logged = |cmd: &mut Command| -> Result<()> {
        writeln!(&log, "xtask: running {cmd:?}")?;
        let status = cmd
            .stdout(log.try_clone()?)
            .stderr(log.try_clone()?)
            .status()
            .with_context(|| format!("could not start {cmd:?}"))?;
        if !status.success() {
            bail!("{cmd:?} failed with {status}");
        }
        Ok(())
    };
    logged(
        Command::new("cargo")
            .args(["clippy", "--ignore-rust-version", "--all-targets", "--"])
            .args(["-D", "warnings"])
            .current_dir(&bench),
    )
    .context("clippy failed in virtual-board/ (its own workspace)")?;
    logged(
        Command::new("cargo")
            .args(["doc", "--no-deps", "--ignore-rust-version"])
            .env("RUSTDOCFLAGS", "-D warnings")
            .current_dir(&bench),
    )
    .context("cargo doc failed in virtual-board/")?;
    logged(crate::vboard::bench_test_command().arg("--no-run"))
        .context("building the virtual-board tests failed")?;
    for flavour in [Flavour::Hil, Flavour::Qemu] {
        for name in FIRMWARES {
            build_firmware(flavour, name, logged)
                .with_context(|| format!("firmware build failed ({flavour:?}: {name})"))?;
        }
    }
    Ok(())
}

/// The bounded fuzz run in `fuzz/`: fmt and clippy there, then both targets. Returns the step's
/// name.
fn fuzz_run(fuzz_seconds: u64) -> Result<String> {
    // The fuzz targets are a workspace of their own (nightly, sanitizers): formatted and
    // linted there, with the lints of the main workspace (its `[lints]` table).
    let fuzz = workspace_root().join("fuzz");
    run_checked(
        Command::new("cargo")
            .args(["fmt", "--all", "--", "--check"])
            .current_dir(&fuzz),
    )
    .context("cargo fmt --check failed in fuzz/: run cargo fmt there")?;
    run_checked(
        Command::new("cargo")
            .args([
                "+nightly",
                "clippy",
                "--all-targets",
                "--",
                "-D",
                "warnings",
            ])
            .current_dir(&fuzz),
    )
    .context("clippy failed in fuzz/ (its own workspace)")?;
    for (target, seconds) in [("decoder", fuzz_seconds), ("encoder", fuzz_seconds / 2)] {
        let max_time = format!("-max_total_time={seconds}");
        run_checked(Command::new("cargo").args([
            "+nightly",
            "fuzz",
            "run",
            target,
            "--",
            &max_time,
            "-max_len=4096",
        ]))
        .with_context(|| format!("fuzz target {target} failed"))?;
    }
    Ok(format!(
        "fmt, clippy and fuzz(decoder {fuzz_seconds} s, encoder {} s) in fuzz/",
        fuzz_seconds / 2
    ))
}

/// The CI's steps with their wall times.
struct Steps {
    /// Name, wall time in s, and what it ran beside (empty: it ran alone).
    list: Vec<(String, f64, &'static str)>,
    lap: Instant,
}

impl Steps {
    fn new() -> Self {
        Self {
            list: Vec::new(),
            lap: Instant::now(),
        }
    }

    /// Ends the current step (it started when the previous one ended).
    fn done(&mut self, name: impl Into<String>) {
        let now = Instant::now();
        let seconds = (now - self.lap).as_secs_f64();
        let name = name.into();
        eprintln!("xtask: step {name} took {seconds:.0} s");
        self.list.push((name, seconds, ""));
        self.lap = now;
    }

    /// Records a step that ran for `seconds` beside `beside`.
    fn push_beside(&mut self, name: impl Into<String>, seconds: f64, beside: &'static str) {
        self.list.push((name.into(), seconds, beside));
    }

    /// `name (N s), ...`.
    fn summary(&self) -> String {
        self.list
            .iter()
            .map(|(name, seconds, beside)| {
                let beside = if beside.is_empty() {
                    String::new()
                } else {
                    format!(", beside {beside}")
                };
                format!("{name} ({seconds:.0} s{beside})")
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// One line per step: its wall time and its name.
    fn print_table(&self) {
        println!("xtask test: wall time per step");
        for (name, seconds, beside) in &self.list {
            if beside.is_empty() {
                println!("{seconds:>8.0} s  {name}");
            } else {
                println!("{seconds:>8.0} s  {name} (beside {beside})");
            }
        }
    }
}

fn install_prerequisites(need_fuzz: bool) -> Result<()> {
    run_checked(Command::new("rustup").args(["target", "add", FIRMWARE_TARGET]))
        .context("rustup target add thumbv7em-none-eabihf")?;
    // The firmware linker (.cargo/config.toml): stack below the statics, so an overflow faults.
    // flip-link has no `--version` (run by hand it only says to use it as a linker and fails),
    // so its presence on PATH is the check.
    if !on_path("flip-link") {
        run_checked(Command::new("cargo").args(["install", "flip-link", "--locked"]))
            .context("cargo install flip-link --locked")?;
    }
    let sudo = if is_root() { None } else { Some("sudo") };
    let apt = |args: &[&str]| -> Result<()> {
        let mut cmd = match sudo {
            Some(s) => {
                let mut c = Command::new(s);
                c.arg("apt-get");
                c
            }
            None => Command::new("apt-get"),
        };
        cmd.args(args).env("DEBIAN_FRONTEND", "noninteractive");
        run_checked(&mut cmd)
    };
    let mut apt_updated = false;
    let mut apt_install = |package: &str| -> Result<()> {
        eprintln!("xtask: installing {package} from Debian's main archive");
        if !apt_updated {
            apt(&["update"])?;
            apt_updated = true;
        }
        apt(&["install", "-y", "--no-install-recommends", package])
    };
    if !succeeds(Command::new("qemu-system-arm").arg("--version")) {
        apt_install("qemu-system-arm")?;
    }
    if !succeeds(Command::new("python3").args(["-c", "import mcap.reader, mcap_protobuf.decoder"]))
    {
        if !succeeds(Command::new("python3").args(["-m", "pip", "--version"])) {
            apt_install("python3-pip")?;
        }
        eprintln!("xtask: installing the mcap Python packages (pip)");
        let pip = |extra: &[&str]| {
            let mut cmd = Command::new("python3");
            cmd.args(["-m", "pip", "install", "--quiet"])
                .args(MCAP_PYTHON)
                .args(extra);
            succeeds(&mut cmd)
        };
        // Debian's own Python refuses pip outside a virtual environment (PEP 668) unless told.
        if !pip(&[]) && !pip(&["--break-system-packages"]) {
            bail!(
                "installing the mcap Python packages failed (python3 -m pip install {})",
                MCAP_PYTHON.join(" ")
            );
        }
    }
    if need_fuzz {
        if !succeeds(Command::new("cargo").args(["+nightly", "--version"])) {
            run_checked(Command::new("rustup").args([
                "toolchain",
                "install",
                "nightly",
                "--profile",
                "minimal",
            ]))?;
        }
        if !succeeds(Command::new("cargo").args(["fuzz", "--version"])) {
            run_checked(Command::new("cargo").args(["install", "cargo-fuzz", "--locked"]))?;
        }
    }
    Ok(())
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// True if an executable file named `program` is in one of PATH's directories.
fn on_path(program: &str) -> bool {
    std::env::var_os("PATH").is_some_and(|paths| {
        std::env::split_paths(&paths).any(|dir| {
            std::fs::metadata(dir.join(program)).is_ok_and(|m| {
                use std::os::unix::fs::PermissionsExt as _;
                m.is_file() && m.permissions().mode() & 0o111 != 0
            })
        })
    })
}

fn succeeds(cmd: &mut Command) -> bool {
    cmd.stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use crate::cargo::workspace_root;

    fn table(path: &str, keys: &[&str]) -> toml::Value {
        let path = workspace_root().join(path);
        let text = std::fs::read_to_string(&path).unwrap();
        let mut value: toml::Value = toml::from_str(&text).unwrap();
        for key in keys {
            value = value
                .get(key)
                .unwrap_or_else(|| panic!("{}: no [{}]", path.display(), keys.join(".")))
                .clone();
        }
        value
    }

    /// The virtual-board bench and the fuzz targets are workspaces of their own, which do not
    /// inherit `[workspace.lints]`: their `[lints]` tables must say the same.
    #[test]
    fn the_separate_workspaces_lint_as_the_main_one() {
        let main = table("Cargo.toml", &["workspace", "lints"]);
        for manifest in ["virtual-board/Cargo.toml", "fuzz/Cargo.toml"] {
            assert_eq!(table(manifest, &["lints"]), main, "{manifest}");
        }
    }

    /// Each test directory is one binary whose `main.rs` declares the files as modules: a file
    /// it does not declare would never be compiled or run, so every file must be declared.
    #[test]
    fn every_test_file_is_a_module_of_its_binary() {
        for dir in [
            "tests/tests/integration",
            "sim-host/tests/commands",
            "virtual-board/tests/vboard",
        ] {
            let dir = workspace_root().join(dir);
            let main = std::fs::read_to_string(dir.join("main.rs")).unwrap();
            let mut files = 0;
            for entry in std::fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                let Some(name) = path.file_stem().and_then(|n| n.to_str()) else {
                    continue;
                };
                if path.extension().is_some_and(|e| e == "rs") && name != "main" {
                    let declared = format!("mod {name};");
                    assert!(
                        main.lines().any(|l| l == declared),
                        "{}: {declared} missing, so {} never runs",
                        dir.join("main.rs").display(),
                        path.display()
                    );
                    files += 1;
                }
            }
            assert!(files > 0, "{}: no test files", dir.display());
        }
    }
}
