//! `learner`'s command line: one variant of [`Command`] per subcommand.

use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "learner",
    version,
    about = "cabc learner: the learner process of a run (Algorithm 1 over zenoh, or in-process with --local)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Train: the learner of a distributed run (Algorithm 1 over zenoh), writing into the run folder.
    Run {
        /// Run configuration: a preset (v-b-ref, v-b, v-a-cpu, smoke, ...) or a TOML file.
        #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
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
        /// The run's baseline: lambda = algorithm.baseline_lambda (0: behaviour cloning), rho = algorithm.baseline_rho
        /// when given, run name suffixed with -baseline.
        #[arg(long)]
        baseline: bool,
        /// Zenoh endpoints to listen on, overriding the configuration's `bus.listen`.
        #[arg(long)]
        listen: Vec<String>,
        /// One process: the actors, the expert and the evaluator in-process, no bus (the policy runs on the
        /// learner's device for collection and evaluation too).
        #[arg(long, conflicts_with = "listen")]
        local: bool,
        /// A configuration value, `key=value` (e.g. `run.seed=3`); repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Resolve a configuration, create its run folder with config.toml inside, and print the folder.
    Prepare {
        #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
        config: String,
        #[arg(long)]
        baseline: bool,
        /// A configuration value, `key=value` (e.g. `run.seed=3`); repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
}
