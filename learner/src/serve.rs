//! `learner run`: Algorithm 1 ([`crate::algorithm`]) with the actors over zenoh (`cabc_bus::rollouts`).
//!
//! The learner listens on `bus.listen` (the embedded router of a one-machine run), resumes from the run folder's
//! checkpoint with `resume`, and at the end publishes Stop, writes the final outputs and prints the summary.

use crate::algorithm::{self, Ending};
use crate::learner::Learner;
use crate::rundir::RunDir;
use anyhow::{Context, Result};
use cabc_bus::interrupt::Interrupt;
use cabc_bus::rollouts::ZenohActors;
use cabc_bus::{Bus, Role};
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::ports::Rollouts;
use std::time::Duration;

/// Runs (or resumes) the run in `run_dir` until early stop, `max_epochs` or Ctrl-C.
pub fn run(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<()> {
    let interrupt = Interrupt::on_ctrl_c();
    let keys = Keys::new(&config.run.name)?;
    let timeout = Duration::from_secs_f64(config.bus.epoch_timeout_s);
    let bus = Bus::join(&config.bus, Role::Listen, keys, "learner")
        .context("opening the bus (is another learner already listening on the same endpoint?)")?;
    tracing::info!(
        run = config.run.name,
        dir = %run_dir.path().display(),
        listen = ?config.bus.listen,
        "learner up; waiting for actors"
    );
    // Subscribe first: actors reconnecting to a restarted learner flush what they could not deliver at once.
    let expected = config.actors.count as usize;
    let mut actors = ZenohActors::new(bus, expected, timeout, interrupt)?;
    let mut learner = Learner::open(config, run_dir, resume)?;
    let ending = algorithm::run(&mut learner, &mut actors)?;
    let reason = match &ending {
        Ending::Interrupted => "interrupted".to_string(),
        Ending::EarlyStop(v) => format!(
            "early stop: policy version {v} completed {} laps twice",
            learner.config.collection.eval_laps
        ),
        Ending::MaxEpochs => format!("max_epochs {} reached", learner.config.run.max_epochs),
    };
    let interrupted = ending == Ending::Interrupted;
    if !interrupted {
        actors.stop(&reason)?;
    }
    let summary = learner.finish(&reason, interrupted, actors.rejected())?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    // Give the stop a moment to reach everyone before the router goes away.
    std::thread::sleep(Duration::from_millis(300));
    actors.into_bus().close_blocking()?;
    Ok(())
}
