//! `vboard`: a virtual board for ground tools.
//!
//! ```text
//! vboard serve autopilot [--listen 127.0.0.1:4010] [--seconds S] [--pace P] [--seed N]
//! ```
//!
//! Runs the real autopilot image (`VBOARD_FIRMWARE_DIR`, default the main workspace's
//! `target/thumbv7em-none-eabihf/release`: `cargo xtask fw` builds it) on the virtual
//! autopilot board, level and still on the bench, and serves its telemetry UART (USART1) to
//! one TCP client: `sim-host monitor --port tcp:127.0.0.1:4010`. It prints `listening on ADDR`
//! once the socket is open (port 0 picks a free one), runs at `--pace` virtual seconds per wall
//! second (default 1; 0: as fast as it can) until `--seconds` of virtual time (default: an
//! hour) or the client leaves, then prints what crossed the bridge and the firmware's log if
//! it faulted.

use std::net::TcpListener;
use std::process::ExitCode;

use virtual_board::bench::{Options, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::serve::TcpBridge;

struct Args {
    listen: String,
    seconds: f64,
    pace: f64,
    seed: u64,
}

const USAGE: &str =
    "usage: vboard serve autopilot [--listen ADDR] [--seconds S] [--pace P] [--seed N]";

fn parse(args: &[String]) -> Result<Args, String> {
    let mut out = Args {
        listen: "127.0.0.1:4010".into(),
        seconds: 3600.0,
        pace: 1.0,
        seed: 1,
    };
    match args {
        [serve, board, ..] if serve == "serve" && board == "autopilot" => {}
        _ => return Err(USAGE.into()),
    }
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
        match flag.as_str() {
            "--listen" => out.listen = value.clone(),
            "--seconds" => out.seconds = number("a number of seconds, not negative")?,
            "--pace" => out.pace = number("virtual seconds per wall second, not negative")?,
            "--seed" => {
                out.seed = value
                    .parse()
                    .map_err(|_| format!("--seed {value}: an unsigned integer"))?
            }
            other => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    Ok(out)
}

fn serve(args: &Args) -> Result<(), String> {
    let firmware = Firmware::real("autopilot")?;
    let board = Autopilot::new(args.seed).map_err(|e| format!("the board: {e:?}"))?;
    let listener = TcpListener::bind(&args.listen)
        .map_err(|e| format!("listening on {}: {e}", args.listen))?;
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    println!("listening on {addr}");
    let pace = (args.pace > 0.0).then_some(args.pace);
    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, pace)
        .map_err(|e| format!("accepting a client on {addr}: {e}"))?;
    let outcome = run(
        Setup {
            board,
            firmware,
            probe: bridge,
        },
        Options::seconds(args.seconds),
    )?;
    let bridge = &outcome.probe;
    println!(
        "served {:.3} s of virtual time in {:.1} s: {} bytes to the client, {} from it ({})",
        outcome.end_ns as f64 / 1e9,
        outcome.wall_s,
        bridge.bytes_out,
        bridge.bytes_in,
        bridge.ended.as_deref().unwrap_or("time is up")
    );
    if !outcome.faults.is_empty() || !outcome.violations.is_empty() {
        return Err(outcome.report());
    }
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match parse(&args).and_then(|a| serve(&a)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vboard: {e}");
            ExitCode::FAILURE
        }
    }
}
