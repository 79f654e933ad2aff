//! `expert-server`: answers relabelling queries on `cabc/<run>/expert/<kind>` (serve), drives the simulator with an
//! expert alone (drive), and measures solve rates (bench). A thin shell over the `cabc_expert` library.

mod server;

use anyhow::{bail, Context, Result};
use cabc_expert::bench;
use cabc_expert::drive::{drive, DriveOptions};
use cabc_expert::relabel::Expert;
use cabc_expert::Mpcc;
use cabc_proto::config::RunConfig;
use cabc_sim::vehicle::VehicleParams;
use clap::{Parser, Subcommand};
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "expert-server",
    version,
    about = "The cabc expert: MPCC-conv on Clarabel or the PID lane follower"
)]
struct Cli {
    /// Run configuration: a preset (v-b-ref, v-b, v-a-cpu, smoke, ...) or a TOML file.
    #[arg(long, short, global = true, default_value = cabc_proto::config::DEFAULT_PRESET)]
    config: String,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Serve relabelling queries over zenoh (the default).
    Serve(server::ServeArgs),
    /// Drive the simulator with the MPCC alone from the fixed spawn and print a JSON summary.
    Drive {
        /// Laps to drive.
        #[arg(long, default_value_t = 3)]
        laps: usize,
        /// Step limit.
        #[arg(long, default_value_t = 5000)]
        max_steps: usize,
        /// Write every step as CSV.
        #[arg(long)]
        trace: Option<std::path::PathBuf>,
        /// Draw the driven line on the track (PNG).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
    },
    /// Print MPCC solves per second per core and step-time percentiles.
    Bench {
        /// Closed-loop steps to time.
        #[arg(long, default_value_t = 300)]
        steps: usize,
        /// Time the closed-loop drive this many times and report the median of the runs' medians (a shared
        /// machine's speed drifts by ±20 % over minutes; one run is one sample of it).
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        /// Where a step's time goes instead: Clarabel's own timers per phase and the time outside Clarabel.
        #[arg(long, conflicts_with = "candidates")]
        profile: bool,
        /// Measure the ways of cutting a step (issue 75) side by side with the reference's: step time (median of
        /// --repeat interleaved drives), iterations, QPs, laps from the fixed spawn, failures from random spawns.
        #[arg(long)]
        candidates: bool,
        /// With --candidates: only these (by name, repeatable; the reference is always measured first).
        #[arg(long = "only", value_name = "NAME")]
        only: Vec<String>,
        /// With --candidates: random spawns (the training distribution) each candidate drives.
        #[arg(long, default_value_t = 40)]
        spawns: usize,
        /// With --candidates: steps of each random-spawn episode.
        #[arg(long, default_value_t = 100)]
        spawn_steps: usize,
    },
}

fn main() -> Result<()> {
    cabc_proto::telemetry::init();
    let cli = Cli::parse();
    let config = RunConfig::load(&cli.config)
        .with_context(|| format!("loading configuration {}", cli.config))?;
    match cli
        .command
        .unwrap_or(Command::Serve(server::ServeArgs::default()))
    {
        Command::Serve(args) => {
            cabc_proto::telemetry::log_run(&config, &format!("expert-server-{}", args.id));
            let expert = Expert::from_config(&config).context("building the MPCC")?;
            server::serve(config, expert, args)
        }
        Command::Drive {
            laps,
            max_steps,
            trace,
            plot,
        } => {
            let mpcc = mpcc(&config)?;
            let opts = DriveOptions {
                laps,
                max_steps,
                stop_on_failure: false,
            };
            let report = drive(&mpcc, &VehicleParams::default(), &opts);
            if let Some(path) = &trace {
                report
                    .write_csv(path)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            if let Some(path) = &plot {
                let line: Vec<(f64, f64)> = report
                    .steps
                    .iter()
                    .map(|s| (s.state[3], s.state[4]))
                    .collect();
                cabc_sim::map::render_track(mpcc.track(), 100.0, &line)
                    .write_png(path)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            println!("{}", serde_json::to_string_pretty(&report.summary())?);
            Ok(())
        }
        Command::Bench {
            steps,
            repeat,
            profile,
            candidates,
            only,
            spawns,
            spawn_steps,
        } => {
            if steps < 10 {
                bail!("--steps must be at least 10");
            }
            if repeat == 0 {
                bail!("--repeat must be at least 1");
            }
            if profile {
                let report = bench::profile(&mpcc(&config)?, steps)?;
                println!("{}", serde_json::to_string_pretty(&report)?);
                return Ok(());
            }
            if candidates {
                let track = mpcc(&config)?.track().clone();
                let all = bench::candidates();
                if let Some(unknown) = only.iter().find(|n| !all.iter().any(|c| c.name == **n)) {
                    let names: Vec<_> = all.iter().map(|c| c.name).collect();
                    bail!("no candidate {unknown:?}; candidates: {}", names.join(", "));
                }
                let chosen: Vec<_> = all
                    .into_iter()
                    .enumerate()
                    .filter(|(i, c)| *i == 0 || only.is_empty() || only.iter().any(|n| n == c.name))
                    .map(|(_, c)| c)
                    .collect();
                let rows = bench::compare(&track, &chosen, steps, repeat, spawns, spawn_steps)?;
                eprint!("{}", bench::candidates_table(&rows));
                println!("{}", serde_json::to_string_pretty(&rows)?);
                return Ok(());
            }
            let report = bench::report(&Arc::new(mpcc(&config)?), steps, repeat)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(())
        }
    }
}

fn mpcc(config: &RunConfig) -> Result<Mpcc> {
    Mpcc::from_config(config).context("building the MPCC")
}
