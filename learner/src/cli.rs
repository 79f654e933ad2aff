//! `learner`'s command line: one variant of [`Command`] per subcommand.

use cabc_learner::bench::BenchOptions;
use cabc_learner::compare;
use cabc_learner::demo::DemoOptions;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "learner",
    version,
    about = "cabc learner: replay, safety auto-labelling, constraint-aware training, the distributed run"
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
    /// Print one value of a configuration (dotted key, e.g. actors.count); or, with --gif, write a video of a run's
    /// policy: `learner show RUN --gif [VERSION]`.
    Show {
        #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
        config: String,
        /// The configuration's key; with --gif, the run folder.
        key: String,
        /// A GIF of VERSION: `best` (the default: best-policy.safetensors evaluated anew), `final` (the final policy
        /// evaluated anew) or a version number (its evaluation's plots/eval-v<N>.gif, or the best version's weights
        /// evaluated anew; no other version's weights are kept).
        #[arg(long, value_name = "VERSION", num_args = 0..=1, default_missing_value = "best")]
        gif: Option<cabc_learner::show::Which>,
        /// Where to write the GIF (default: in the run folder).
        #[arg(long, requires = "gif")]
        out: Option<PathBuf>,
    },
    /// A video (GIF) of a run's best (or final) policy driving from the fixed spawn, evaluated anew.
    Video {
        /// The run folder.
        run: PathBuf,
        /// The final policy instead of the best.
        #[arg(long = "final")]
        final_: bool,
        /// Where to write the GIF (default: RUN/best-policy.gif or RUN/final-policy.gif).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// zenohd's configuration for a run (deploy/SCALE-OUT.md §2), JSON5 on stdout: the links, TLS and access control
    /// of its `[bus.security]` under the router's certificate `<certs>/zenohd.pem` (make-certs.sh --zenohd).
    ZenohdConfig {
        #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
        config: String,
        /// Endpoints zenohd listens on (default: the protocol and port of every bus.connect endpoint, on every
        /// address); repeatable.
        #[arg(long)]
        listen: Vec<String>,
        /// A configuration value, `key=value`; repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// The messages a standalone zenohd's access control dropped, from its log (written with
    /// `RUST_LOG=info,zenoh::net::routing::interceptor::access_control=trace`), as JSON by "<subject>: <action> on
    /// <key>" (deploy/SCALE-OUT.md §2).
    AclDenials {
        /// zenohd's log file.
        log: PathBuf,
    },
    /// The paper's figures for a set of run folders, both methods on one plot: laps per version, imitation loss with
    /// the early stops, lap times of the full evaluations; a Markdown table of the runs on stdout.
    Compare(compare::CompareOptions),
    /// The paper's Fig. 3: auto-labelling and the critic it trains on a constructed 2-d example.
    AutolabelDemo {
        #[command(flatten)]
        options: DemoOptions,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// The camera policy's training and inference images per second (ResNet-18 at 224x224 by default), on a GPU
    /// where there is one; prints JSON.
    BenchVision(cabc_learner::bench_vision::VisionBenchOptions),
    /// Throughput of auto-labelling and training.
    Bench {
        #[command(flatten)]
        options: BenchOptions,
        #[arg(long)]
        json: bool,
    },
}
