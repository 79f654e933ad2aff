//! `cabc robust RUN [--policy best|final|FILE] [study options] [--out DIR]`: a run's policy driven from random
//! spawns under action and state noise ([`cabc_robust`]); the summary as JSON on stdout, the full report (with every
//! spawn and its outcome per level) in OUT/robust.json, the figure in OUT/robust.png.

use crate::show::run_config;
use cabc_robust::RobustOptions;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// The run folder (its config.toml, and its policy files unless --policy names another).
    pub run: PathBuf,
    /// The policy: `best` (RUN/best-policy.safetensors), `final` (RUN/final-policy.safetensors) or a safetensors
    /// file of the run's architecture.
    #[arg(long, default_value = "best")]
    pub policy: String,
    #[command(flatten)]
    pub options: RobustOptions,
    /// Where to write robust.json and robust.png (default: RUN/robust/).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let config = run_config(&args.run)?;
    let settings = args.options.settings(&config)?;
    let policy = cabc_robust::policy_path(&args.run, &args.policy);
    let out = args.out.clone().unwrap_or_else(|| args.run.join("robust"));
    // One libtorch thread: a policy of one observation at a time gains nothing from more.
    cabc_models::device::one_cpu_thread();
    let started = Instant::now();
    let written = cabc_robust::study_policy_file(&config, &settings, &policy, &out)?;
    crate::print_json(&written.report.summary())?;
    eprintln!(
        "{} episodes in {:.1} s; wrote {} and {}",
        settings.spawns * settings.levels.len(),
        started.elapsed().as_secs_f64(),
        written.json.display(),
        written.png.display()
    );
    Ok(())
}
