//! `expert-server`: answers relabelling queries on `cabc/<run>/expert/<kind>` (serve), drives the simulator with an
//! expert alone (drive), and measures solve rates (bench). A thin shell over the `cabc_expert` library.

mod server;

use anyhow::{Context, Result};
use cabc_expert::bench;
use cabc_expert::drive::{drive, DriveOptions};
use cabc_expert::relabel::Expert;
use cabc_expert::Mpcc;
use cabc_proto::config::RunConfig;
use cabc_sim::vehicle::VehicleParams;
use clap::{Parser, Subcommand};

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
    /// A configuration value over it, `key=value` (e.g. `expert.mpcc_tol_gap=1e-2`); repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", global = true)]
    set: Vec<String>,
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
    Bench(bench::BenchArgs),
    /// Drive the MPCC alone on each track (the L-track and the shipped ones unless named) and print a table of laps,
    /// lap times and solver failures (Markdown on stdout; --json for every figure).
    Tracks(cabc_expert::tracks::TracksArgs),
}

fn main() -> Result<()> {
    cabc_proto::telemetry::init();
    let cli = Cli::parse();
    let config = RunConfig::load(&cli.config)
        .and_then(|c| c.with_overrides(&cli.set))
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
        Command::Tracks(args) => {
            print!("{}", cabc_expert::tracks::run(&args)?);
            Ok(())
        }
        Command::Bench(args) => {
            let output = bench::run(&mpcc(&config)?, &args)?;
            println!("{}", serde_json::to_string_pretty(&output)?);
            Ok(())
        }
    }
}

fn mpcc(config: &RunConfig) -> Result<Mpcc> {
    Mpcc::from_config(config).context("building the MPCC")
}
