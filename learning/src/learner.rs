//! What the learner holds between epochs of Algorithm 1 ([`crate::algorithm`]): D+, D? and D- (the replay), the
//! three networks and their optimisers (the trainer), the exactly-once ledger, the evaluations, the epochs' records
//! and the checkpoint; and, within an epoch, its record. It keeps its checkpoint through one port, a [`Checkpointer`]
//! (the run folder's, [`InFolder`]; one in memory for tests), and writes everything else through another, a [`Sink`]
//! (the cabc-outputs crate has the run folder's, the `learner` binary the bus's); what it reads of the bus besides
//! the actors' port, the access control's refusals, is given to it too ([`AclDenials`]).

use crate::autolabel::{autolabel_replay, AutolabelOptions};
use crate::checkpoint::CheckpointError;
use crate::checkpointer::{Checkpointer, InFolder};
use crate::evaluations::Evaluations;
use crate::record::Record;
use crate::replay::{Checked, Frames, Replay};
use crate::schedule::Schedule;
use crate::sink::{Sink, SinkError};
use crate::state::{LearnerState, StateError};
use crate::summary::{LapTime, Restarts, Summary, RESTARTED_ROLES};
use crate::train::{TrainError, Trainer};
use cabc_models::device::parse_device;
use cabc_models::Network;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EvalReport, Outcome, PolicyUpdate, Segment, SegmentId, ShieldNets};
use cabc_proto::ports::{Collected, PortError};
use cabc_sim::track::Track;
use std::collections::{BTreeMap, HashSet};
use std::path::PathBuf;
use tch::Device;

mod epoch;
use epoch::Epoch;

/// Errors that end the learner.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error("the actors' port: {0}")]
    Port(#[from] PortError),
    #[error("training: {0}")]
    Train(#[from] TrainError),
    #[error("the learner state: {0}")]
    State(#[from] StateError),
    #[error("the checkpoint: {0}")]
    CheckpointFile(#[from] CheckpointError),
    #[error("writing the run's outputs: {0}")]
    Sink(#[from] SinkError),
    #[error("{0}")]
    Checkpoint(String),
    #[error("the track (sim.track): {0}")]
    Track(#[from] cabc_sim::TrackError),
}

/// The access control's refusals so far, by "<subject>: <action> on <key>", as the side that knows the bus counts
/// them (the `learner` binary: its router's, `cabc_proto::telemetry::acl_denials`): the `acl_denied` column, its
/// warning and the summary's. In process there is no bus, and nothing refused: `Box::new(BTreeMap::new)`.
pub type AclDenials = Box<dyn Fn() -> BTreeMap<String, u64>>;

/// Told each segment the learner refuses, and why.
pub type Refusals = Box<dyn FnMut(&SegmentId, &str)>;

/// Everything the learner holds. Made with [`Learner::new`] and [`Learner::restore`] (a run folder's:
/// [`Learner::open`]); Algorithm 1 ([`crate::algorithm::run`]) drives it an epoch at a time ([`Learner::begin_epoch`],
/// [`Learner::policy_update`], [`Learner::store`], [`Learner::partition`], [`Learner::autolabel`], its training,
/// [`Learner::on_eval`], [`Learner::end_epoch`]); the binaries end it ([`Learner::finish`]).
pub struct Learner {
    config: RunConfig,
    trainer: Trainer,
    /// D+, D?, D- and the dynamics-only store.
    replay: Replay,
    /// The records, the evaluations, the ledger: what the checkpoint saves besides networks and replay.
    state: LearnerState,
    checkpointer: Box<dyn Checkpointer>,
    sink: Box<dyn Sink>,
    acl_denials: AclDenials,
    restarts: Option<Restarts>,
    /// Told each segment refused and why ([`Learner::with_refusals`]).
    refusals: Option<Refusals>,
    /// The segments of the epoch being collected, until [`Learner::partition`].
    d_new: Vec<Checked>,
    /// Every segment offered this epoch (stored, a copy, refused): the epoch's checkpoint settles them, and their
    /// actors may forget them ([`Learner::settled`]).
    settled: Vec<SegmentId>,
    epoch: Epoch,
    expert_streams: HashSet<(String, u32, u64)>,
    /// The track's half-width (off-track spawns in [`Provenance`]).
    half_width: f64,
}

impl Learner {
    /// The learner of the run folder `folder`: [`Learner::new`] with its checkpoint there ([`InFolder`]:
    /// `folder/checkpoint`, and D+'s image logs), [`Learner::restore`]d.
    pub fn open(
        config: RunConfig,
        folder: PathBuf,
        sink: Box<dyn Sink>,
        acl_denials: AclDenials,
        resume: bool,
    ) -> Result<Self, LearnerError> {
        let checkpointer = Box::new(InFolder::new(folder));
        Self::new(config, sink, checkpointer, acl_denials)?.restore(resume)
    }

    /// The learner of `config`, assembled: its networks on `training.device`, an empty replay and state, its
    /// checkpoint kept with `checkpointer`, its outputs written through `sink` and the access control's refusals read
    /// from `acl_denials`. It runs once [`Learner::restore`]d.
    pub fn new(
        config: RunConfig,
        sink: Box<dyn Sink>,
        checkpointer: Box<dyn Checkpointer>,
        acl_denials: AclDenials,
    ) -> Result<Self, LearnerError> {
        let device = parse_device(&config.training.device).map_err(TrainError::from)?;
        let state = LearnerState::default();
        let half_width = Track::constraint_of(&config.sim)?;
        Ok(Learner {
            trainer: Trainer::with_device(&config, device),
            replay: Replay::from_config(&config),
            epoch: Epoch::new(state.next_epoch, &state.ledger),
            state,
            checkpointer,
            sink,
            acl_denials,
            restarts: None,
            refusals: None,
            settled: Vec::new(),
            d_new: Vec::new(),
            expert_streams: HashSet::new(),
            half_width,
            config,
        })
    }

    /// Starts the run: a fresh one, or with `resume` the checkpoint's (refused without `resume` when the
    /// checkpointer holds one, and with it when it holds none); then opens the sink with what the run wrote so far.
    pub fn restore(mut self, resume: bool) -> Result<Self, LearnerError> {
        match (self.checkpointer.exists(), resume) {
            (true, true) => self.resume()?,
            (false, false) => self.start()?,
            (true, false) => {
                return Err(LearnerError::Checkpoint(format!(
                    "{} holds a checkpoint: pass --resume to continue that run, or --fresh to start over",
                    self.checkpointer
                )))
            }
            (false, true) => {
                return Err(LearnerError::Checkpoint(format!(
                    "{} holds no checkpoint to resume: nothing was started; drop --resume to start a new run",
                    self.checkpointer
                )))
            }
        }
        self.epoch = Epoch::new(self.state.next_epoch, &self.state.ledger);
        self.sink.open(&self.state.history());
        Ok(self)
    }

    /// A fresh run: the policy's trunk from `observation.pretrained` (or not), said in the summary.
    fn start(&mut self) -> Result<(), LearnerError> {
        tracing::info!(
            d_plus_capacity = self.replay.plus.capacity(),
            capacity = self.config.replay.capacity,
            max_bytes = self.config.replay.max_bytes,
            "replay"
        );
        self.state.trunk_init = Some(self.trainer.init_trunk()?);
        Ok(())
    }

    /// The checkpoint's run: its networks and optimisers, its replay and the learner state.
    fn resume(&mut self) -> Result<(), LearnerError> {
        let (parts, replay) = self.checkpointer.load()?;
        self.state = LearnerState::load(&*parts)?;
        self.trainer.load(&*parts)?;
        self.replay = replay
            .with_frames(Frames::of(&self.config))
            .with_dynamics_only(self.config.replay.dynamics_only);
        tracing::info!(
            epoch = self.state.next_epoch,
            d_plus = self.replay.len_plus(),
            d_uncertain = self.replay.len_uncertain(),
            "resumed from {}",
            parts.path().display()
        );
        Ok(())
    }

    /// Tells `refusals` each segment [`Learner::store`] refuses, and why (the run's journal, for `cabc audit`).
    pub fn with_refusals(mut self, refusals: Refusals) -> Self {
        self.refusals = Some(refusals);
        self
    }

    /// Reads the supervisor's restarts at each epoch's end (a run under `cabc supervise`).
    pub fn with_restarts(mut self, restarts: Restarts) -> Self {
        self.restarts = Some(restarts);
        self
    }

    /// The run's configuration.
    pub fn config(&self) -> &RunConfig {
        &self.config
    }

    /// The device the networks train on (`training.device`).
    pub fn device(&self) -> Device {
        self.trainer.device()
    }

    /// The run's schedule, the trainer's ([`Trainer::schedule`]), which Algorithm 1's loop reads.
    pub(crate) fn schedule(&self) -> &Schedule {
        self.trainer.schedule()
    }

    /// The epoch the run goes on with (0 for a fresh run).
    pub fn next_epoch(&self) -> u64 {
        self.state.next_epoch
    }

    /// Every epoch's record so far (`metrics.csv`'s rows).
    pub fn rows(&self) -> &[Record] {
        &self.state.rows
    }

    /// The evaluations taken in, the best version and the early stop.
    pub fn evaluations(&self) -> &Evaluations {
        &self.state.evaluations
    }

    /// The version kept by the early stop, once the second evaluation that completed `eval_laps` laps came in.
    pub fn early_stop(&self) -> Option<u64> {
        self.state.evaluations.early_stop()
    }

    /// (pi_j, beta_j) as the actors receive it, with each actor's step budget for the epoch.
    pub fn policy_update(&mut self, epoch: u64) -> PolicyUpdate {
        let weights = self.trainer.policy_bytes();
        self.state.evaluations.publish(epoch, weights.clone());
        self.progress(epoch, "collecting");
        PolicyUpdate {
            version: epoch,
            beta: self.config.beta(epoch),
            architecture: self.trainer.policy_architecture(),
            weights,
            steps_per_actor: self.config.steps_per_actor(epoch),
            published_unix_ms: unix_ms(),
            shield: (self.config.collection.shield > 0.0 && self.trainer.critic_trained()).then(
                || ShieldNets {
                    dynamics: self.trainer.dynamics().to_bytes(),
                    critic: self.trainer.critic().to_bytes(),
                },
            ),
        }
    }

    /// Begins epoch `epoch`: its record (with beta_j), its clock and its counts (what the ledger stored so far, no
    /// incomplete steps, no D? steps).
    pub fn begin_epoch(&mut self, epoch: u64) {
        self.epoch = Epoch::new(epoch, &self.state.ledger);
        self.epoch.record.real("beta", self.config.beta(epoch), 6);
    }

    /// Takes in a segment of D_new, exactly once (the ledger drops a duplicate). A segment tagged with a policy
    /// version this learner never published (a forged or replayed update's, issue 57), or that the replay would
    /// not take (images not of the run's observation size, [`Replay::check_segment`]), is refused and counted in
    /// `segments_not_stored` before the ledger sees it, as an evaluation of such a version is. This is the one check
    /// of a segment: it waits in D_new as [`Checked`], and [`Learner::partition`] stores it and counts it stored.
    pub fn store(&mut self, segment: Segment) {
        let (actor, seq, id) = (segment.actor.clone(), segment.seq, SegmentId::of(&segment));
        self.settled.push(id.clone());
        let published = self.state.evaluations.published();
        if published.is_none_or(|published| segment.policy_version > published) {
            tracing::warn!(
                actor,
                seq,
                version = segment.policy_version,
                published = ?published,
                "segment of a policy version not published: refused"
            );
            self.refuse(&id, "a policy version this learner has not published");
            return;
        }
        let steps = segment.steps.len();
        let checked = match self.replay.checked(segment) {
            Ok(checked) => checked,
            Err(e) => {
                tracing::warn!(actor, seq, steps, "segment refused: {e}");
                self.refuse(&id, &e.to_string());
                return;
            }
        };
        if self.state.ledger.seen(checked.segment()) {
            tracing::warn!(actor, seq, "duplicate segment dropped");
            return;
        }
        self.state.ledger.admit(checked.segment());
        self.d_new.push(checked);
    }

    /// Counts segment `id` refused (`segments_not_stored`) and tells [`Learner::with_refusals`]'s hook why.
    fn refuse(&mut self, id: &SegmentId, why: &str) {
        self.state.segments_not_stored += 1;
        if let Some(refusals) = &mut self.refusals {
            refusals(id, why);
        }
    }

    /// Partitions D_new, as the actors closed its collection (`collected`), into D+' (laps) and D?' (failures;
    /// unfinished steps go to the dynamics-only store) and adds them to D+ and D?. Segments are added in (actor,
    /// incarnation, seq) order, whatever order the bus delivered them in, so a distributed run with a given seed is
    /// as reproducible as an in-process one. Puts the collection's time and the actors' counts, what the epoch
    /// stored, and where its D? steps came from. D_new's rows are the critic's next held-out set
    /// ([`Replay::begin_epoch`]).
    pub fn partition(&mut self, collected: &Collected) {
        self.collected(collected);
        self.replay.begin_epoch();
        let mut d_new = std::mem::take(&mut self.d_new);
        d_new.sort_by(|a, b| {
            let (a, b) = (a.segment(), b.segment());
            (&a.actor, a.incarnation, a.seq).cmp(&(&b.actor, b.incarnation, b.seq))
        });
        for checked in d_new {
            let segment = checked.segment();
            self.expert_lap_time(segment);
            if segment.outcome == Outcome::Incomplete {
                self.epoch.incomplete_steps += segment.steps.len() as u64;
            }
            self.replay.add_checked(&checked);
            self.state.ledger.stored(segment);
            let flush = self.config.collection.flush;
            self.epoch.provenance.add(segment, flush, self.half_width);
        }
        let (ledger, t) = (&self.state.ledger, &mut self.epoch);
        let record = &mut t.record;
        let stored = ledger.stored_steps - t.stored_before.0;
        record.count("steps_collected", stored);
        record.count("segments", ledger.stored_segments - t.stored_before.1);
        // Cut by the budget: dynamics only, never labelled.
        record.count("incomplete_steps", t.incomplete_steps);
        record.real(
            "incomplete_share",
            t.incomplete_steps as f64 / stored.max(1) as f64,
            4,
        );
        record.count("uncertain_truncating", t.provenance.truncating);
        record.count("uncertain_spawn", t.provenance.spawn);
        record.count("uncertain_patience", t.provenance.patience);
        record.count("uncertain_failed_lap", t.provenance.failed_lap);
        record.count("expert_failures", t.provenance.expert_failures);
        record.count("segments_not_stored", self.state.segments_not_stored);
    }

    /// The collection's time (from the epoch's start, its publication, to its close; under `collection.overlap`
    /// the epoch's training ran within it) and the actors' own counts (their markers), into the record and to the
    /// sinks.
    fn collected(&mut self, collected: &Collected) {
        let record = &mut self.epoch.record;
        record.real("collect_s", self.epoch.started.elapsed().as_secs_f64(), 3);
        record.count("steps_published", collected.steps_published);
        record.count("steps_taken", collected.steps_taken);
        record.count("steps_staged", collected.steps_staged);
        if self.config.collection.shield > 0.0 {
            record.count("steps_shielded", collected.steps_shielded);
        }
        record.flag("closed_by_timeout", collected.timed_out);
        if let Some(t) = &collected.times {
            record.real("collect_observe_s", t.observe_s, 3);
            record.real("collect_policy_s", t.policy_s, 3);
            record.real("collect_expert_s", t.expert_s, 3);
            record.real("collect_step_s", t.step_s, 3);
            record.real("collect_store_s", t.store_s, 3);
            record.real("evaluate_s", t.evaluate_s, 3);
        }
        self.sink.collected(record.epoch(), collected);
    }

    /// Complete laps driven by the expert alone (beta = 1) give the expert's lap time: every lap segment of an
    /// episode after its first starts at the start line.
    fn expert_lap_time(&mut self, segment: &Segment) {
        if segment.outcome == Outcome::Lap
            && segment.policy_version == 0
            && self.config.beta(0) >= 1.0
        {
            let stream = (segment.actor.clone(), segment.env, segment.episode);
            if !self.expert_streams.insert(stream) {
                let seconds = segment.steps.len() as f64 * cabc_sim::env::DT;
                self.state.expert_lap_times.push(seconds);
                self.sink.expert_lap(seconds);
            }
        }
    }

    /// Auto-labels D? when `due` (eq. (19)) and makes what stays in it D-. Puts the points removed and the rho used
    /// (0 and `algorithm.rho` when not due, or when D? holds fewer than `algorithm.autolabel_min_uncertain` points).
    pub fn autolabel(&mut self, due: bool) {
        let labelled = due.then(|| self.label()).flatten();
        let rho = self.config.algorithm.rho;
        let record = &mut self.epoch.record;
        record.count(
            "autolabel_removed",
            labelled.map_or(0, |(removed, _)| removed),
        );
        record.exact("rho", labelled.map_or(rho, |(_, rho)| rho));
    }

    /// [`Learner::autolabel`]'s labelling: (points removed, rho used), or None when D? holds too few points.
    fn label(&mut self) -> Option<(usize, f64)> {
        if self.replay.len_uncertain() < self.config.algorithm.autolabel_min_uncertain.max(1) {
            return None;
        }
        let epoch = self.epoch.record.epoch();
        self.progress(epoch, "auto-labelling");
        let report = autolabel_replay(&self.replay, &AutolabelOptions::from_config(&self.config));
        self.replay.apply_labels(&report.removed);
        let removed = report.removed.len();
        tracing::info!(
            epoch,
            removed,
            queried = report.queries,
            secs = report.seconds,
            d_minus = self.replay.len_minus(),
            "auto-labelling removed {removed} likely-safe states from D?"
        );
        Some((removed, report.rho))
    }

    /// ComputeGradient and Update: the trainer's epoch on the replay ([`Trainer::train_epoch`]: p_hat's held-out
    /// measure, then f_hat and p_hat as the schedule says, and pi); its losses go into the epoch's record.
    pub(crate) fn train(&mut self) -> Result<(), LearnerError> {
        let epoch = self.epoch.record.epoch();
        self.progress(epoch, "training");
        let record = &mut self.epoch.record;
        Ok(self.trainer.train_epoch(epoch, &self.replay, record)?)
    }

    /// An evaluation report ([`crate::evaluations::Evaluations::take`]).
    pub fn on_eval(&mut self, report: EvalReport) {
        let rules = &self.config.collection;
        let sink = &mut self.sink;
        self.state
            .evaluations
            .take(report, rules, |taken| sink.evaluation(taken));
    }

    /// Closes the epoch in progress: puts D+, D?, D-, the evaluations, the access control's refusals and the
    /// epoch's time, checkpoints, and writes the record through the sink.
    pub fn end_epoch(&mut self) -> Result<(), LearnerError> {
        let next = Epoch::new(self.epoch.record.epoch() + 1, &self.state.ledger);
        let Epoch {
            mut record,
            started,
            ..
        } = std::mem::replace(&mut self.epoch, next);
        record.count("d_plus", self.replay.len_plus());
        record.count("d_uncertain", self.replay.len_uncertain());
        // What the last auto-labelling left in D? (the critic's negatives), held until the next labelling.
        record.count("d_minus", self.replay.len_minus());
        record.count("dynamics_only", self.replay.len_dynamics_only());
        self.state.evaluations.put(&mut record);
        record.count("acl_denied", self.acl_denied());
        if let Some(restarts) = &self.restarts {
            let by = restarts();
            for (role, column) in RESTARTED_ROLES {
                record.count(column, by.get(role).copied().unwrap_or(0));
            }
        }
        record.real("epoch_s", started.elapsed().as_secs_f64(), 3);
        let epoch = record.epoch();
        tracing::info!("epoch done: {record}");
        self.state.next_epoch = epoch + 1;
        self.state.rows.push(record);
        self.checkpoint()?;
        match self.state.rows.last() {
            Some(record) => Ok(self.sink.write(record)?),
            None => Ok(()),
        }
    }

    /// Messages the router's access control has dropped so far, warned about when they grew since the last epoch
    /// (zenoh logs its decisions only at TRACE): an operator under attack sees who tried what.
    fn acl_denied(&self) -> u64 {
        let by = (self.acl_denials)();
        let total: u64 = by.values().sum();
        let before = self.state.rows.last().and_then(|r| r.u64("acl_denied"));
        if total > before.unwrap_or(0) {
            tracing::warn!(
                new = total - before.unwrap_or(0),
                total,
                "the access control dropped messages: {by:?}"
            );
        }
        total
    }

    /// Shows the phase of epoch `epoch` (the progress bar).
    fn progress(&mut self, epoch: u64, phase: &str) {
        self.sink.phase(epoch, phase);
    }

    /// The networks, the replay and the learner state, through the checkpointer.
    fn checkpoint(&mut self) -> Result<(), LearnerError> {
        let mut files = self.trainer.to_checkpoint();
        files.push(self.state.part()?);
        Ok(self.checkpointer.save(files, &mut self.replay)?)
    }

    /// The segments the last checkpoint settled (since the last call): what the actors may forget.
    pub fn settled(&mut self) -> Vec<SegmentId> {
        std::mem::take(&mut self.settled)
    }

    /// Ends the run: the final outputs (unless interrupted) and the summary, written through the sink and returned.
    pub fn finish(
        &mut self,
        reason: &str,
        interrupted: bool,
        rejected: u64,
    ) -> Result<Summary, LearnerError> {
        tracing::info!("run ends: {reason}");
        let not_evaluated = self.state.evaluations.not_evaluated();
        if !not_evaluated.is_empty() {
            // The rule by which a version goes unevaluated: the run ended before its report arrived.
            tracing::warn!(
                ?not_evaluated,
                "the run ends before these versions' evaluations arrived"
            );
        }
        if !interrupted {
            self.state.stopped = Some(reason.to_string());
        }
        let summary = self.summary(reason, rejected);
        let final_policy = (!interrupted).then(|| self.trainer.policy_bytes());
        self.sink.close(&summary, final_policy.as_deref())?;
        Ok(summary)
    }

    fn summary(&self, reason: &str, rejected: u64) -> Summary {
        let (config, state) = (&self.config, &self.state);
        let evaluations = &state.evaluations;
        let epoch_s: Vec<f64> = state.rows.iter().filter_map(|r| r.f64("epoch_s")).collect();
        let expert = cabc_proto::stats::mean_std(&state.expert_lap_times);
        Summary {
            run: config.run.name.clone(),
            experiment: config.run.experiment.clone(),
            lambda: config.algorithm.lambda,
            rho: config.algorithm.rho,
            ended: reason.to_string(),
            epochs: state.rows.len(),
            early_stop_version: evaluations.early_stop(),
            first_version_with_eval_laps: evaluations.first_completing(config.collection.eval_laps),
            best_eval: evaluations.best().cloned(),
            last_eval: evaluations.evals.last().cloned(),
            trunk_init: state.trunk_init.clone(),
            device: cabc_models::device_name(self.device()),
            precision: cabc_models::precision::effective(config.training.precision, self.device()),
            expert_lap_time: expert.map(|(mean, std)| LapTime {
                laps: state.expert_lap_times.len(),
                mean,
                std,
            }),
            mean_epoch_s: cabc_proto::stats::mean(&epoch_s).unwrap_or(0.0),
            learner_peak_rss_mb: peak_rss_mb(),
            steps_stored: state.ledger.stored_steps,
            segments_stored: state.ledger.stored_segments,
            duplicate_segments: state.ledger.duplicates,
            segments_not_stored: state.segments_not_stored,
            refused_evals: evaluations.refused(),
            duplicate_evals: evaluations.duplicates(),
            versions_not_evaluated: evaluations.not_evaluated(),
            rejected_messages: rejected,
            acl_denied: (self.acl_denials)(),
            restarts: self.restarts.as_ref().map(|r| r()),
            d_plus: self.replay.len_plus(),
            d_uncertain: self.replay.len_uncertain(),
            d_minus: self.replay.len_minus(),
        }
    }
}

/// The learner process's peak resident memory (MB), from /proc/self/status (None where there is no /proc).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}
