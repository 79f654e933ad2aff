//! `cabc probe RUN [--steps N] [--json]`: what a run's data lets a camera policy copy (issue 58,
//! [`cabc_learning::probe`]): predictors of the expert's label fitted on the run's D+ and their held-out imitation
//! loss beside a constant predictor's, as a Markdown table (or JSON) on stdout.

use crate::show::run_config;
use anyhow::Context;
use cabc_learning::checkpoint::Checkpoint;
use cabc_learning::probe::{self, ProbeOptions};
use cabc_learning::replay::ReplaySnapshot;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The run folder (its config.toml and checkpoint; a run still going is read as its last checkpoint left it).
    pub run: PathBuf,
    /// Adam steps of each fitted predictor.
    #[arg(long, default_value_t = ProbeOptions::default().steps)]
    pub steps: usize,
    /// Rows per mini-batch.
    #[arg(long, default_value_t = ProbeOptions::default().batch)]
    pub batch: usize,
    /// D+'s rows read at most, evenly spaced (a camera row holds its image in memory).
    #[arg(long, default_value_t = ProbeOptions::default().max_rows)]
    pub max_rows: usize,
    /// The seed of the predictors' weights and mini-batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let config = run_config(&args.run)?;
    let checkpoint = Checkpoint::open(&args.run.join("checkpoint"))
        .with_context(|| format!("{} has no checkpoint to read D+ from", args.run.display()))?;
    let bytes = checkpoint.read("replay.bin")?;
    let replay = ReplaySnapshot::read(&bytes, &args.run)
        .with_context(|| format!("reading {}'s replay", args.run.display()))?;
    drop(bytes);
    let options = ProbeOptions {
        steps: args.steps,
        batch: args.batch,
        max_rows: args.max_rows,
        seed: args.seed,
        ..ProbeOptions::default()
    };
    eprintln!(
        "[probe] fitting {} predictors for {} steps each on {}'s D+ ({} steps)",
        if config.observation.kind == cabc_proto::config::ObservationKind::Camera {
            3
        } else {
            2
        },
        options.steps,
        args.run.display(),
        replay.plus.len()
    );
    let report = probe::probe(&config, &replay, &options)
        .with_context(|| format!("probing {}", args.run.display()))?;
    if args.json {
        crate::print_json(&report)
    } else {
        print!("{}", report.table());
        Ok(())
    }
}
