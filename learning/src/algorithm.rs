//! Algorithm 1 of the paper, "Constraint-aware Behavior Cloning", one epoch j per turn of the loop.
//!
//! The actors are a port ([`Rollouts`]): over zenoh in a distributed run (`cabc_bus::rollouts`), in-process in a
//! test (`cabc_actor::local`). Everything the learner holds (D+, D?, D-, the three networks, the evaluations, the
//! checkpoint) is in [`Learner`]; the schedule (k_f, k_p, the auto-labelling period, the passes) in [`Schedule`]. Each
//! epoch's metrics are one [`Record`], each put where it is computed.

use crate::learner::{Learner, LearnerError};
use crate::record::Record;
use crate::schedule::Schedule;
use crate::sink::{Bus, Sink};
use cabc_proto::ports::Rollouts;
use std::time::Instant;

/// Why a run ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ending {
    /// The second evaluation that completed `eval_laps` laps: this policy version is kept (early stopping).
    EarlyStop(u64),
    /// `run.max_epochs` epochs done.
    MaxEpochs,
    /// Ctrl-C: the last checkpoint stays, `--resume` continues.
    Interrupted,
}

/// Runs Algorithm 1 from the learner's next epoch until early stop, `max_epochs` or an interrupt.
pub fn run(learner: &mut Learner, actors: &mut dyn Rollouts) -> Result<Ending, LearnerError> {
    let schedule = Schedule::from_config(&learner.config);
    for j in learner.state.next_epoch..learner.config.run.max_epochs {
        let started = Instant::now();
        let mut record = Record::new(j);
        // pi_collect <- beta_j pi_beta + (1 - beta_j) pi_theta: publish (pi_j, beta_j).
        let update = learner.policy_update(j);
        record.real("beta", update.beta, 6);
        // Rollout pi_collect to collect D_new.
        learner.begin_epoch();
        let Some(collected) = actors.collect(&update, &mut |segment| learner.store(segment))?
        else {
            return Ok(Ending::Interrupted);
        };
        record.real("collect_s", started.elapsed().as_secs_f64(), 3);
        // The actors' own counts (their markers).
        record.count("steps_published", collected.steps_published);
        record.count("steps_taken", collected.steps_taken);
        record.count("steps_staged", collected.steps_staged);
        if learner.config.collection.shield > 0.0 {
            record.count("steps_shielded", collected.steps_shielded);
        }
        record.flag("closed_by_timeout", collected.timed_out);
        // Partition D_new into D+' (laps) and D?' (failures): D+ <- D+ u D+', D? <- D? u D?'.
        learner.partition(&mut record);
        // Safety auto-labelling (eq. (19)), every `autolabel_every` epochs: remove from D? every x inside the convex
        // hull of its D+ neighbours within rho; what D? then holds is D-, until the next labelling.
        let labelled = schedule
            .autolabel_due(j)
            .then(|| learner.autolabel(j))
            .flatten();
        record.count(
            "autolabel_removed",
            labelled.map_or(0, |(removed, _)| removed),
        );
        record.exact(
            "rho",
            labelled.map_or(learner.config.algorithm.rho, |(_, rho)| rho),
        );
        // ComputeGradient and Update (Trainer::train_epoch): phi_f every k_f epochs (eq. (15)), phi_p every k_p epochs
        // (eq. (16), D+ against D-), theta every epoch (eq. (14): L_clone + L_safety through the frozen f_hat and
        // p_hat); or all three every epoch (the reference's full-state trainer, `training.schedule`).
        learner.progress(j, "training");
        learner
            .trainer
            .train_epoch(j, &learner.replay, &mut record)?;
        // Evaluate: the evaluator drives pi_j alone from the fixed spawn; the second evaluation that completes
        // `eval_laps` laps stops the run and keeps that version.
        for report in actors.evaluations() {
            learner.on_eval(report);
        }
        // The record: to the checkpoint, the learner's sinks (metrics.csv, TensorBoard, ...) and the bus.
        learner.end_epoch(record, started)?;
        if let Some(record) = learner.state.rows.last() {
            let live = &collected.live;
            Bus {
                actors: &mut *actors,
                live,
            }
            .write(record)?;
        }
        if actors.interrupted() {
            return Ok(Ending::Interrupted);
        }
        if let Some(version) = learner.state.evaluations.early_stop() {
            return Ok(Ending::EarlyStop(version));
        }
    }
    Ok(Ending::MaxEpochs)
}
