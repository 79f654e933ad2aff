//! `cabc`: the tools a user runs on a run's results, one subcommand each (the cargo and git convention), while the
//! processes of a run stay `learner`, `actor` and `expert-server`.
//!
//! A subcommand is one module: its arguments (a [`clap::Args`] struct) and its `run`, and one variant of
//! [`Command`] below that hands the one to the other.

use clap::{Parser, Subcommand};

mod campaign;
mod export;

#[derive(Parser)]
#[command(
    name = "cabc",
    version,
    about = "cabc's tools for finished runs: export (more to come: compare, video, show, bench, ...)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// A run's data (its checkpoint's replay) as a LeRobot v3 dataset: parquet rows of every step with the expert's
    /// label, the applied action, the next state, episode, store and policy version; prints what it wrote as JSON.
    Export(export::Args),
    /// The reproduction campaign as data: a plan (deploy/campaign/<plan>.toml) of slices of deploy/reproduce.sh,
    /// listed, its runs' states, run in lanes that share its slices, and its tables (deploy/campaign.sh wraps it).
    Campaign(campaign::Args),
}

fn main() -> anyhow::Result<()> {
    cabc_proto::telemetry::init();
    match Cli::parse().command {
        Command::Export(args) => export::run(&args),
        Command::Campaign(args) => campaign::run(&args),
    }
}

/// Prints `report` as pretty JSON on stdout.
fn print_json(report: &impl serde::Serialize) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(report)?);
    Ok(())
}
