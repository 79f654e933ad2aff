//! `cabc`: the tools a user runs on a run's results and on a deployment, one subcommand each (the cargo and git
//! convention), while the processes of a run stay `learner`, `actor` and `expert-server`.
//!
//! A subcommand is its arguments (a [`clap::Args`] struct) and one function, and one variant of [`Command`] below
//! that hands the one to the other: `export` in [`export`], `show` and `video` in [`show`], `robust` in [`robust`],
//! `probe` in [`probe`], `supervise` in [`supervise`],
//! the rest in [`tools`].

use clap::{Parser, Subcommand};

mod campaign;
mod export;
mod probe;
mod robust;
mod show;
mod supervise;
mod tools;

use tools::load;

#[derive(Parser)]
#[command(
    name = "cabc",
    version,
    about = "cabc's tools: finished runs (compare, plots, show, video, export), the learning core's demo and \
             benchmarks, a secure deployment's zenohd configuration and denials"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The paper's figures for a set of run folders, both methods on one plot: laps per version, imitation loss with
    /// the early stops, lap times of the full evaluations; a Markdown table of the runs on stdout.
    Compare(cabc_analysis::compare::CompareOptions),
    /// Print one value of a configuration (dotted key, e.g. actors.count); or, with --gif, write a video of a run's
    /// policy: `cabc show RUN --gif [VERSION]`.
    Show(show::ShowArgs),
    /// Redraws a run's plots (laps per version, losses, lap times against the expert's) from its config.toml,
    /// metrics.csv, evals.csv and summary.json alone: a run folder, or its kept copy in docs/reproduction/<run>/.
    /// Prints the files written; the plots those files cannot give (the evaluated line, the videos) are named on
    /// stderr with the command that makes them from a full run folder.
    Plots(tools::PlotsArgs),
    /// A video (GIF) of a run's best (or final) policy driving from the fixed spawn, evaluated anew.
    Video(show::VideoArgs),
    /// A run's data (its checkpoint's replay) as a LeRobot v3 dataset: parquet rows of every step with the expert's
    /// label, the applied action, the next state, episode, store and policy version; prints what it wrote as JSON.
    Export(export::Args),
    /// A run's policy driven from N random spawns along the track under action and state noise, at several levels:
    /// crashes (share, Wilson 95 %), laps and lap times per level as JSON on stdout and in OUT/robust.json, and a
    /// figure OUT/robust.png (crash share per level; the spawns on the track by the first level that crashes).
    Robust(robust::Args),
    /// What a run's data lets a camera policy copy (issue 58): a constant, the velocities alone, the run's policy and
    /// the image alone fitted on its D+, with their held-out imitation loss (a copycat shows before the epochs go).
    Probe(probe::Args),
    /// The paper's Fig. 3: auto-labelling and the critic it trains on a constructed 2-d example.
    Demo(tools::DemoArgs),
    /// Throughput of auto-labelling and training.
    Bench(tools::BenchArgs),
    /// The camera policy's training and inference images per second (ResNet-18 at 224x224 by default), on a GPU
    /// where there is one; prints JSON.
    BenchVision(cabc_bench::vision::VisionBenchOptions),
    /// One epoch of a run's configuration timed per phase (each network's fit and its mini-batches' phases,
    /// auto-labelling, a collection step's parts) against its floor (FLOPs at this core's GEMM rate; the expert's
    /// step); prints JSON.
    BenchEpoch(tools::BenchEpochArgs),
    /// One learner's capacity (issue 73): N synthetic actors (a child process) publish real-shaped segments at full
    /// speed through the real intake (zenoh, codec, receipts, ledger, replay) on the embedded router or a standalone
    /// zenohd; steps/s and MB/s absorbed, the learner's CPU per step by stage, the receipts' round trip, the policy's
    /// broadcast to N, and the books (fails when anything was lost). A Markdown table on stdout; --json for all.
    BenchBus(cabc_bench::capacity::BusBenchOptions),
    /// bench-bus's actors (its child process).
    #[command(hide = true)]
    BenchBusActors(cabc_bench::capacity::actors::ActorsArgs),
    /// zenohd's configuration for a run (deploy/SCALE-OUT.md §2), JSON5 on stdout: the links, TLS and access control
    /// of its `[bus.security]` under the router's certificate `<certs>/zenohd.pem` (make-certs.sh --zenohd).
    ZenohdConfig(tools::ZenohdConfigArgs),
    /// The messages a standalone zenohd's access control dropped, from its log (written with
    /// `RUST_LOG=info,zenoh::net::routing::interceptor::access_control=trace`), as JSON by "<subject>: <action> on
    /// <key>" (deploy/SCALE-OUT.md §2).
    AclDenials(tools::AclDenialsArgs),
    /// The reproduction campaign as data: a plan (deploy/campaign/<plan>.toml) of slices of deploy/reproduce.sh,
    /// listed, its runs' states, run in lanes that share its slices, and its tables (deploy/campaign.sh wraps it).
    Campaign(campaign::Args),
    /// Runs over seeds, the campaign's per-run step: each preset's runs `<preset>[-<tag>]-s<k>[-baseline]` (seed
    /// 41 + k), an ended one skipped, one with a checkpoint resumed, any other started (deploy/run-local.sh with
    /// the binaries of CABC_BIN); their results copied to docs/reproduction/<run>/ and each group's figures and table
    /// redrawn (deploy/reproduce.sh builds the binaries and calls it).
    Reproduce(campaign::ReproduceArgs),
    /// A run's processes, supervised (issue 64): the learner, the expert server, the actors and the evaluators of a
    /// run folder's configuration (or the --roles given: a machine that adds actors), each restarted with backoff
    /// when it dies (the learner with --resume), the restarts counted in <run>/supervision.json, a crash loop
    /// (supervision.max_restarts deaths within supervision.window_s) stopping the run with an error that names the
    /// process and its log. deploy/run-local.sh runs it.
    Supervise(supervise::Args),
    /// A supervised run under a seeded schedule of faults (issue 64): every 10-30 s (--every) one of its processes is
    /// killed (SIGKILL) or paused for 5-30 s (SIGSTOP; --faults, --pause); <run>/chaos.json reports the faults, the
    /// restarts, the time each cost, the stalls, the steps published and stored, the duplicates and the early stop.
    /// deploy/chaos.sh runs it on the main job.
    Chaos(supervise::ChaosArgs),
    /// Every segment of a run accounted for (issue 74): each one an actor journalled (<run>/journal/, written by the
    /// actors under `cabc supervise`) is stored once in the learner's final ledger, refused, never sent, in flight at
    /// its actor's end, held by a learner that stopped before its checkpoint, after the run's end, or lost; and the
    /// steps taken and never published. Exits 1 on a lost segment or a ledger that disagrees with the journals.
    Audit(tools::AuditArgs),
}

fn main() -> anyhow::Result<()> {
    cabc_proto::telemetry::init();
    cabc_models::flush_denormals();
    match Cli::parse().command {
        Command::Compare(options) => tools::compare(&options),
        Command::Show(args) => show::run(&args),
        Command::Plots(args) => tools::plots(&args),
        Command::Video(args) => show::video(&args),
        Command::Export(args) => export::run(&args),
        Command::Robust(args) => robust::run(&args),
        Command::Probe(args) => probe::run(&args),
        Command::Demo(args) => tools::demo(&args),
        Command::Bench(args) => tools::bench(&args),
        Command::BenchVision(options) => tools::bench_vision(&options),
        Command::BenchEpoch(args) => tools::bench_epoch(&args),
        Command::BenchBus(options) => tools::bench_bus(&options),
        Command::BenchBusActors(args) => tools::bench_bus_actors(&args),
        Command::ZenohdConfig(args) => tools::zenohd_config(&args),
        Command::AclDenials(args) => tools::acl_denials(&args),
        Command::Campaign(args) => campaign::run(&args),
        Command::Reproduce(args) => campaign::reproduce(&args),
        Command::Supervise(args) => {
            let code = supervise::run(&args)?;
            std::process::exit(code)
        }
        Command::Chaos(args) => {
            let code = supervise::chaos(&args)?;
            std::process::exit(code)
        }
        Command::Audit(args) => {
            let code = tools::audit(&args)?;
            std::process::exit(code)
        }
    }
}

/// Prints `report` as pretty JSON on stdout.
fn print_json(report: &impl serde::Serialize) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(report)?);
    Ok(())
}
