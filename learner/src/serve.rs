//! The learner process: Algorithm 1 over the bus (architecture.md's epoch protocol).
//!
//! Per epoch j: publish PolicyUpdate j → store every segment that arrives (exactly once, late ones too) until
//! every live actor is done with j or the timeout passes → auto-label when due → train (while still taking in
//! segments) → checkpoint, tables, plots, metrics. Evaluation reports arrive at any time; the second evaluation
//! that completes `eval_laps` laps stops the run (early stopping) and keeps that policy.

use crate::autolabel::{autolabel_replay, AutolabelOptions};
use crate::epoch::{Closed, EpochGate};
use crate::plots;
use crate::replay::Replay;
use crate::rundir::{EpochRow, EvalSummary, LearnerState, RunDir};
use crate::train::{EpochLosses, Trainer};
use anyhow::{anyhow, bail, Context, Result};
use cabc_bus::{decode_sample, encoding_of, Bus, Role};
use cabc_models::device::parse_device;
use cabc_proto::codec;
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{EvalReport, Outcome, PolicyUpdate, Segment, Stop, TrajMessage};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::time::{Duration, Instant};
use zenoh::sample::SampleKind;

/// Everything the learner holds.
struct Learner {
    config: RunConfig,
    run_dir: RunDir,
    trainer: Option<Trainer>,
    replay: Option<Replay>,
    state: LearnerState,
    /// Weights of recent policy versions (the early stop keeps the one that succeeded).
    history: BTreeMap<u64, Vec<u8>>,
    live: BTreeSet<String>,
    last_eval: Option<EvalReport>,
    early_stop: Option<u64>,
    expert_streams: HashSet<(String, u32, u64)>,
    failed_segments: u64,
    bar: ProgressBar,
}

/// Runs (or resumes) the run in `run_dir` until early stop, `max_epochs` or Ctrl-C.
pub fn run(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(run_async(config, run_dir, resume))
}

async fn run_async(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<()> {
    let device = parse_device(&config.training.device)?;
    let (trainer, replay, state) = if run_dir.has_checkpoint() {
        if !resume {
            bail!(
                "{} holds a checkpoint: pass --resume to continue that run, or --fresh to start over",
                run_dir.path().display()
            );
        }
        let state = run_dir
            .load_state()
            .context("reading the checkpoint's state")?;
        let ck = run_dir.open_checkpoint()?;
        let mut trainer = Trainer::with_device(&config, device);
        trainer
            .load(&ck)
            .context("loading the networks of the checkpoint")?;
        let replay = Replay::from_bytes(&ck.read("replay.bin")?)
            .context("loading the replay of the checkpoint")?;
        tracing::info!(
            epoch = state.next_epoch,
            d_plus = replay.len_plus(),
            d_uncertain = replay.len_uncertain(),
            "resumed from {}",
            ck.path().display()
        );
        (trainer, replay, state)
    } else {
        (
            Trainer::with_device(&config, device),
            Replay::from_config(&config),
            LearnerState::default(),
        )
    };
    let bar = ProgressBar::new(config.run.max_epochs);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} epoch {pos}/{len} {bar:30} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_position(state.next_epoch);
    let mut learner = Learner {
        config,
        run_dir,
        trainer: Some(trainer),
        replay: Some(replay),
        state,
        history: BTreeMap::new(),
        live: BTreeSet::new(),
        last_eval: None,
        early_stop: None,
        expert_streams: HashSet::new(),
        failed_segments: 0,
        bar,
    };
    learner.main_loop().await
}

/// Bus handles of the learner.
struct Wires {
    bus: Bus,
    traj: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    eval: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    alive: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    policy: zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>,
    latest_policy: Vec<u8>,
}

/// What woke the loop.
enum Event {
    Traj(zenoh::sample::Sample),
    Eval(zenoh::sample::Sample),
    Alive(zenoh::sample::Sample),
    PolicyQuery(zenoh::query::Query),
    Tick,
    Interrupt,
}

impl Wires {
    async fn next(&self, tick: &mut tokio::time::Interval) -> Result<Event> {
        Ok(tokio::select! {
            s = self.traj.recv_async() => Event::Traj(s.map_err(|e| anyhow!("trajectory subscription: {e}"))?),
            s = self.eval.recv_async() => Event::Eval(s.map_err(|e| anyhow!("eval subscription: {e}"))?),
            s = self.alive.recv_async() => Event::Alive(s.map_err(|e| anyhow!("liveliness subscription: {e}"))?),
            q = self.policy.recv_async() => Event::PolicyQuery(q.map_err(|e| anyhow!("policy queryable: {e}"))?),
            _ = tick.tick() => Event::Tick,
            _ = tokio::signal::ctrl_c() => Event::Interrupt,
        })
    }
}

/// The component name of an actor's liveliness token `.../alive/actor/<id>`.
fn actor_of_token(key: &str) -> Option<String> {
    let (_, rest) = key.split_once("/alive/actor/")?;
    Some(rest.to_string())
}

impl Learner {
    async fn main_loop(&mut self) -> Result<()> {
        let keys = Keys::new(&self.config.run.name)?;
        let bus = Bus::connect(&self.config.bus, Role::Listen, keys.clone(), "learner")
            .await
            .context(
                "opening the bus (is another learner already listening on the same endpoint?)",
            )?;
        let zerr = |what: String| move |e: zenoh::Error| anyhow!("{what}: {e}");
        let traj = bus
            .session
            .declare_subscriber(keys.traj_all())
            .with(zenoh::handlers::FifoChannel::new(1 << 16))
            .await
            .map_err(zerr(keys.traj_all()))?;
        let eval = bus
            .session
            .declare_subscriber(keys.eval_all())
            .await
            .map_err(zerr(keys.eval_all()))?;
        let alive = bus
            .session
            .liveliness()
            .declare_subscriber(keys.alive("actor/*"))
            .history(true)
            .await
            .map_err(zerr(keys.alive("actor/*")))?;
        let policy = bus
            .session
            .declare_queryable(keys.policy())
            .await
            .map_err(zerr(keys.policy()))?;
        let mut wires = Wires {
            bus,
            traj,
            eval,
            alive,
            policy,
            latest_policy: Vec::new(),
        };
        tracing::info!(
            run = keys.run(),
            dir = %self.run_dir.path().display(),
            listen = ?self.config.bus.listen,
            "learner up; waiting for actors"
        );
        let mut tick = tokio::time::interval(Duration::from_millis(250));
        let mut interrupted = false;
        let first = self.state.next_epoch;
        for epoch in first..self.config.run.max_epochs {
            if self.early_stop.is_some() {
                break;
            }
            match self.epoch(epoch, &mut wires, &mut tick).await? {
                true => {}
                false => {
                    interrupted = true;
                    break;
                }
            }
        }
        let reason = if interrupted {
            "interrupted".to_string()
        } else if let Some(v) = self.early_stop {
            format!(
                "early stop: policy version {v} completed {} laps twice",
                self.config.collection.eval_laps
            )
        } else {
            format!("max_epochs {} reached", self.config.run.max_epochs)
        };
        self.bar.finish_and_clear();
        tracing::info!("run ends: {reason}");
        if !interrupted {
            self.state.stopped = Some(reason.clone());
            let control = wires.bus.keys.control();
            wires
                .bus
                .put(
                    &control,
                    &Stop {
                        reason: reason.clone(),
                    },
                )
                .await?;
            self.write_outputs(true)?;
        }
        let summary = self.summary(&reason, &wires);
        self.run_dir.write_summary(&summary)?;
        println!("{}", serde_json::to_string_pretty(&summary)?);
        // Give the stop a moment to reach everyone before the router goes away.
        tokio::time::sleep(Duration::from_millis(300)).await;
        wires.bus.close().await?;
        Ok(())
    }

    /// One epoch. Returns false when interrupted.
    async fn epoch(
        &mut self,
        epoch: u64,
        wires: &mut Wires,
        tick: &mut tokio::time::Interval,
    ) -> Result<bool> {
        let epoch_start = Instant::now();
        let trainer = self
            .trainer
            .as_ref()
            .expect("trainer present between epochs");
        let weights = trainer.policy_bytes();
        let update = PolicyUpdate {
            version: epoch,
            beta: self.config.beta(epoch),
            architecture: trainer.policy_architecture(),
            weights: weights.clone(),
            steps_per_actor: self.config.steps_per_actor(epoch),
            published_unix_ms: unix_ms(),
        };
        self.history.insert(epoch, weights);
        while self.history.len() > 8 {
            self.history.pop_first();
        }
        wires.latest_policy = codec::encode(&update);
        let key = wires.bus.keys.policy();
        wires.bus.put(&key, &update).await?;
        let timeout = Duration::from_secs_f64(self.config.bus.epoch_timeout_s);
        let mut gate = EpochGate::open(epoch, timeout, self.live.iter().cloned(), Instant::now());
        let stored_before = self.state.ledger.stored_steps;
        let segments_before = self.state.ledger.stored_segments;
        let mut last_wait_log = Instant::now();
        self.bar.set_message(self.status(epoch, "collecting"));

        // 1. Collect until the gate closes.
        let closed = loop {
            match wires.next(tick).await? {
                Event::Traj(sample) => {
                    if let Some(marker) = self.on_traj(&sample, wires, None) {
                        gate.done(marker);
                    }
                }
                Event::Eval(sample) => self.on_eval(&sample, wires),
                Event::Alive(sample) => self.on_alive(&sample, Some(&mut gate)),
                Event::PolicyQuery(query) => reply_policy(query, &wires.latest_policy).await,
                Event::Tick => {
                    if let Some(closed) = gate.closed(Instant::now()) {
                        break closed;
                    }
                    if last_wait_log.elapsed() > Duration::from_secs(30) {
                        last_wait_log = Instant::now();
                        tracing::info!(epoch, live = ?self.live, missing = ?gate.missing(), "waiting for actors");
                    }
                    self.bar.set_message(self.status(epoch, "collecting"));
                }
                Event::Interrupt => return Ok(false),
            }
        };
        if let Closed::Timeout { missing } = &closed {
            tracing::warn!(
                epoch,
                ?missing,
                "epoch closed by the timeout without these actors"
            );
        }
        let steps_published: u64 = gate.markers().map(|m| m.steps).sum();
        let collect_s = epoch_start.elapsed().as_secs_f64();

        // 2. Auto-labelling when due.
        let replay = self.replay.as_mut().expect("replay present between epochs");
        let mut removed = 0;
        let mut rho = self.config.algorithm.rho;
        if epoch % self.config.algorithm.autolabel_every == 0 && replay.len_uncertain() > 0 {
            let report = autolabel_replay(replay, &AutolabelOptions::from_config(&self.config));
            replay.apply_labels(&report);
            removed = report.removed.len();
            rho = report.rho;
            tracing::info!(
                epoch,
                removed,
                queried = report.queries,
                secs = report.seconds,
                "auto-labelling removed {removed} likely-safe states from D?"
            );
        }

        // 3. Train, while still taking in what arrives.
        self.bar.set_message(self.status(epoch, "training"));
        let train_start = Instant::now();
        let mut trainer = self.trainer.take().expect("trainer present");
        let replay = self.replay.take().expect("replay present");
        let mut training = tokio::task::spawn_blocking(move || {
            let losses = trainer.train_epoch(epoch, &replay);
            (trainer, replay, losses)
        });
        let mut late: Vec<Segment> = Vec::new();
        let (trainer, mut replay, losses) = loop {
            tokio::select! {
                done = &mut training => break done.map_err(|e| anyhow!("training task failed: {e}"))?,
                event = wires.next(tick) => match event? {
                    Event::Traj(sample) => { self.on_traj(&sample, wires, Some(&mut late)); }
                    Event::Eval(sample) => self.on_eval(&sample, wires),
                    Event::Alive(sample) => self.on_alive(&sample, None),
                    Event::PolicyQuery(query) => reply_policy(query, &wires.latest_policy).await,
                    Event::Tick => {}
                    Event::Interrupt => {
                        tracing::info!("interrupted during training; the last checkpoint stays");
                        return Ok(false);
                    }
                }
            }
        };
        for segment in &late {
            self.store(&mut replay, segment);
        }
        let losses: EpochLosses = losses.context("training")?;
        let train_s = train_start.elapsed().as_secs_f64();
        self.trainer = Some(trainer);

        // 4. Bookkeeping.
        let row = EpochRow {
            epoch,
            beta: update.beta,
            steps_collected: self.state.ledger.stored_steps - stored_before,
            steps_published,
            segments: self.state.ledger.stored_segments - segments_before,
            d_plus: replay.len_plus(),
            d_uncertain: replay.len_uncertain(),
            dynamics_only: replay.len_dynamics_only(),
            autolabel_removed: removed,
            rho,
            imitation_loss: losses.imitation,
            safety_loss: losses.safety,
            dynamics_loss: losses.dynamics,
            critic_loss: losses.critic,
            critic_accuracy: losses.critic_accuracy,
            collect_s,
            train_s,
            epoch_s: epoch_start.elapsed().as_secs_f64(),
            closed_by_timeout: matches!(closed, Closed::Timeout { .. }),
            eval_version: self.last_eval.as_ref().map(|e| e.version),
            eval_laps: self.last_eval.as_ref().map(|e| e.laps),
        };
        tracing::info!(
            epoch,
            beta = format!("{:.3}", row.beta),
            d_plus = row.d_plus,
            d_uncertain = row.d_uncertain,
            imitation = format!("{:.5}", row.imitation_loss),
            safety = format!("{:.5}", row.safety_loss),
            collect_s = format!("{:.2}", collect_s),
            train_s = format!("{:.2}", train_s),
            "epoch done"
        );
        self.state.rows.push(row.clone());
        self.state.next_epoch = epoch + 1;
        self.replay = Some(replay);
        self.checkpoint()?;
        self.write_outputs(false)?;
        self.bar.set_position(epoch + 1);
        let metrics = json!({ "epoch": epoch, "row": row, "live_actors": self.live, "rejected_messages": wires.bus.rejects.count() });
        if let Err(e) = wires.bus.metrics(&metrics).await {
            tracing::warn!("publishing metrics: {e}");
        }
        Ok(true)
    }

    fn status(&self, epoch: u64, phase: &str) -> String {
        let replay = self.replay.as_ref();
        let eval = self
            .last_eval
            .as_ref()
            .map(|e| format!("v{}: {} laps", e.version, e.laps))
            .unwrap_or_else(|| "none".into());
        format!(
            "{phase} | beta {:.3} | D+ {} D? {} | actors {} | last eval {eval}",
            self.config.beta(epoch),
            replay.map_or(0, |r| r.len_plus()),
            replay.map_or(0, |r| r.len_uncertain()),
            self.live.len(),
        )
    }

    /// Handles a trajectory message: stores a segment (or queues it in `late` while training), returns a marker.
    fn on_traj(
        &mut self,
        sample: &zenoh::sample::Sample,
        wires: &Wires,
        late: Option<&mut Vec<Segment>>,
    ) -> Option<cabc_proto::messages::EpochDone> {
        let bytes = sample.payload().to_bytes();
        match decode_sample::<TrajMessage>(sample.key_expr().as_str(), &bytes, &wires.bus.rejects)?
        {
            TrajMessage::EpochDone(marker) => Some(marker),
            TrajMessage::Segment(segment) => {
                if !self.state.ledger.admit(&segment) {
                    tracing::warn!(
                        actor = segment.actor,
                        seq = segment.seq,
                        "duplicate segment dropped"
                    );
                    return None;
                }
                match late {
                    Some(late) => late.push(segment),
                    None => {
                        let mut replay =
                            self.replay.take().expect("replay present while collecting");
                        self.store(&mut replay, &segment);
                        self.replay = Some(replay);
                    }
                }
                None
            }
        }
    }

    fn store(&mut self, replay: &mut Replay, segment: &Segment) {
        // Complete laps driven by the expert alone (beta = 1) give the expert's lap time: every lap segment of an
        // episode after its first starts at the start line.
        if segment.outcome == Outcome::Lap
            && segment.policy_version == 0
            && self.config.beta(0) >= 1.0
        {
            let stream = (segment.actor.clone(), segment.env, segment.episode);
            if !self.expert_streams.insert(stream) {
                self.state
                    .expert_lap_times
                    .push(segment.steps.len() as f64 * 0.1);
            }
        }
        if let Err(e) = replay.add_segment(segment) {
            self.failed_segments += 1;
            tracing::warn!(
                actor = segment.actor,
                seq = segment.seq,
                "segment not stored: {e}"
            );
        }
    }

    fn on_eval(&mut self, sample: &zenoh::sample::Sample, wires: &Wires) {
        let bytes = sample.payload().to_bytes();
        let Some(report) =
            decode_sample::<EvalReport>(sample.key_expr().as_str(), &bytes, &wires.bus.rejects)
        else {
            return;
        };
        let summary = EvalSummary::of(&report);
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
                if let Some(weights) = self.history.get(&report.version) {
                    if let Err(e) = self.run_dir.write_file("best-policy.safetensors", weights) {
                        tracing::warn!("saving the early-stopped policy: {e}");
                    }
                }
            }
        }
        self.state.evals.push(summary);
        self.last_eval = Some(report);
    }

    fn on_alive(&mut self, sample: &zenoh::sample::Sample, gate: Option<&mut EpochGate>) {
        let Some(actor) = actor_of_token(sample.key_expr().as_str()) else {
            return;
        };
        match sample.kind() {
            SampleKind::Put => {
                tracing::info!(actor, "actor joined");
                if let Some(g) = gate {
                    g.alive(&actor);
                }
                self.live.insert(actor);
            }
            SampleKind::Delete => {
                tracing::warn!(actor, "actor left");
                if let Some(g) = gate {
                    g.gone(&actor);
                }
                self.live.remove(&actor);
            }
        }
    }

    fn checkpoint(&self) -> Result<()> {
        let trainer = self.trainer.as_ref().expect("trainer present");
        let replay = self.replay.as_ref().expect("replay present");
        let mut files = trainer.to_checkpoint();
        files.push(("replay.bin", replay.to_bytes()));
        self.run_dir
            .save_checkpoint(&self.state, files)
            .context("writing the checkpoint")?;
        Ok(())
    }

    fn write_outputs(&self, final_: bool) -> Result<()> {
        self.run_dir.write_tables(&self.state)?;
        if let Err(e) = plots::draw_all(
            &self.run_dir.plots(),
            &self.state,
            self.last_eval.as_ref(),
            self.config.collection.eval_laps,
        ) {
            tracing::warn!("drawing plots: {e}");
        }
        if final_ {
            if let Some(trainer) = &self.trainer {
                self.run_dir
                    .write_file("final-policy.safetensors", &trainer.policy_bytes())?;
            }
        }
        Ok(())
    }

    fn summary(&self, reason: &str, wires: &Wires) -> serde_json::Value {
        let first_50 = self
            .state
            .evals
            .iter()
            .find(|e| e.laps >= self.config.collection.eval_laps)
            .map(|e| e.version);
        let best = self
            .state
            .evals
            .iter()
            .max_by_key(|e| (e.laps, std::cmp::Reverse(e.version)));
        let expert = crate::rundir::mean_std(&self.state.expert_lap_times);
        let epochs = self.state.rows.len();
        let mean_epoch_s = if epochs > 0 {
            self.state.rows.iter().map(|r| r.epoch_s).sum::<f64>() / epochs as f64
        } else {
            0.0
        };
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
            "expert_lap_time": expert.map(|(m, s)| json!({"mean": m, "std": s, "laps": self.state.expert_lap_times.len()})),
            "mean_epoch_s": mean_epoch_s,
            "steps_stored": self.state.ledger.stored_steps,
            "segments_stored": self.state.ledger.stored_segments,
            "duplicate_segments": self.state.ledger.duplicates,
            "segments_not_stored": self.failed_segments,
            "rejected_messages": wires.bus.rejects.count(),
            "d_plus": self.replay.as_ref().map(|r| r.len_plus()),
            "d_uncertain": self.replay.as_ref().map(|r| r.len_uncertain()),
        })
    }
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

async fn reply_policy(query: zenoh::query::Query, latest: &[u8]) {
    if latest.is_empty() {
        return;
    }
    let key = query.key_expr().clone();
    if let Err(e) = query
        .reply(key, latest.to_vec())
        .encoding(encoding_of::<PolicyUpdate>())
        .await
    {
        tracing::warn!("answering a policy query: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actor_tokens_are_recognised() {
        assert_eq!(
            actor_of_token("cabc/r/alive/actor/actor-1").as_deref(),
            Some("actor-1")
        );
        assert_eq!(actor_of_token("cabc/r/alive/eval/e"), None);
        assert_eq!(actor_of_token("cabc/r/alive/learner"), None);
    }
}
