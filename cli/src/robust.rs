//! `cabc robust RUN [--policy best|final|FILE] [study options] [--out DIR]`: a run's policy driven from random
//! spawns under action and state noise ([`cabc_bench::robust`]); the summary as JSON on stdout, the full report
//! (with every spawn and its outcome per level) in OUT/robust.json, the figure in OUT/robust.png.

use crate::show::run_config;
use anyhow::Context;
use cabc_bench::robust::{self, RobustOptions};
use cabc_outputs::rundir::{load_policy, KeptPolicy, RunDir};
use cabc_sim::track::Track;
use std::path::{Path, PathBuf};
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

/// The policy file `which` names for `run`.
fn policy_path(run: &Path, which: &str) -> PathBuf {
    match KeptPolicy::named(which) {
        Some(kept) => run.join(RunDir::policy_file(kept)),
        None => PathBuf::from(which),
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let config = run_config(&args.run)?;
    let settings = args.options.settings(&config)?;
    let path = policy_path(&args.run, &args.policy);
    if !path.is_file() {
        anyhow::bail!(
            "no policy file {} (--policy is best, final or a .safetensors file; a run writes \
             best-policy.safetensors at its first evaluation and final-policy.safetensors at its end)",
            path.display()
        );
    }
    let policy = load_policy(&path)?;
    let out = args.out.clone().unwrap_or_else(|| args.run.join("robust"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    // One libtorch thread: a policy of one observation at a time gains nothing from more.
    cabc_models::device::one_cpu_thread();
    let started = Instant::now();
    let report = robust::study(&config, &settings, &path.display().to_string(), |input| {
        Ok(cabc_actor::run::act(&policy, input)?)
    })
    .with_context(|| format!("driving {}", path.display()))?;
    let json = out.join("robust.json");
    std::fs::write(&json, serde_json::to_string_pretty(&report)? + "\n")
        .with_context(|| format!("writing {}", json.display()))?;
    let png = out.join("robust.png");
    robust::figure::draw(&png, &Track::from_kind(config.sim.track), &report)?;
    crate::print_json(&report.summary())?;
    eprintln!(
        "{} episodes in {:.1} s; wrote {} and {}",
        settings.spawns * settings.levels.len(),
        started.elapsed().as_secs_f64(),
        json.display(),
        png.display()
    );
    Ok(())
}
