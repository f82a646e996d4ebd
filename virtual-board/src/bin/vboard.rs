//! `vboard`: virtual boards for ground tools.
//!
//! ```text
//! vboard serve autopilot [--listen 127.0.0.1:4010] [--seconds S] [--pace P] [--seed N]
//! vboard serve hil [--stereo-listen 127.0.0.1:4011] [--autopilot-listen 127.0.0.1:4012]
//!                  [--seconds S] [--pace P] [--seed N]
//! ```
//!
//! `serve autopilot` runs the real autopilot image (`VBOARD_FIRMWARE_DIR`, default the main
//! workspace's `target/firmware/real`: `cargo xtask fw` builds it) on the
//! virtual autopilot board, level and still on the bench, and serves its telemetry UART
//! (USART1) to one TCP client: `sim-host monitor --port tcp:127.0.0.1:4010`. It runs at `--pace`
//! virtual seconds per wall second (default 1).
//!
//! `serve hil` runs both `hil`-flavour images (`VBOARD_HIL_FIRMWARE_DIR`, default
//! `target/firmware/hil`: `cargo xtask fw --flavour hil` builds them)
//! on the two virtual boards, their link UARTs joined, and serves the camera board's host UART
//! (USART2) on `--stereo-listen` and the autopilot's (USART1) on `--autopilot-listen`, for
//! `sim-host hil --stereo tcp:ADDR --autopilot tcp:ADDR`. The boards run on the host's world
//! time, so the default pace is 0: as fast as the bench can.
//!
//! Each prints `listening on ADDR` per socket once it is open (port 0 picks a free one), runs
//! until `--seconds` of virtual time (default: an hour) or a client leaves, then prints what
//! crossed each bridge and the firmware's log if it faulted.

use std::net::TcpListener;
use std::process::ExitCode;

use virtual_board::bench::{BenchBoard, Options, Outcome, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::serve::{self, TcpBridge};

/// Which boards to serve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum What {
    /// The real autopilot image, its telemetry port.
    Autopilot,
    /// Both hil images, both host ports.
    Hil,
}

struct Args {
    what: What,
    listen: String,
    stereo_listen: String,
    autopilot_listen: String,
    seconds: f64,
    pace: Option<f64>,
    seed: u64,
}

const USAGE: &str = "usage: vboard serve autopilot [--listen ADDR] [--seconds S] [--pace P] [--seed N]
       vboard serve hil [--stereo-listen ADDR] [--autopilot-listen ADDR] [--seconds S] [--pace P] [--seed N]";

fn parse(args: &[String]) -> Result<Args, String> {
    let what = match args {
        [serve, board, ..] if serve == "serve" && board == "autopilot" => What::Autopilot,
        [serve, board, ..] if serve == "serve" && board == "hil" => What::Hil,
        _ => return Err(USAGE.into()),
    };
    let mut out = Args {
        what,
        listen: "127.0.0.1:4010".into(),
        stereo_listen: "127.0.0.1:4011".into(),
        autopilot_listen: "127.0.0.1:4012".into(),
        seconds: 3600.0,
        pace: None,
        seed: 1,
    };
    let mut it = args[2..].iter();
    while let Some(flag) = it.next() {
        let value = it
            .next()
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
        let number = |what: &str| -> Result<f64, String> {
            value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| format!("{flag} {value}: {what}"))
        };
        match (flag.as_str(), what) {
            ("--listen", What::Autopilot) => out.listen = value.clone(),
            ("--stereo-listen", What::Hil) => out.stereo_listen = value.clone(),
            ("--autopilot-listen", What::Hil) => out.autopilot_listen = value.clone(),
            ("--seconds", _) => out.seconds = number("a number of seconds, not negative")?,
            ("--pace", _) => {
                out.pace = Some(number("virtual seconds per wall second, not negative")?);
            }
            ("--seed", _) => {
                out.seed = value
                    .parse()
                    .map_err(|_| format!("--seed {value}: an unsigned integer"))?;
            }
            (other, _) => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    Ok(out)
}

fn listen(addr: &str, what: &str) -> Result<TcpListener, String> {
    let listener = TcpListener::bind(addr).map_err(|e| format!("listening on {addr}: {e}"))?;
    let bound = listener.local_addr().map_err(|e| e.to_string())?;
    println!("{what}: listening on {bound}");
    Ok(listener)
}

fn accept<B>(
    listener: &TcpListener,
    uart: fn(&mut B) -> &mut virtual_board::link::WireEnd,
    pace: Option<f64>,
) -> Result<TcpBridge<B>, String> {
    TcpBridge::accept(listener, uart, pace.filter(|p| *p > 0.0))
        .map_err(|e| format!("accepting a client: {e}"))
}

/// What crossed a bridge, and why the run ended (`options`: the run's).
fn served<B: BenchBoard>(
    name: &str,
    outcome: &Outcome<B, TcpBridge<B>>,
    options: Options,
) -> Result<(), String> {
    let bridge = &outcome.probe;
    let why = bridge
        .ended
        .as_deref()
        .unwrap_or(if outcome.end_ns >= options.until_ns {
            "time is up"
        } else {
            "the other board's client left"
        });
    println!(
        "{name}: served {:.3} s of virtual time in {:.1} s: {} bytes to the client, {} from it ({why})",
        outcome.end_ns as f64 / 1e9,
        outcome.wall_s,
        bridge.bytes_out,
        bridge.bytes_in,
    );
    if !outcome.faults.is_empty() || !outcome.violations.is_empty() {
        return Err(outcome.report());
    }
    Ok(())
}

fn serve_autopilot(args: &Args) -> Result<(), String> {
    let firmware = Firmware::real("autopilot")?;
    let board = Autopilot::new(args.seed).map_err(|e| format!("the board: {e:?}"))?;
    let listener = listen(&args.listen, "autopilot telemetry")?;
    let bridge = accept(&listener, serve::autopilot_host, args.pace.or(Some(1.0)))?;
    let options = Options::seconds(args.seconds);
    let outcome = run(
        Setup {
            board,
            firmware,
            probe: bridge,
        },
        options,
    )?;
    served("autopilot", &outcome, options)
}

fn serve_hil(args: &Args) -> Result<(), String> {
    let stereo = listen(&args.stereo_listen, "camera board (hil) host link")?;
    let autopilot = listen(&args.autopilot_listen, "autopilot (hil) host link")?;
    let (s, a) = (
        stereo.local_addr().map_err(|e| e.to_string())?,
        autopilot.local_addr().map_err(|e| e.to_string())?,
    );
    println!("run: sim-host hil --stereo tcp:{s} --autopilot tcp:{a}");
    let camera = accept(&stereo, serve::camera_host, args.pace)?;
    let autopilot = accept(&autopilot, serve::autopilot_host, args.pace)?;
    let options = Options::seconds(args.seconds);
    let (camera, autopilot) = serve::hil(camera, autopilot, args.seed, options)?;
    match (
        served("camera board", &camera, options),
        served("autopilot", &autopilot, options),
    ) {
        (Ok(()), Ok(())) => Ok(()),
        (Err(e), Ok(())) | (Ok(()), Err(e)) => Err(e),
        (Err(c), Err(a)) => Err(format!("{c}\n{a}")),
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = parse(&args).and_then(|a| match a.what {
        What::Autopilot => serve_autopilot(&a),
        What::Hil => serve_hil(&a),
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vboard: {e}");
            ExitCode::FAILURE
        }
    }
}
