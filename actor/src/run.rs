//! The actor's loop over its ports (Acme's environment loop): follow the [`PolicySource`], collect each version's
//! share of the epoch under the mixture pi_collect = beta_j pi_beta + (1 - beta_j) pi_theta, hand the segments to the
//! [`SegmentSink`]; or, as the evaluator, drive each version alone and report it to the [`EvalSink`].
//!
//! The same functions run in the `actor` binary over zenoh and in-process in a test ([`crate::local`]).
//!
//! A policy update is checked against the run's architecture ([`PolicyCheck`]: the update's architecture name, the
//! weights' metadata, every tensor's shape) before anything is built from it. A refused update is counted
//! ([`ActorStats::refused_policies`], the metrics' `refused_policies`) and otherwise ignored, as if it had not
//! arrived: an epoch in progress goes on with its policy to its budget (a refused update does not interrupt it), and
//! an actor done with its share waits for the next good version. The actor never exits over a bad update.

use crate::collect::{Collector, Observations};
use crate::evaluate::evaluate;
use cabc_models::{ModelError, Observation, Policy, PolicyCheck};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EpochDone, PolicyUpdate, Segment, TrajMessage};
use cabc_proto::ports::{EvalSink, ExpertClient, Next, PolicySource, PortError, SegmentSink};
use std::time::{Duration, Instant};
use tch::Device;

/// Errors that end an actor.
#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("running the policy: {0}")]
    Model(#[from] ModelError),
    #[error("evaluating: {0}")]
    Evaluate(anyhow::Error),
}

/// What an actor has done since it started.
#[derive(Clone, Debug, Default)]
pub struct ActorStats {
    /// Policy versions followed.
    pub versions: u64,
    /// Steps published.
    pub steps: u64,
    /// Time spent collecting (or evaluating).
    pub busy: Duration,
    /// Policy updates refused (another architecture, malformed weights): ignored, the actor went on.
    pub refused_policies: u64,
}

impl ActorStats {
    /// The figures an actor publishes after every epoch (`metrics/<role>/<id>`) and logs at exit: these, the
    /// transport's (`wire`) and the messages its bus refused.
    pub fn metrics(
        &self,
        update: &PolicyUpdate,
        rejected: u64,
        wire: serde_json::Map<String, serde_json::Value>,
    ) -> serde_json::Value {
        let busy = self.busy.as_secs_f64();
        let mut value = serde_json::json!({
            "version": update.version,
            "beta": update.beta,
            "versions_seen": self.versions,
            "steps": self.steps,
            "steps_per_s": if busy > 0.0 { self.steps as f64 / busy } else { 0.0 },
            "rejected_messages": rejected,
            "refused_policies": self.refused_policies,
        });
        if let Some(object) = value.as_object_mut() {
            object.extend(wire);
        }
        value
    }
}

/// pi_theta(y) for a batch of observations (states, or images with the velocities).
pub fn act(policy: &Policy, input: &Observations) -> Result<Vec<[f32; 2]>, ModelError> {
    let observations: Vec<Observation> = if input.images.is_empty() {
        input.states.iter().map(Observation::State).collect()
    } else {
        input
            .states
            .iter()
            .zip(input.images)
            .map(|(state, image)| Observation::camera(image, state))
            .collect()
    };
    policy.act(&observations)
}

pub use cabc_proto::ports::FAR_AHEAD;

/// The jump from `last` (the version admitted before, if any) to `version` when it is more than [`FAR_AHEAD`].
pub fn far_ahead(last: Option<u64>, version: u64) -> Option<u64> {
    let jump = version.saturating_sub(last?);
    (jump > FAR_AHEAD).then_some(jump)
}

/// A [`PolicySource`] that lets through only the updates that pass the run's [`PolicyCheck`]; the others are logged
/// and counted, never handed on (so they neither start nor interrupt an epoch). A version far ahead of the last one
/// admitted ([`far_ahead`]) is let through but logged.
pub struct Checked<'a> {
    source: &'a mut dyn PolicySource,
    check: &'a PolicyCheck,
    /// Updates refused so far.
    pub refused: u64,
    /// The version of the last update admitted.
    last_version: Option<u64>,
}

impl<'a> Checked<'a> {
    pub fn new(source: &'a mut dyn PolicySource, check: &'a PolicyCheck) -> Self {
        Checked {
            source,
            check,
            refused: 0,
            last_version: None,
        }
    }

    /// The update when it passes the check; else counted and None.
    fn admit(&mut self, next: Next) -> Option<Next> {
        if let Next::Policy(update) = &next {
            if let Err(e) = self.check.check(&update.architecture, &update.weights) {
                self.refused += 1;
                tracing::error!(
                    version = update.version,
                    refused = self.refused,
                    "refusing a policy update: {e}"
                );
                return None;
            }
            if let Some(jump) = far_ahead(self.last_version, update.version) {
                tracing::warn!(
                    version = update.version,
                    last = self.last_version,
                    jump,
                    "a policy version far ahead of the last one followed: not the learner's pace"
                );
            }
            self.last_version = Some(update.version);
        }
        Some(next)
    }

    /// The next version that passes the check, with its policy (`pending` first: a version that interrupted the last
    /// epoch); None on a stop. Refused versions are counted in `stats` and skipped.
    fn next_policy(
        &mut self,
        pending: Option<Next>,
        stats: &mut ActorStats,
    ) -> Result<Option<(PolicyUpdate, Policy)>, ActorError> {
        let mut pending = pending;
        loop {
            let next = match pending.take() {
                Some(next) => next,
                None => self.next()?,
            };
            let update = match next {
                Next::Stop(reason) => {
                    tracing::info!("stop: {reason}");
                    return Ok(None);
                }
                Next::Policy(update) => *update,
            };
            let policy = self.policy_of(&update);
            stats.refused_policies = self.refused;
            if let Some(policy) = policy {
                stats.versions += 1;
                return Ok(Some((update, policy)));
            }
        }
    }

    /// The policy of a checked update (weights for CPU inference); None (counted) if building it still fails.
    fn policy_of(&mut self, update: &PolicyUpdate) -> Option<Policy> {
        match self
            .check
            .policy(&update.architecture, &update.weights, Device::Cpu)
        {
            Ok(policy) => Some(policy),
            Err(e) => {
                self.refused += 1;
                tracing::error!(version = update.version, "refusing policy weights: {e}");
                None
            }
        }
    }
}

impl PolicySource for Checked<'_> {
    fn next(&mut self) -> Result<Next, PortError> {
        loop {
            let next = self.source.next()?;
            if let Some(next) = self.admit(next) {
                return Ok(next);
            }
        }
    }

    fn interrupted(&mut self) -> Option<Next> {
        let next = self.source.interrupted()?;
        self.admit(next)
    }
}

/// Collects this actor's share of epoch `update.version` (`update.steps_per_actor` steps), sends every segment and
/// then the "done with j" marker to `sink`. Returns the steps published and a newer version or a stop that
/// interrupted the epoch.
pub fn collect_epoch(
    collector: &mut Collector,
    update: &PolicyUpdate,
    policy: &Policy,
    expert: &mut dyn ExpertClient,
    source: &mut dyn PolicySource,
    sink: &mut dyn SegmentSink,
) -> Result<(u64, Option<Next>), ActorError> {
    let budget = update.steps_per_actor;
    let first_seq = collector.segments_cut();
    collector.begin_epoch();
    collector.arm_shield(update.shield.as_ref());
    let mut published = 0u64;
    let interrupted = collector.collect(
        budget,
        update.beta,
        update.version,
        expert,
        |input| Ok::<_, ActorError>(act(policy, input)?),
        |out| {
            published += publish(out, sink)?;
            Ok(source.interrupted())
        },
    )?;
    let mut out = Vec::new();
    collector.end_epoch(update.version, &mut out);
    published += publish(&mut out, sink)?;
    // Stopped before its share was whole (its own SIGTERM: a scheduler stops every process at once; or the learner's
    // stop): no marker, as the actor is not done. A short marker would close the learner's epoch short when the
    // learner's own signal comes a moment later; without it the learner sees the actor leave and deals the rest of
    // its share again, or stops.
    if matches!(interrupted, Some(Next::Stop(_))) && collector.taken() < budget {
        tracing::info!(
            version = update.version,
            taken = collector.taken(),
            budget,
            "stopped inside the epoch: no marker"
        );
        return Ok((published, interrupted));
    }
    sink.put(TrajMessage::EpochDone(EpochDone {
        actor: collector.actor().to_string(),
        version: update.version,
        published_unix_ms: update.published_unix_ms,
        segments: collector.segments_cut() - first_seq,
        steps: published,
        taken: collector.taken(),
        staged: collector.staged(),
        shielded: collector.shielded(),
    }))?;
    Ok((published, interrupted))
}

fn publish(out: &mut Vec<Segment>, sink: &mut dyn SegmentSink) -> Result<u64, PortError> {
    let mut steps = 0;
    for segment in out.drain(..) {
        steps += segment.steps.len() as u64;
        sink.put(TrajMessage::Segment(segment))?;
    }
    Ok(steps)
}

/// A collecting actor: follows `source` until a stop, collecting each version's share with the updates that pass
/// `check` (the run's architecture). `after_epoch` runs after each version (metrics).
pub fn run_actor(
    collector: &mut Collector,
    check: &PolicyCheck,
    source: &mut dyn PolicySource,
    expert: &mut dyn ExpertClient,
    sink: &mut dyn SegmentSink,
    mut after_epoch: impl FnMut(&PolicyUpdate, &ActorStats),
) -> Result<ActorStats, ActorError> {
    let mut source = Checked::new(source, check);
    let mut stats = ActorStats::default();
    let mut pending = None;
    while let Some((update, policy)) = source.next_policy(pending.take(), &mut stats)? {
        let started = Instant::now();
        let (steps, interrupted) =
            collect_epoch(collector, &update, &policy, expert, &mut source, sink)?;
        stats.refused_policies = source.refused;
        stats.steps += steps;
        stats.busy += started.elapsed();
        tracing::info!(
            version = update.version,
            steps,
            secs = started.elapsed().as_secs_f64(),
            "epoch collected"
        );
        pending = interrupted;
        after_epoch(&update, &stats);
    }
    Ok(stats)
}

/// The evaluator: drives each new version that passes `check` alone from the fixed spawn and reports it, until a
/// stop.
pub fn run_evaluator(
    id: &str,
    config: &RunConfig,
    check: &PolicyCheck,
    source: &mut dyn PolicySource,
    sink: &mut dyn EvalSink,
    mut after_epoch: impl FnMut(&PolicyUpdate, &ActorStats),
) -> Result<ActorStats, ActorError> {
    let mut source = Checked::new(source, check);
    let mut stats = ActorStats::default();
    while let Some((update, policy)) = source.next_policy(None, &mut stats)? {
        let started = Instant::now();
        let report = evaluate(id, update.version, config, |input| Ok(act(&policy, input)?))
            .map_err(ActorError::Evaluate)?;
        stats.steps += report.steps;
        stats.busy += started.elapsed();
        tracing::info!(
            version = update.version,
            laps = report.laps,
            end = %report.end_reason,
            secs = started.elapsed().as_secs_f64(),
            "evaluated"
        );
        sink.report(report)?;
        after_epoch(&update, &stats);
    }
    Ok(stats)
}

/// The end of a collector's or evaluator's loop: a stop by Ctrl-C or a scheduler's SIGTERM (`interrupted`) while the
/// learner (or the expert server) was already gone is a stop, not a failure (what could not be sent is counted in the
/// metrics, `segments_lost`); any other error is the process's.
pub fn stop_or_fail(
    ran: Result<ActorStats, ActorError>,
    interrupted: bool,
) -> Result<(), ActorError> {
    match ran {
        Err(ActorError::Port(PortError::Stopped(why))) if interrupted => {
            tracing::warn!("stopped while the bus was down ({why})");
            Ok(())
        }
        ran => ran.map(|_| ()),
    }
}

#[cfg(test)]
mod tests {
    use super::{far_ahead, FAR_AHEAD};

    #[test]
    fn a_version_far_ahead_of_the_last_one_is_flagged() {
        // The first version an actor sees (it joined late, or the learner resumed) is no jump.
        assert_eq!(far_ahead(None, 1004), None);
        assert_eq!(far_ahead(Some(3), 4), None);
        assert_eq!(far_ahead(Some(3), 3 + FAR_AHEAD), None);
        assert_eq!(far_ahead(Some(3), 4 + FAR_AHEAD), Some(FAR_AHEAD + 1));
        // Issue 57's replayed update: version 4 raised by 1,000.
        assert_eq!(far_ahead(Some(3), 1004), Some(1001));
        // A version back (the learner's after a forged one) is no jump ahead.
        assert_eq!(far_ahead(Some(1004), 5), None);
    }
}
