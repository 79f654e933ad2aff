//! `learner`: a thin shell over the cabc-learner library. Each subcommand is one variant of [`Command`] and one
//! function; the distributed run (`run`) is added beside the others.

use anyhow::Context;
use cabc_learner::bench::{run_bench, BenchOptions};
use cabc_learner::demo::autolabel_demo;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "learner",
    about = "cabc learner: replay, safety auto-labelling, constraint-aware training"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
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
