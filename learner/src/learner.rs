//! What the learner holds between epochs of Algorithm 1 ([`crate::algorithm`]): D+, D? and D- (the replay), the
//! three networks and their optimisers (the trainer), the exactly-once ledger, the evaluations and early stopping,
//! and the run folder it writes (checkpoint, `metrics.csv`, `evals.csv`, plots, summary).

use crate::autolabel::{autolabel_replay, AutolabelOptions};
use crate::provenance::Provenance;
use crate::replay::{Frames, ImageLog, Replay};
use crate::rundir::{EpochRow, EvalSummary, LearnerState, RunDir, RunDirError};
use crate::tensorboard::EventWriter;

mod outputs;
use crate::train::{EpochLosses, TrainError, Trainer};
use cabc_models::device::parse_device;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EvalReport, Outcome, PolicyUpdate, Segment};
use cabc_proto::ports::{Collected, PortError};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::collections::{BTreeMap, HashSet};

/// Errors that end the learner.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error("the actors' port: {0}")]
    Port(#[from] PortError),
    #[error("training: {0}")]
    Train(#[from] TrainError),
    #[error("the run folder: {0}")]
    RunDir(#[from] RunDirError),
    #[error("{0}")]
    Checkpoint(String),
}

/// The replay's file in the checkpoint.
const REPLAY: &str = "replay.bin";

/// Published versions' weights are kept until their evaluation arrives (the best evaluated one is written to
/// `best-policy.safetensors`, whatever its version), up to this many bytes together (a ResNet-18 policy is 45 MB, so
/// 11 versions; the full-state MLP is 0.1 MB): past it the oldest are dropped, logged; the newest always stays.
const PENDING_WEIGHT_BYTES: usize = 512 << 20;

/// Everything the learner holds.
pub struct Learner {
    pub config: RunConfig,
    pub run_dir: RunDir,
    pub trainer: Trainer,
    /// D+, D?, D- and the dynamics-only store.
    pub replay: Replay,
    pub state: LearnerState,
    /// The version that stopped the run early, once decided.
    pub early_stop: Option<u64>,
    history: BTreeMap<u64, Vec<u8>>,
    /// The segments of the epoch being collected, until [`Learner::partition`].
    d_new: Vec<Segment>,
    last_eval: Option<EvalReport>,
    expert_streams: HashSet<(String, u32, u64)>,
    failed_segments: u64,
    /// Steps in incomplete segments since the last [`Learner::counts`].
    incomplete_steps: u64,
    /// Where this epoch's D? steps came from.
    provenance: Provenance,
    /// The track's half-width (off-track spawns in [`Provenance`]).
    half_width: f64,
    /// Messages the router's access control had dropped at the last epoch's end (logged when it grows).
    acl_denied: u64,
    /// TensorBoard's event file in the run folder's `tb/` (None when it could not be created: logged).
    tb: Option<EventWriter>,
    /// The newest version published ([`Learner::policy_update`]): evaluation reports of later versions are refused.
    published: Option<u64>,
    /// Evaluation reports refused (a version not published yet).
    refused_evals: u64,
    /// Evaluation reports of a version already evaluated (ignored).
    duplicate_evals: u64,
    /// D+'s images on disk (`replay-images-<generation>.log` in the run folder), appended to at each checkpoint.
    image_log: Option<ImageLog>,
    bar: ProgressBar,
}

impl Learner {
    /// A fresh learner for `config` writing into `run_dir`, or the one of its checkpoint with `resume` (refused
    /// without `resume` when a checkpoint exists).
    pub fn open(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<Self, LearnerError> {
        let device = parse_device(&config.training.device).map_err(TrainError::from)?;
        let (trainer, replay, image_log, state) = if run_dir.has_checkpoint() {
            if !resume {
                return Err(LearnerError::Checkpoint(format!(
                    "{} holds a checkpoint: pass --resume to continue that run, or --fresh to start over",
                    run_dir.path().display()
                )));
            }
            let state = run_dir.load_state()?;
            let ck = run_dir.open_checkpoint()?;
            let mut trainer = Trainer::with_device(&config, device);
            trainer.load(&ck)?;
            let (replay, image_log) = ck
                .read(REPLAY)
                .map_err(|e| LearnerError::Checkpoint(e.to_string()))
                .and_then(|bytes| {
                    Replay::from_checkpoint(&bytes, run_dir.path())
                        .map(|(replay, log)| {
                            let replay = replay
                                .with_frames(Frames::of(&config))
                                .with_dynamics_only(config.replay.dynamics_only);
                            (replay, log)
                        })
                        .map_err(|e| LearnerError::Checkpoint(format!("loading the replay: {e}")))
                })?;
            tracing::info!(
                epoch = state.next_epoch,
                d_plus = replay.len_plus(),
                d_uncertain = replay.len_uncertain(),
                "resumed from {}",
                ck.path().display()
            );
            (trainer, replay, image_log, state)
        } else if resume {
            return Err(LearnerError::Checkpoint(format!(
                "{} holds no checkpoint to resume (not even checkpoint.old/): nothing was started; drop --resume to \
                 start a new run",
                run_dir.path().display()
            )));
        } else {
            let replay = Replay::from_config(&config);
            tracing::info!(
                d_plus_capacity = replay.plus.capacity(),
                capacity = config.replay.capacity,
                max_bytes = config.replay.max_bytes,
                "replay"
            );
            let mut trainer = Trainer::with_device(&config, device);
            let state = LearnerState {
                trunk_init: Some(trainer.init_trunk()?),
                ..LearnerState::default()
            };
            (trainer, replay, None, state)
        };
        let bar = ProgressBar::new(config.run.max_epochs);
        bar.set_style(
            ProgressStyle::with_template("{elapsed_precise} epoch {pos}/{len} {bar:30} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(state.next_epoch);
        let tb = EventWriter::create(&run_dir.path().join("tb"))
            .map_err(|e| tracing::warn!("no TensorBoard events: {e}"))
            .ok();
        Ok(Learner {
            config,
            run_dir,
            trainer,
            replay,
            state,
            early_stop: None,
            history: BTreeMap::new(),
            d_new: Vec::new(),
            last_eval: None,
            expert_streams: HashSet::new(),
            failed_segments: 0,
            incomplete_steps: 0,
            provenance: Provenance::default(),
            half_width: cabc_sim::track::Track::l_track_barc().half_width(),
            acl_denied: 0,
            tb,
            published: None,
            refused_evals: 0,
            duplicate_evals: 0,
            image_log,
            bar,
        })
    }

    /// (pi_j, beta_j) as the actors receive it, with each actor's step budget for the epoch.
    pub fn policy_update(&mut self, epoch: u64) -> PolicyUpdate {
        let weights = self.trainer.policy_bytes();
        self.history.insert(epoch, weights.clone());
        let mut held: usize = self.history.values().map(Vec::len).sum();
        while held > PENDING_WEIGHT_BYTES && self.history.len() > 1 {
            if let Some((version, dropped)) = self.history.pop_first() {
                held -= dropped.len();
                tracing::warn!(
                    version,
                    "no evaluation of version {version} yet, and the versions awaiting one hold over \
                     {} MB: its weights are dropped (it cannot become best-policy.safetensors)",
                    PENDING_WEIGHT_BYTES >> 20
                );
            }
        }
        self.progress(epoch, "collecting");
        self.published = Some(epoch);
        PolicyUpdate {
            version: epoch,
            beta: self.config.beta(epoch),
            architecture: self.trainer.policy_architecture(),
            weights,
            steps_per_actor: self.config.steps_per_actor(epoch),
            published_unix_ms: unix_ms(),
        }
    }

    /// Starts an epoch's bookkeeping: returns the stored steps and segments so far (the epoch's row reports the
    /// difference) and zeroes the epoch's count of incomplete steps.
    pub fn begin_epoch(&mut self) -> (u64, u64) {
        self.incomplete_steps = 0;
        self.provenance = Provenance::default();
        (
            self.state.ledger.stored_steps,
            self.state.ledger.stored_segments,
        )
    }

    /// Takes in a segment of D_new, exactly once (the ledger drops a duplicate). A segment the replay would not
    /// take (images not of the run's observation size, [`Replay::check_segment`]) is refused and counted in
    /// `segments_not_stored` before the ledger sees it, and before it waits in D_new.
    pub fn store(&mut self, segment: Segment) {
        if let Err(e) = self.replay.check_segment(&segment) {
            self.failed_segments += 1;
            tracing::warn!(
                actor = segment.actor,
                seq = segment.seq,
                "segment refused: {e}"
            );
            return;
        }
        if !self.state.ledger.admit(&segment) {
            tracing::warn!(
                actor = segment.actor,
                seq = segment.seq,
                "duplicate segment dropped"
            );
            return;
        }
        self.d_new.push(segment);
    }

    /// Partitions D_new into D+' (laps) and D?' (failures; unfinished steps go to the dynamics-only store) and adds
    /// them to D+ and D?. Segments are added in (actor, incarnation, seq) order, whatever order the bus delivered them in, so a
    /// distributed run with a given seed is as reproducible as an in-process one.
    pub fn partition(&mut self) {
        let mut d_new = std::mem::take(&mut self.d_new);
        d_new.sort_by(|a, b| {
            (&a.actor, a.incarnation, a.seq).cmp(&(&b.actor, b.incarnation, b.seq))
        });
        for segment in d_new {
            self.expert_lap_time(&segment);
            if segment.outcome == Outcome::Incomplete {
                self.incomplete_steps += segment.steps.len() as u64;
            }
            match self.replay.add_segment(&segment) {
                Ok(_) => {
                    let flush = self.config.collection.flush;
                    self.provenance.add(&segment, flush, self.half_width);
                }
                Err(e) => {
                    self.failed_segments += 1;
                    tracing::warn!(
                        actor = segment.actor,
                        seq = segment.seq,
                        "segment not stored: {e}"
                    );
                }
            }
        }
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
                let dt = cabc_sim::env::DT;
                self.state
                    .expert_lap_times
                    .push(segment.steps.len() as f64 * dt);
            }
        }
    }

    /// Auto-labels D? (eq. (19)) and makes what stays in it D-. Returns (points removed, rho used); None when D? holds
    /// fewer than `algorithm.autolabel_min_uncertain` points (or none).
    pub fn autolabel(&mut self, epoch: u64) -> Option<(usize, f64)> {
        if self.replay.len_uncertain() < self.config.algorithm.autolabel_min_uncertain.max(1) {
            return None;
        }
        self.progress(epoch, "auto-labelling");
        let report = autolabel_replay(&self.replay, &AutolabelOptions::from_config(&self.config));
        self.replay.apply_labels(&report);
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

    /// An evaluation report: counts toward early stopping when it completed `eval_laps` laps. A report of a version
    /// not published yet is refused and counted (`refused_evals`); the bus already checked that it came from an
    /// evaluator under its own name.
    pub fn on_eval(&mut self, report: EvalReport) {
        if self
            .published
            .is_none_or(|published| report.version > published)
        {
            self.refused_evals += 1;
            tracing::warn!(
                actor = report.actor,
                version = report.version,
                published = ?self.published,
                "evaluation report of a version not published: refused"
            );
            return;
        }
        if self.state.evals.iter().any(|e| e.version == report.version) {
            self.duplicate_evals += 1;
            tracing::warn!(
                actor = report.actor,
                version = report.version,
                "a second evaluation of a version: ignored (early stopping counts distinct versions)"
            );
            return;
        }
        let summary = EvalSummary::of(&report);
        let weights = self.history.remove(&report.version);
        let best = self.state.evals.iter().all(|e| summary.better_than(e));
        if report.laps >= self.config.collection.eval_laps {
            self.eval_video(&report, best);
        }
        if best {
            match weights {
                Some(weights) => {
                    if let Err(e) = self.run_dir.write_file("best-policy.safetensors", &weights) {
                        tracing::warn!("saving the best policy: {e}");
                    }
                }
                None => tracing::warn!(
                    version = report.version,
                    "the best evaluation so far, but its weights are no longer held"
                ),
            }
        }
        tracing::info!(
            version = report.version,
            laps = report.laps,
            end = %report.end_reason,
            lap_mean = ?summary.lap_mean,
            "evaluation"
        );
        if report.laps >= self.config.collection.eval_laps {
            self.state.successes += 1;
            if self.state.successes >= self.config.collection.early_stop_successes
                && self.early_stop.is_none()
            {
                self.early_stop = Some(report.version);
            }
        }
        let mut eval = vec![("laps", report.laps as f32)];
        eval.extend(summary.lap_mean.map(|m| ("lap_mean", m as f32)));
        eval.extend(summary.lap_std.map(|s| ("lap_std", s as f32)));
        self.record_scalars(report.version, "eval", &eval);
        self.state.evals.push(summary);
        self.last_eval = Some(report);
    }

    /// The epoch's row of `metrics.csv`.
    #[allow(clippy::too_many_arguments)]
    pub fn row(
        &self,
        epoch: u64,
        update: &PolicyUpdate,
        (steps_before, segments_before): (u64, u64),
        collected: &Collected,
        labelled: Option<(usize, f64)>,
        fits: &EpochLosses,
        collect_s: f64,
    ) -> EpochRow {
        EpochRow {
            epoch,
            beta: update.beta,
            steps_collected: self.state.ledger.stored_steps - steps_before,
            steps_published: collected.steps_published,
            segments: self.state.ledger.stored_segments - segments_before,
            steps_taken: collected.steps_taken,
            steps_staged: collected.steps_staged,
            incomplete_steps: self.incomplete_steps,
            d_plus: self.replay.len_plus(),
            d_uncertain: self.replay.len_uncertain(),
            d_minus: self.replay.len_minus(),
            dynamics_only: self.replay.len_dynamics_only(),
            autolabel_removed: labelled.map_or(0, |(removed, _)| removed),
            rho: labelled.map_or(self.config.algorithm.rho, |(_, rho)| rho),
            imitation_loss: fits.imitation,
            safety_loss: fits.safety,
            dynamics_loss: fits.dynamics,
            critic_loss: fits.critic,
            critic_accuracy: fits.critic_accuracy,
            critic_points: fits.critic_points,
            critic_positives: fits.critic_positives,
            critic_negatives: fits
                .critic_points
                .zip(fits.critic_positives)
                .map(|(n, p)| n - p),
            uncertain_truncating: self.provenance.truncating,
            uncertain_spawn: self.provenance.spawn,
            uncertain_patience: self.provenance.patience,
            uncertain_failed_lap: self.provenance.failed_lap,
            expert_failures: self.provenance.expert_failures,
            collect_s,
            train_s: fits.seconds,
            epoch_s: 0.0,
            closed_by_timeout: collected.timed_out,
            eval_version: self.last_eval.as_ref().map(|e| e.version),
            eval_laps: self.last_eval.as_ref().map(|e| e.laps),
        }
    }

    /// Closes an epoch: its row, the checkpoint, the tables and plots.
    pub fn end_epoch(&mut self, mut row: EpochRow, epoch_s: f64) -> Result<(), LearnerError> {
        row.epoch_s = epoch_s;
        tracing::info!(
            epoch = row.epoch,
            beta = format!("{:.3}", row.beta),
            d_plus = row.d_plus,
            d_uncertain = row.d_uncertain,
            imitation = format!("{:.5}", row.imitation_loss),
            safety = format!("{:.5}", row.safety_loss),
            collect_s = format!("{:.2}", row.collect_s),
            train_s = format!("{:.2}", row.train_s),
            "epoch done"
        );
        self.report_denials(row.epoch);
        self.record_scalars(row.epoch, "metrics", &row.scalars());
        self.state.next_epoch = row.epoch + 1;
        self.state.rows.push(row);
        self.checkpoint()?;
        self.write_outputs(false)?;
        self.bar.set_position(self.state.next_epoch);
        Ok(())
    }

    /// The learner's metrics after epoch `epoch` (JSON on `metrics/learner`).
    pub fn metrics_json(&self, epoch: u64, collected: &Collected, rejected: u64) -> String {
        json!({
            "epoch": epoch,
            "row": self.state.rows.last(),
            "live_actors": collected.live,
            "rejected_messages": rejected,
            "segments_not_stored": self.failed_segments,
            "refused_evals": self.refused_evals,
            "acl_denied": self.acl_denied,
        })
        .to_string()
    }

    /// Shows the phase of epoch `epoch` on the progress bar.
    pub fn progress(&self, epoch: u64, phase: &str) {
        let eval = self
            .last_eval
            .as_ref()
            .map(|e| format!("v{}: {} laps", e.version, e.laps))
            .unwrap_or_else(|| "none".into());
        self.bar.set_message(format!(
            "{phase} | beta {:.3} | D+ {} D? {} D- {} | last eval {eval}",
            self.config.beta(epoch),
            self.replay.len_plus(),
            self.replay.len_uncertain(),
            self.replay.len_minus(),
        ));
    }

    /// The networks, the replay and the learner state, written atomically (see `crate::checkpoint`).
    /// D+'s images go to the image log first (only those new since the last checkpoint); a generation the
    /// committed checkpoint no longer names is removed after the commit.
    fn checkpoint(&mut self) -> Result<(), LearnerError> {
        let mut files = self.trainer.to_checkpoint();
        let replay = self
            .replay
            .checkpoint_bytes(self.run_dir.path(), &mut self.image_log)
            .map_err(|e| LearnerError::Checkpoint(format!("saving the replay: {e}")))?;
        files.push((REPLAY, replay));
        self.run_dir.save_checkpoint(&self.state, files)?;
        if let Some(log) = &self.image_log {
            if let Err(e) = log.prune() {
                tracing::warn!("removing an old image log: {e}");
            }
        }
        Ok(())
    }

    /// Ends the run: the final outputs (unless interrupted) and `summary.json`, which is returned.
    pub fn finish(
        &mut self,
        reason: &str,
        interrupted: bool,
        rejected: u64,
    ) -> Result<serde_json::Value, LearnerError> {
        self.bar.finish_and_clear();
        tracing::info!("run ends: {reason}");
        let not_evaluated = self.not_evaluated();
        if !not_evaluated.is_empty() {
            // The rule by which a version goes unevaluated: the run ended before its report arrived.
            tracing::warn!(
                ?not_evaluated,
                "the run ends before these versions' evaluations arrived"
            );
        }
        if !interrupted {
            self.state.stopped = Some(reason.to_string());
            self.write_outputs(true)?;
        }
        let summary = self.summary(reason, rejected);
        self.run_dir.write_summary(&summary)?;
        Ok(summary)
    }

    /// Published versions with no evaluation report.
    fn not_evaluated(&self) -> Vec<u64> {
        let evaluated: HashSet<u64> = self.state.evals.iter().map(|e| e.version).collect();
        let published = self.published.map_or(0, |p| p + 1);
        (0..published).filter(|v| !evaluated.contains(v)).collect()
    }

    fn summary(&self, reason: &str, rejected: u64) -> serde_json::Value {
        let eval_laps = self.config.collection.eval_laps;
        let first_50 = self
            .state
            .evals
            .iter()
            .find(|e| e.laps >= eval_laps)
            .map(|e| e.version);
        let best = self
            .state
            .evals
            .iter()
            .reduce(|best, e| if e.better_than(best) { e } else { best });
        let not_evaluated = self.not_evaluated();
        let expert = cabc_proto::stats::mean_std(&self.state.expert_lap_times);
        let epochs = self.state.rows.len();
        let epoch_s: Vec<f64> = self.state.rows.iter().map(|r| r.epoch_s).collect();
        json!({
            "run": self.config.run.name,
            "experiment": self.config.run.experiment,
            "lambda": self.config.algorithm.lambda,
            "rho": self.config.algorithm.rho,
            "ended": reason,
            "epochs": epochs,
            "early_stop_version": self.early_stop,
            "first_version_with_eval_laps": first_50,
            "best_eval": best,
            "last_eval": self.state.evals.last(),
            "trunk_init": self.state.trunk_init,
            "expert_lap_time": expert.map(|(m, s)| json!({"mean": m, "std": s, "laps": self.state.expert_lap_times.len()})),
            "mean_epoch_s": cabc_proto::stats::mean(&epoch_s).unwrap_or(0.0),
            "learner_peak_rss_mb": peak_rss_mb(),
            "steps_stored": self.state.ledger.stored_steps,
            "segments_stored": self.state.ledger.stored_segments,
            "duplicate_segments": self.state.ledger.duplicates,
            "segments_not_stored": self.failed_segments,
            "refused_evals": self.refused_evals,
            "duplicate_evals": self.duplicate_evals,
            "versions_not_evaluated": not_evaluated,
            "rejected_messages": rejected,
            "acl_denied": cabc_proto::telemetry::acl_denials(),
            "d_plus": self.replay.len_plus(),
            "d_uncertain": self.replay.len_uncertain(),
            "d_minus": self.replay.len_minus(),
        })
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
