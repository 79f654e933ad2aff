//! `cabc export RUN --out DIR`: a run's data as a LeRobot v3 dataset ([`cabc_export`]).

use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The run folder.
    run: PathBuf,
    /// The dataset's folder (new, or empty).
    #[arg(long)]
    out: PathBuf,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let report = cabc_export::export(&args.run, &args.out)
        .with_context(|| format!("exporting {}", args.run.display()))?;
    crate::print_json(&report)
}
