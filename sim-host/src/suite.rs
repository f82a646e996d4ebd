//! `sim-host suite merge`: puts the shards of a room suite back together. Each shard is the CSV
//! of `sim-host fly --suite N --shard I/N --format csv` (run anywhere, in any order); the merge
//! prints the table or the CSV that one `sim-host fly --suite N` prints for the whole suite.

use crate::fly::{Format, SUITE_CSV_HEADER};
use crate::sim::suite;
use anyhow::Context;
use std::path::PathBuf;

/// Command-line arguments of `sim-host suite`.
#[derive(Debug, clap::Args)]
pub struct SuiteArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: SuiteCommand,
}

/// The `suite` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum SuiteCommand {
    /// Merge the CSVs of a suite's shards (`fly --suite N --shard I/N --format csv`) into the
    /// suite's table or CSV, rooms in order; fails on a room twice, a missing room or rows of
    /// two suites.
    Merge(MergeArgs),
}

/// Command-line arguments of `sim-host suite merge`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The shards' CSV files, in any order.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Output format: the table by class of room, or the merged CSV.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
    /// Also write the merged CSV as `suite.csv` in this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `sim-host suite`.
pub fn run(args: &SuiteArgs) -> anyhow::Result<()> {
    match &args.command {
        SuiteCommand::Merge(m) => merge(m),
    }
}

/// The merged CSV of the suite's `rows` (header first).
pub fn merged_csv(rows: &[suite::SuiteRow]) -> String {
    let mut csv = format!("{SUITE_CSV_HEADER}\n");
    for row in rows {
        csv.push_str(&row.line);
        csv.push('\n');
    }
    csv
}

fn merge(args: &MergeArgs) -> anyhow::Result<()> {
    let mut parts = Vec::with_capacity(args.files.len());
    for file in &args.files {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        let name = file.display().to_string();
        let rows = suite::parse_csv(&name, &text, SUITE_CSV_HEADER)?;
        parts.push((name, rows));
    }
    let rows = suite::merge(parts)?;
    let csv = merged_csv(&rows);
    let written = match &args.out {
        Some(dir) => {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            let path = dir.join("suite.csv");
            std::fs::write(&path, &csv).with_context(|| format!("writing {}", path.display()))?;
            Some(path)
        }
        None => None,
    };
    if args.format == Format::Csv {
        print!("{csv}");
        return Ok(());
    }
    print!("{}", suite::table(&rows));
    let sim_s: f64 = rows.iter().map(|r| r.duration_s).sum();
    print!(
        "{sim_s:.0} s simulated, {} rooms merged from {} files",
        rows.len(),
        args.files.len()
    );
    match written {
        Some(path) => println!("; rows in {}", path.display()),
        None => println!(),
    }
    Ok(())
}
