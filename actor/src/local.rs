//! The actors in-process: [`LocalActors`] is the learner's [`Rollouts`] port without a bus. It runs
//! `actors.count` collectors one after the other with the same [`collect_epoch`] the `actor` binary runs, asks an
//! in-process [`ExpertClient`], and evaluates each version with the same `evaluate` as the eval actor. Used by the
//! tests that run Algorithm 1 in one process, and by anyone who wants a run without processes.

use crate::collect::Collector;
use crate::evaluate::evaluate;
use crate::run::{act, collect_epoch};
use cabc_bus::interrupt::Interrupt;
use cabc_models::Policy;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{
    EvalReport, ExpertAnswer, ExpertQuery, PolicyUpdate, Segment, TrajMessage,
};
use cabc_proto::ports::{
    Collected, CollectionTimes, ExpertClient, Next, Pending, PolicySource, PortError, Rollouts,
    SegmentSink,
};
use std::thread::JoinHandle;
use std::time::Instant;
use tch::Device;

/// `actors.count` collectors and an evaluator, in this process.
pub struct LocalActors<E: ExpertClient> {
    config: RunConfig,
    collectors: Vec<Collector>,
    expert: E,
    evaluate: bool,
    reports: Vec<EvalReport>,
    /// Where the policy runs for collection and evaluation (the learner's device in `learner run --local`).
    device: Device,
    interrupt: Option<Interrupt>,
    /// Whether a version was gathered yet: the first one names the collectors' incarnation.
    started: bool,
}

impl<E: ExpertClient> LocalActors<E> {
    /// The actors `actor-0 .. actor-{count-1}` of `config` (the same random streams as the processes of a
    /// distributed run), asking `expert`; with `evaluate`, each version is also evaluated (as `eval-0`).
    pub fn new(
        config: &RunConfig,
        expert: E,
        evaluate: bool,
    ) -> Result<Self, cabc_sim::TrackError> {
        let collectors = (0..config.actors.count as u64)
            .map(|i| Collector::new(&format!("actor-{i}"), i, config))
            .collect::<Result<_, _>>()?;
        Ok(LocalActors {
            config: config.clone(),
            collectors,
            expert,
            evaluate,
            reports: Vec::new(),
            device: Device::Cpu,
            interrupt: None,
            started: false,
        })
    }

    /// The same actors running the policy on `device`: on a GPU each half of an actor's environments is one batch
    /// of the policy there.
    pub fn on_device(mut self, device: Device) -> Self {
        self.device = device;
        self
    }

    /// The same actors, stopping at the next epoch boundary once `interrupt` is set (Ctrl-C).
    pub fn with_interrupt(mut self, interrupt: Interrupt) -> Self {
        self.interrupt = Some(interrupt);
        self
    }

    fn is_interrupted(&self) -> bool {
        self.interrupt.as_ref().is_some_and(Interrupt::is_set)
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
    steps_shielded: u64,
}

impl SegmentSink for Store<'_> {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        match message {
            TrajMessage::EpochDone(done) => {
                self.steps_published += done.steps;
                self.steps_taken += done.taken;
                self.steps_staged += done.staged;
                self.steps_shielded += done.shielded;
            }
            message => message
                .into_segments()
                .into_iter()
                .for_each(&mut *self.store),
        }
        Ok(())
    }
}

impl<E: ExpertClient> Rollouts for LocalActors<E> {
    /// Nothing to send: in-process the collection runs in [`Rollouts::gather`], on the learner's thread, so an
    /// overlapped run (`collection.overlap`) here has the numbers of one over the bus, not its wall clock.
    fn publish(&mut self, _update: &PolicyUpdate) -> Result<(), PortError> {
        Ok(())
    }

    fn gather(
        &mut self,
        update: &PolicyUpdate,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError> {
        if self.is_interrupted() {
            return Ok(None);
        }
        // The collectors' incarnation is the first version they collect with: 0 in a fresh run, the epoch it goes
        // on from in a resumed one. Their segments' seqs start again at 0 either way, and the resumed run's ledger
        // holds the first incarnation's: under the same one, every new segment would be dropped as a duplicate
        // until its seq passed the old ones (issue 56's resumed V-C at 224x224 lost its last 13 epochs' data so).
        if !self.started {
            self.started = true;
            for collector in &mut self.collectors {
                collector.set_incarnation(update.version);
            }
        }
        // The collectors run libtorch as an actor's process does, one CPU thread (the learner's fits set the same):
        // beside the evaluation and the expert's threads, a team of OpenMP threads would spin against them.
        cabc_models::device::one_cpu_thread();
        let policy = Policy::from_bytes(&update.weights, self.device)
            .map_err(|e| PortError::Transport(format!("policy version {}: {e}", update.version)))?;
        let evaluation = self
            .evaluate
            .then(|| evaluate_beside(&self.config, update, self.device))
            .transpose()?;
        let mut sink = Store {
            store,
            steps_published: 0,
            steps_taken: 0,
            steps_staged: 0,
            steps_shielded: 0,
        };
        let mut times = CollectionTimes::default();
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
            times.add(&collector.times());
        }
        if let Some(evaluation) = evaluation {
            let (report, seconds) = evaluation
                .join()
                .map_err(|_| PortError::Transport("the evaluation's thread panicked".into()))?
                .map_err(|e| PortError::Transport(format!("evaluating: {e:#}")))?;
            times.evaluate_s = seconds;
            self.reports.push(report);
        }
        Ok(Some(Collected {
            steps_published: sink.steps_published,
            steps_taken: sink.steps_taken,
            steps_staged: sink.steps_staged,
            steps_shielded: sink.steps_shielded,
            timed_out: false,
            missing: Vec::new(),
            live: self
                .collectors
                .iter()
                .map(|c| c.actor().to_string())
                .collect(),
            times: Some(times),
        }))
    }

    fn evaluations(&mut self) -> Vec<EvalReport> {
        std::mem::take(&mut self.reports)
    }

    fn interrupted(&self) -> bool {
        self.is_interrupted()
    }

    fn stop(&mut self, _reason: &str) -> Result<(), PortError> {
        Ok(())
    }
}

/// The evaluation of `update` (as `eval-0`) on a thread of its own, beside the collection: its report and its wall
/// clock. The thread loads its own copy of the policy on `device` and runs libtorch as the eval actor's process does
/// (one CPU thread, subnormals flushed): two teams of OpenMP threads on a small machine spin against each other
/// (a 2-core machine's first epoch at 32x32 took 10 times as long).
fn evaluate_beside(
    config: &RunConfig,
    update: &PolicyUpdate,
    device: Device,
) -> Result<JoinHandle<anyhow::Result<(EvalReport, f64)>>, PortError> {
    let (config, version, weights) = (config.clone(), update.version, update.weights.clone());
    std::thread::Builder::new()
        .name("eval-0".into())
        .spawn(move || {
            let started = Instant::now();
            cabc_models::device::one_cpu_thread();
            let policy = Policy::from_bytes(&weights, device)
                .map_err(|e| anyhow::anyhow!("policy version {version}: {e}"))?;
            let report = evaluate("eval-0", version, &config, |input| Ok(act(&policy, input)?))?;
            Ok((report, started.elapsed().as_secs_f64()))
        })
        .map_err(|e| PortError::Transport(format!("starting the evaluation's thread: {e}")))
}

/// An in-process expert client that answers a relabelling only when its answers are asked for
/// ([`ExpertClient::receive`]), as a server over the bus does, so that [`Collector::collect`] has several in flight;
/// tests of the halves use it. `most_in_flight` is the most that were at once.
pub struct Deferred<C: ExpertClient> {
    pub inner: C,
    waiting: Vec<(u64, Vec<ExpertQuery>)>,
    next: u64,
    pub most_in_flight: usize,
}

impl<C: ExpertClient> Deferred<C> {
    pub fn new(inner: C) -> Self {
        Deferred {
            inner,
            waiting: Vec::new(),
            next: 0,
            most_in_flight: 0,
        }
    }

    /// Relabellings sent and neither received nor cancelled.
    pub fn in_flight(&self) -> usize {
        self.waiting.len()
    }
}

impl<C: ExpertClient> ExpertClient for Deferred<C> {
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        self.inner.relabel(queries)
    }

    fn send(&mut self, queries: Vec<ExpertQuery>) -> Result<Pending, PortError> {
        self.next += 1;
        self.waiting.push((self.next, queries));
        self.most_in_flight = self.most_in_flight.max(self.waiting.len());
        Ok(Pending::InFlight(self.next))
    }

    fn cancel(&mut self, pending: Pending) {
        if let Pending::InFlight(id) = pending {
            self.waiting.retain(|(i, _)| *i != id);
        }
    }

    fn receive(&mut self, pending: Pending) -> Result<Vec<ExpertAnswer>, PortError> {
        let id = match pending {
            Pending::Answered(answers) => return Ok(answers),
            Pending::InFlight(id) => id,
        };
        let at = self.waiting.iter().position(|(i, _)| *i == id);
        let (_, queries) = at
            .map(|at| self.waiting.remove(at))
            .ok_or_else(|| PortError::Transport(format!("request {id} is not in flight")))?;
        self.inner.relabel(queries)
    }
}
