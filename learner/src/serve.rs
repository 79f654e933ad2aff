//! `learner run`: Algorithm 1 (`cabc_learning::algorithm`) with the actors over zenoh (`cabc_bus::rollouts`), or in this
//! process (`--local`).
//!
//! The learner listens on `bus.listen` (the embedded router of a one-machine run; with `bus.listen = []` it is a
//! client of the standalone router of `bus.connect`, deploy/SCALE-OUT.md §2), resumes from the run folder's
//! checkpoint with `resume`, and at the end publishes Stop, writes the final outputs and prints the summary.

use crate::watch::BusMetrics;
use anyhow::{Context, Result};
use cabc_actor::local::LocalActors;
use cabc_bus::interrupt::Interrupt;
use cabc_bus::rollouts::{Waits, ZenohActors};
use cabc_bus::{Bus, Role};
use cabc_expert::relabel::{Background, Expert, Relabeller};
use cabc_learning::algorithm::{self, Ending};
use cabc_learning::learner::Learner;
use cabc_outputs::RunDir;
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::ports::Rollouts;
use cabc_runfolder::journal::{self, LearnerEvent, LearnerJournal};
use cabc_runfolder::Status;
use std::collections::BTreeMap;
use std::time::Duration;

/// Runs (or resumes) the run in `run_dir` until early stop, `max_epochs` or Ctrl-C.
pub fn run(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<()> {
    let interrupt = Interrupt::on_signals();
    let keys = Keys::new(&config.run.name)?;
    let waits = Waits {
        epoch_timeout: Duration::from_secs_f64(config.bus.epoch_timeout_s),
        no_actor_timeout: Duration::from_secs_f64(config.bus.no_actor_timeout_s),
    };
    let bus = Bus::join(&config.bus, Role::of_learner(&config.bus), keys, "learner")
        .context("opening the bus (is another learner already listening on the same endpoint?)")?;
    tracing::info!(
        run = config.run.name,
        dir = %run_dir.path().display(),
        listen = ?config.bus.listen,
        "learner up; waiting for actors"
    );
    // Subscribe first: actors reconnecting to a restarted learner flush what they could not deliver at once.
    let metrics = Box::new(BusMetrics::new(bus.metrics_out()));
    let mut actors = ZenohActors::new(bus, &config, waits, interrupt)?;
    // What the router's access control refused (this process's router: zenoh logs its decisions only at TRACE).
    let acl_denials = Box::new(cabc_proto::telemetry::acl_denials);
    let folder = run_dir.path().to_path_buf();
    let mut learner = cabc_outputs::learner_on_bus(config, run_dir, resume, metrics, acl_denials)?;
    // The run's journal (`cabc audit`): this process's start, the segments it refused, its end.
    let journal = std::rc::Rc::new(
        LearnerJournal::open(&folder.join(journal::JOURNAL))
            .context("opening the learner's journal")?,
    );
    journal.record(&LearnerJournal::began(actors.incarnation(), resume));
    let refusals = journal.clone();
    learner = learner.with_refusals(Box::new(move |id, why| {
        refusals.record(&LearnerEvent::Refused {
            actor: id.actor.clone(),
            incarnation: id.incarnation,
            seq: id.seq,
            why: why.to_string(),
        })
    }));
    // Under a supervisor (`cabc supervise`, which writes supervision.json before it starts the learner): its restarts
    // by role, read at each epoch's end.
    if Status::read(&folder).is_some() {
        learner = learner.with_restarts(Box::new(move || {
            Status::read(&folder)
                .map(|s| s.restarts.into_iter().collect())
                .unwrap_or_default()
        }));
    }
    let reason = run_to_the_end(&mut learner, &mut actors)?;
    let mut unstored: BTreeMap<(String, u64), Vec<u64>> = BTreeMap::new();
    for id in actors.unstored() {
        unstored
            .entry((id.actor, id.incarnation))
            .or_default()
            .push(id.seq);
    }
    for ((actor, incarnation), seqs) in unstored {
        journal.record(&LearnerEvent::Unstored {
            actor,
            incarnation,
            seqs,
        });
    }
    journal.record(&LearnerEvent::Ended { reason });
    // Give the stop a moment to reach everyone before the router goes away.
    std::thread::sleep(Duration::from_millis(300));
    actors.into_bus().close_blocking()?;
    Ok(())
}

/// `learner run --local`: the same Algorithm 1 in one process, with `actors.count` in-process collectors, the
/// expert answering in the background (`Background`: a half's batch solved on every core while the other half
/// steps) and the evaluator beside the collection; no bus. The policy of collection and evaluation runs on the learner's device. For a seed it gives the numbers of
/// the distributed run (the same streams, segment order and code; `tests/tests/local.rs`), except that every
/// version's evaluation arrives before the next epoch, so an early stop can come a few epochs sooner.
pub fn run_local(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<()> {
    anyhow::ensure!(
        config.sim.actor_tracks.is_empty(),
        "sim.actor_tracks needs each actor in its own process with its own expert (deploy/run-local.sh); \
         learner run --local shares one expert on sim.track"
    );
    let interrupt = Interrupt::on_signals();
    let expert = Expert::from_config(&config).context("building the MPCC")?;
    let expert = Background::new(Relabeller::new(
        expert,
        config.expert.max_streams,
        config.expert.max_batch,
    ));
    let dir = run_dir.path().to_path_buf();
    let mut learner = cabc_outputs::learner(config, run_dir, resume)?;
    tracing::info!(
        run = learner.config().run.name,
        dir = %dir.display(),
        device = ?learner.device(),
        "learner up, actors in-process"
    );
    let mut actors = LocalActors::new(learner.config(), expert, true)?
        .on_device(learner.device())
        .with_interrupt(interrupt);
    run_to_the_end(&mut learner, &mut actors).map(drop)
}

/// Algorithm 1 until it ends, then the stop, the final outputs and the summary (printed); the reason it ended.
fn run_to_the_end(learner: &mut Learner, actors: &mut dyn Rollouts) -> Result<String> {
    let ending = algorithm::run(learner, actors)?;
    let reason = match &ending {
        Ending::Interrupted => "interrupted".to_string(),
        Ending::EarlyStop(v) => format!(
            "early stop: policy version {v} completed {} laps twice",
            learner.config().collection.eval_laps
        ),
        Ending::MaxEpochs => format!("max_epochs {} reached", learner.config().run.max_epochs),
    };
    let interrupted = ending == Ending::Interrupted;
    if !interrupted {
        actors.stop(&reason)?;
    }
    let summary = learner.finish(&reason, interrupted, actors.rejected())?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(reason)
}
