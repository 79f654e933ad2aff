//! `learner`: a thin shell over the cabc-learner library. Each subcommand is one variant of [`Command`] and one
//! function; the distributed run (`run`) is added beside the others.

use anyhow::Context;
use cabc_learner::bench::{run_bench, BenchOptions};
use cabc_learner::demo::autolabel_demo;
use cabc_learner::rundir::RunDir;
use cabc_proto::config::RunConfig;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "learner",
    version,
    about = "cabc learner: replay, safety auto-labelling, constraint-aware training, the distributed run"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train: the learner of a distributed run (Algorithm 1 over zenoh), writing into the run folder.
    Run {
        /// Run configuration: a preset (v-a, v-b, v-c, smoke) or a TOML file.
        #[arg(long, short, default_value = "v-b")]
        config: String,
        /// The run folder (default: <runs_dir>/<run name>).
        #[arg(long)]
        run_dir: Option<PathBuf>,
        /// Continue the run from its checkpoint.
        #[arg(long, conflicts_with = "fresh")]
        resume: bool,
        /// Start over, discarding the run folder's checkpoint.
        #[arg(long)]
        fresh: bool,
        /// The behaviour-cloning baseline: lambda = 0, run name suffixed with -baseline.
        #[arg(long)]
        baseline: bool,
        /// Zenoh endpoints to listen on, overriding the configuration's `bus.listen`.
        #[arg(long)]
        listen: Vec<String>,
    },
    /// Resolve a configuration, create its run folder with config.toml inside, and print the folder.
    Prepare {
        #[arg(long, short, default_value = "v-b")]
        config: String,
        #[arg(long)]
        baseline: bool,
    },
    /// Print one value of a configuration (dotted key, e.g. actors.count).
    Show {
        #[arg(long, short, default_value = "v-b")]
        config: String,
        key: String,
    },
    /// The paper's Fig. 3: auto-labelling and the critic it trains on a constructed 2-d example.
    AutolabelDemo {
        /// Radii to compare, one panel each.
        #[arg(long = "rho", num_args = 1.., default_values_t = [0.5, 0.25, 0.1])]
        rho: Vec<f64>,
        #[arg(long, default_value = "autolabel-demo.png")]
        out: PathBuf,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// Throughput of auto-labelling and training.
    Bench {
        #[arg(long, default_value_t = 100_000)]
        plus: usize,
        #[arg(long, default_value_t = 20_000)]
        uncertain: usize,
        #[arg(long, default_value_t = 100_000)]
        train: usize,
        /// Skip the CUDA figures even when a GPU is present.
        #[arg(long)]
        cpu_only: bool,
        #[arg(long)]
        json: bool,
    },
}

fn main() -> anyhow::Result<()> {
    cabc_proto::telemetry::init();
    match Cli::parse().command {
        Command::Run {
            config,
            run_dir,
            resume,
            fresh,
            baseline,
            listen,
        } => {
            let mut config = load(&config, baseline)?;
            if !listen.is_empty() {
                config.bus.listen = listen;
            }
            let dir = run_dir.unwrap_or_else(|| default_run_dir(&config));
            let run_dir =
                RunDir::create(&dir).with_context(|| format!("creating {}", dir.display()))?;
            if fresh {
                let _ = run_dir.remove_checkpoint();
            }
            run_dir.write_config(&config)?;
            cabc_learner::serve::run(config, run_dir, resume)
        }
        Command::Prepare { config, baseline } => {
            let config = load(&config, baseline)?;
            let dir = default_run_dir(&config);
            let run_dir =
                RunDir::create(&dir).with_context(|| format!("creating {}", dir.display()))?;
            run_dir.write_config(&config)?;
            println!("{}", dir.display());
            Ok(())
        }
        Command::Show { config, key } => {
            let config = RunConfig::load(&config)?;
            let value: toml::Value = toml::from_str(&config.to_toml())?;
            let found = key
                .split('.')
                .try_fold(&value, |v, k| v.get(k))
                .with_context(|| format!("no key {key} in the configuration"))?;
            match found {
                toml::Value::String(s) => println!("{s}"),
                other => println!("{other}"),
            }
            Ok(())
        }
        Command::AutolabelDemo {
            rho,
            out,
            json,
            seed,
        } => demo(&rho, &out, json, seed),
        Command::Bench {
            plus,
            uncertain,
            train,
            cpu_only,
            json,
        } => bench(plus, uncertain, train, !cpu_only, json),
    }
}

fn demo(rho: &[f64], out: &std::path::Path, json: bool, seed: u64) -> anyhow::Result<()> {
    let report = autolabel_demo(rho, seed, out).context("auto-labelling demo")?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for p in &report.panels {
            tracing::info!(
                rho = p.rho,
                removed_correctly = p.removed_correctly,
                removed_wrongly = p.removed_wrongly,
                kept = p.kept,
                accuracy = p.accuracy,
                "panel"
            );
        }
        tracing::info!(png = %report.png, "written");
    }
    Ok(())
}

/// Loads a configuration; the baseline is the same run with lambda = 0 under its own name.
fn load(name: &str, baseline: bool) -> anyhow::Result<RunConfig> {
    let mut config =
        RunConfig::load(name).with_context(|| format!("loading configuration {name}"))?;
    if baseline && config.algorithm.lambda != 0.0 {
        config.algorithm.lambda = 0.0;
        config.run.name = format!("{}-baseline", config.run.name);
    }
    Ok(config)
}

fn default_run_dir(config: &RunConfig) -> PathBuf {
    PathBuf::from(&config.run.runs_dir).join(&config.run.name)
}

fn bench(
    plus: usize,
    uncertain: usize,
    train: usize,
    cuda: bool,
    json: bool,
) -> anyhow::Result<()> {
    let report = run_bench(&BenchOptions {
        n_plus: plus,
        n_uncertain: uncertain,
        n_train: train,
        cuda,
        ..Default::default()
    });
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}
