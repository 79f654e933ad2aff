//! `actor`: collects trajectory segments for the learner (or, with `--eval`, evaluates each new policy).
//!
//! Wiring only: the loop is `cabc_actor::run`, its ports are zenoh's (`cabc_bus::ports`): the learner's latest
//! policy on start, then its updates; the expert server's labels for each batch (waiting and retrying while no server
//! answers), or the actor's own under `expert.placement = "in-actor"`; segments and the epoch's "done" marker published
//! reliably on `cabc/<run>/traj/<id>`.

use anyhow::{Context, Result};
use cabc_actor::collect::Collector;
use cabc_actor::journal::{self, Journaled};
use cabc_actor::run::{run_actor, run_evaluator, stop_or_fail, ActorStats};
use cabc_bus::interrupt::Interrupt;
use cabc_bus::outbox::{Batching, ZenohSegments};
use cabc_bus::ports::{Shard, SharedStats, ZenohEvals, ZenohPolicySource};
use cabc_bus::{Bus, Role};
use cabc_models::{PolicyArch, PolicyCheck};
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::PolicyUpdate;
use clap::Parser;

#[derive(Parser)]
#[command(
    name = "actor",
    version,
    about = "The cabc actor: collects segments under the expert/policy mixture"
)]
struct Cli {
    /// Run configuration: a preset (v-b-ref, v-b, v-a-cpu, smoke, ...) or a TOML file.
    #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
    config: String,
    /// This actor's name (a key chunk: letters, digits, '-', '_', '.').
    #[arg(long, default_value = "actor-0")]
    id: String,
    /// Index of this actor's random streams (default: the number at the end of --id, else 0).
    #[arg(long)]
    index: Option<u64>,
    /// Evaluate each new policy from the fixed spawn instead of collecting.
    #[arg(long)]
    eval: bool,
    /// Zenoh endpoints to connect to, overriding the configuration's `bus.connect`.
    #[arg(long)]
    connect: Vec<String>,
    /// The run's journal folder (`<run>/journal`, which `cabc supervise` passes): this process writes what it
    /// publishes, what the learner acknowledged and the steps it took there, for `cabc audit`.
    #[arg(long)]
    journal: Option<std::path::PathBuf>,
}

fn main() -> Result<()> {
    cabc_proto::telemetry::init();
    let cli = Cli::parse();
    let mut config = RunConfig::load(&cli.config)
        .with_context(|| format!("loading configuration {}", cli.config))?;
    cabc_proto::keys::check_chunk(&cli.id)?;
    cabc_proto::telemetry::log_run(&config, &cli.id);
    if !cli.connect.is_empty() {
        config.bus.connect = cli.connect.clone();
    }
    // One inference thread (actors are many, cores few); subnormals flushed as in the learner.
    cabc_models::device::one_cpu_thread();
    let interrupt = Interrupt::on_signals();
    let keys = Keys::new(&config.run.name)?;
    let evaluators = config.actors.evaluators as u64;
    let shard = cli
        .eval
        .then(|| Shard::of_evaluator(&cli.id, cli.index, evaluators))
        .transpose()
        .map_err(anyhow::Error::msg)?;
    let role = if cli.eval { "eval" } else { "actor" };
    let component = format!("{role}/{}", cli.id);
    let bus = Bus::join(&config.bus, Role::Connect, keys, &component).context("joining the bus")?;
    tracing::info!(component, run = config.run.name, "actor started");
    let stats = SharedStats::default();
    let source = ZenohPolicySource::new(&bus, &interrupt, stats.clone())?;
    // An evaluator takes every version of its shard in order; a collector skips to the newest.
    let mut source = match shard {
        Some(shard) => source.every_version(shard),
        None => source,
    };
    let check = PolicyCheck::new(PolicyArch::from_config(&config));
    let mut last = None;
    let mut after_epoch = |update: &PolicyUpdate, actor: &ActorStats| {
        let wire = stats
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .figures(actor.busy);
        let value = actor.metrics(update, bus.rejects.count(), wire);
        bus.metrics_blocking(&value.to_string());
        last = Some(value);
    };
    if shard.is_some() {
        let mut sink = ZenohEvals::new(&bus, &cli.id);
        let ran = run_evaluator(
            &cli.id,
            &config,
            &check,
            &mut source,
            &mut sink,
            &mut after_epoch,
        );
        stop_or_fail(ran, interrupt.is_set())?;
        drop(source);
    } else {
        let index = cli
            .index
            .unwrap_or_else(|| cabc_proto::keys::trailing_number(&cli.id));
        let config = config.for_actor(index);
        let mut expert = cabc_actor::expert::of_run(&config, &bus, &interrupt, stats.clone())?;
        // Restarts under the same id are new incarnations (the learner's ledger keys segments by both).
        let incarnation = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        let journal = journal::begin(cli.journal.as_deref(), &cli.id, incarnation)
            .context("beginning the actor's journal")?;
        let mut sink =
            ZenohSegments::journaled(&bus, &cli.id, &interrupt, stats.clone(), journal.clone())?
                .batching(Batching::of(&config.bus));
        let mut source = source.echoing(sink.echo());
        let mut collector = Collector::new(&cli.id, index, &config)
            .context("the run's track (sim.track)")?
            .with_incarnation(incarnation);
        if let Some(journal) = &journal {
            collector = collector.with_tally(journal::tally(journal.clone()));
        }
        let ran = run_actor(
            &mut collector,
            &check,
            &mut source,
            expert.as_mut(),
            &mut Journaled::new(&mut sink, journal.clone()),
            &mut after_epoch,
        );
        if let Some(journal) = &journal {
            journal::ended(journal, &ran, interrupt.is_set());
        }
        stop_or_fail(ran, interrupt.is_set())?;
    }
    if let Some(value) = last {
        tracing::info!("final metrics: {value}");
    }
    // (The policy source, and with it its subscriptions, is gone: the bus closes.)
    bus.close_blocking()?;
    Ok(())
}
