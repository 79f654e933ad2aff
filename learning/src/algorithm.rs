//! Algorithm 1 of the paper, "Constraint-aware Behavior Cloning", one epoch j per turn of the loop.
//!
//! The actors are a port ([`Rollouts`]): over zenoh in a distributed run (`cabc_bus::rollouts`), in-process in a
//! test (`cabc_actor::local`). Everything the learner holds (D+, D?, D-, the three networks, the evaluations, the
//! checkpoint, the epoch's record and its sinks) is in [`Learner`]; the schedule (k_f, k_p, the auto-labelling
//! period, the passes) in its trainer's [`Schedule`], built once from the run's configuration: read here (the
//! overlap, the auto-labelling) and in the trainer's epoch (k_f, k_p, the passes: `Trainer::train_epoch`). Each
//! epoch's metrics are one record ([`crate::record::Record`]), each put where it is computed. Under
//! `training.schedule = "every-epoch"` (the reference's full-state trainer) f_hat, p_hat and pi all train every
//! epoch.
//!
//! Under `collection.overlap` (issue 46) epoch j >= 1 trains while the actors collect its D_new with pi_j, on the
//! data of epochs < j; the collecting policy is then one version behind Algorithm 1's, and an epoch takes about the
//! longer of collection and training instead of their sum.

use crate::learner::{Learner, LearnerError};
use crate::schedule::Schedule;
use cabc_proto::ports::Rollouts;

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
    let schedule: Schedule = *learner.schedule();
    // A resumed run that had reached its early stop (interrupted in the epoch that reached it) ends there.
    if let Some(version) = learner.early_stop() {
        return Ok(Ending::EarlyStop(version));
    }
    for j in learner.next_epoch()..learner.config().run.max_epochs {
        learner.begin_epoch(j);
        // pi_collect <- beta_j pi_beta + (1 - beta_j) pi_theta: publish (pi_j, beta_j); rollout pi_collect: D_new.
        let update = learner.policy_update(j);
        actors.publish(&update)?;
        // Under `collection.overlap` the learner trains while D_new is collected, on what it held before.
        if schedule.overlapped(j) {
            learner.train()?;
        }
        let Some(collected) = actors.gather(&update, &mut |segment| learner.store(segment))? else {
            return Ok(Ending::Interrupted);
        };
        // Interrupted while the epoch closed (a scheduler's SIGTERM reaches the learner and the actors at once, and
        // the actors' last markers can close the epoch short): the epoch is not kept short. The run ends at the
        // checkpoint of the epoch before, and a resumed run collects this one whole.
        if actors.interrupted() {
            return Ok(Ending::Interrupted);
        }
        // Partition D_new into D+' (laps) and D?' (failures): D+ <- D+ u D+', D? <- D? u D?'.
        learner.partition(&collected);
        // Safety auto-labelling (eq. (19)), every `autolabel_every` epochs: remove from D? every x inside the convex
        // hull of its D+ neighbours within rho; what D? then holds is D-, until the next labelling.
        learner.autolabel(schedule.autolabel_due(j));
        // ComputeGradient; if j mod k_f = 0, update phi_f (eq. (15)); if j mod k_p = 0, update phi_p (eq. (16), D+
        // against D-); update theta (eq. (14): L_clone + L_safety through the frozen f_hat and p_hat). The schedule's
        // k_f and k_p, read in the trainer's epoch.
        if !schedule.overlapped(j) {
            learner.train()?;
        }
        // Evaluate: pi_j alone from the fixed spawn; the second evaluation with `eval_laps` laps keeps that version.
        for report in actors.evaluations() {
            learner.on_eval(report);
        }
        // The epoch's record: to the checkpoint and the learner's sinks (metrics.csv, TensorBoard, the bus, ...). The
        // checkpoint holds the epoch's segments now: their actors may forget them.
        learner.end_epoch()?;
        actors.commit(&learner.settled());
        if actors.interrupted() {
            return Ok(Ending::Interrupted);
        }
        if let Some(version) = learner.early_stop() {
            return Ok(Ending::EarlyStop(version));
        }
    }
    Ok(Ending::MaxEpochs)
}
