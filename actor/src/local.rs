//! The actors in-process: [`LocalActors`] is the learner's [`Rollouts`] port without a bus. It runs
//! `actors.count` collectors one after the other with the same [`collect_epoch`] the `actor` binary runs, asks an
//! in-process [`ExpertClient`], and evaluates each version with the same `evaluate` as the eval actor. Used by the
//! tests that run Algorithm 1 in one process, and by anyone who wants a run without processes.

use crate::collect::Collector;
use crate::evaluate::evaluate;
use crate::run::{act, collect_epoch};
use cabc_models::Policy;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EvalReport, PolicyUpdate, Segment, TrajMessage};
use cabc_proto::ports::{
    Collected, ExpertClient, Next, PolicySource, PortError, Rollouts, SegmentSink,
};
use tch::Device;

/// `actors.count` collectors and an evaluator, in this process.
pub struct LocalActors<E: ExpertClient> {
    config: RunConfig,
    collectors: Vec<Collector>,
    expert: E,
    evaluate: bool,
    reports: Vec<EvalReport>,
}

impl<E: ExpertClient> LocalActors<E> {
    /// The actors `actor-0 .. actor-{count-1}` of `config` (the same random streams as the processes of a
    /// distributed run), asking `expert`; with `evaluate`, each version is also evaluated (as `eval-0`).
    pub fn new(config: &RunConfig, expert: E, evaluate: bool) -> Self {
        let collectors = (0..config.actors.count as u64)
            .map(|i| Collector::new(&format!("actor-{i}"), i, config))
            .collect();
        LocalActors {
            config: config.clone(),
            collectors,
            expert,
            evaluate,
            reports: Vec::new(),
        }
    }
}

/// An in-process actor never learns of a newer version mid-epoch: the learner waits for it.
struct Current;

impl PolicySource for Current {
    fn next(&mut self) -> Result<Next, PortError> {
        Err(PortError::Stopped(
            "an in-process actor is driven by the learner".into(),
        ))
    }

    fn interrupted(&mut self) -> Option<Next> {
        None
    }
}

/// Hands segments to the learner's store and adds up the markers' step counts.
struct Store<'a> {
    store: &'a mut dyn FnMut(Segment),
    steps_published: u64,
    steps_taken: u64,
    steps_staged: u64,
}

impl SegmentSink for Store<'_> {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        match message {
            TrajMessage::Segment(segment) => (self.store)(segment),
            TrajMessage::EpochDone(done) => {
                self.steps_published += done.steps;
                self.steps_taken += done.taken;
                self.steps_staged += done.staged;
            }
        }
        Ok(())
    }
}

impl<E: ExpertClient> Rollouts for LocalActors<E> {
    fn collect(
        &mut self,
        update: &PolicyUpdate,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError> {
        let policy = Policy::from_bytes(&update.weights, Device::Cpu)
            .map_err(|e| PortError::Transport(format!("policy version {}: {e}", update.version)))?;
        let mut sink = Store {
            store,
            steps_published: 0,
            steps_taken: 0,
            steps_staged: 0,
        };
        for collector in &mut self.collectors {
            collect_epoch(
                collector,
                update,
                &policy,
                &mut self.expert,
                &mut Current,
                &mut sink,
            )
            .map_err(|e| PortError::Transport(e.to_string()))?;
        }
        if self.evaluate {
            let report = evaluate("eval-0", update.version, &self.config, |input| {
                Ok(act(&policy, input)?)
            })
            .map_err(|e| PortError::Transport(format!("evaluating: {e}")))?;
            self.reports.push(report);
        }
        Ok(Some(Collected {
            steps_published: sink.steps_published,
            steps_taken: sink.steps_taken,
            steps_staged: sink.steps_staged,
            timed_out: false,
            missing: Vec::new(),
            live: self
                .collectors
                .iter()
                .map(|c| c.actor().to_string())
                .collect(),
        }))
    }

    fn evaluations(&mut self) -> Vec<EvalReport> {
        std::mem::take(&mut self.reports)
    }

    fn stop(&mut self, _reason: &str) -> Result<(), PortError> {
        Ok(())
    }
}
