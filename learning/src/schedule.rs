//! When each part of Algorithm 1 runs in epoch j: auto-labelling, the dynamics model (every k_f epochs), the critic
//! (every k_p epochs), and how many passes each fit makes (more for the policy in epoch 0, the warm-up).
//!
//! All numbers come from the run configuration (`algorithm.autolabel_every`, `training.dynamics_every` = k_f,
//! `training.critic_every` = k_p, `training.initial_passes` / `passes` / `aux_passes`, `training.schedule`,
//! `collection.overlap`).

use cabc_proto::config::{RunConfig, ScheduleKind};

/// What trains in an epoch besides the policy: Algorithm 1's `j mod k_f = 0` (f_hat) and `j mod k_p = 0` (p_hat),
/// read by the trainer's epoch ([`crate::Trainer::train_epoch`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Due {
    /// f_hat trains (eq. (15)).
    pub dynamics: bool,
    /// p_hat trains (eq. (16)).
    pub critic: bool,
}

/// The schedule of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Schedule {
    kind: ScheduleKind,
    autolabel_every: u64,
    /// k_f.
    dynamics_every: u64,
    /// k_p.
    critic_every: u64,
    initial_passes: usize,
    passes: usize,
    aux_passes: usize,
    initial_aux_passes: usize,
    /// `collection.overlap`.
    overlap: bool,
}

impl Schedule {
    pub fn from_config(config: &RunConfig) -> Self {
        let t = &config.training;
        Schedule {
            kind: t.schedule,
            autolabel_every: config.algorithm.autolabel_every,
            dynamics_every: t.dynamics_every,
            critic_every: t.critic_every,
            initial_passes: t.initial_passes,
            passes: t.passes,
            aux_passes: t.aux_passes,
            initial_aux_passes: t.initial_aux_passes.unwrap_or(t.aux_passes),
            overlap: config.collection.overlap,
        }
    }

    /// Whether epoch j trains while its D_new is collected (`collection.overlap`, from epoch 1 on: epoch 0 has
    /// nothing to train on before its collection), on what the learner held before; else it trains after.
    pub fn overlapped(&self, j: u64) -> bool {
        self.overlap && j > 0
    }

    /// Whether D? is auto-labelled (eq. (19)) before training in epoch j; the same under both kinds of schedule.
    pub fn autolabel_due(&self, j: u64) -> bool {
        j % self.autolabel_every == 0
    }

    /// What trains in epoch j besides the policy ([`Schedule::dynamics_due`], [`Schedule::critic_due`]).
    pub fn due(&self, j: u64) -> Due {
        Due {
            dynamics: self.dynamics_due(j),
            critic: self.critic_due(j),
        }
    }

    /// Whether f_hat trains in epoch j: every k_f epochs (Algorithm 1), or every epoch (`EveryEpoch`).
    pub fn dynamics_due(&self, j: u64) -> bool {
        match self.kind {
            ScheduleKind::Paper => j % self.dynamics_every == 0,
            ScheduleKind::EveryEpoch => true,
        }
    }

    /// Whether p_hat trains in epoch j: every k_p epochs (Algorithm 1), or every epoch (`EveryEpoch`).
    pub fn critic_due(&self, j: u64) -> bool {
        match self.kind {
            ScheduleKind::Paper => j % self.critic_every == 0,
            ScheduleKind::EveryEpoch => true,
        }
    }

    /// Passes of the policy over D+ in epoch j: `initial_passes` in epoch 0 (the warm-up), `passes` later.
    pub fn policy_passes(&self, j: u64) -> usize {
        if j == 0 {
            self.initial_passes
        } else {
            self.passes
        }
    }

    /// Passes of f_hat and p_hat when they train in epoch j: `initial_aux_passes` (or `aux_passes`) in epoch 0 and
    /// `aux_passes` later
    /// (Algorithm 1; the reference's vision trainer: 50 and 10), or the policy's passes (`EveryEpoch`, the
    /// reference's full-state trainer).
    pub fn aux_passes(&self, j: u64) -> usize {
        match self.kind {
            ScheduleKind::Paper if j == 0 => self.initial_aux_passes,
            ScheduleKind::Paper => self.aux_passes,
            ScheduleKind::EveryEpoch => self.policy_passes(j),
        }
    }

    /// Whether L_safety stays on in an epoch whose critic fit did not run (too few negatives). Under Algorithm 1 the
    /// critic keeps its last fit between k_p epochs; the reference's full-state trainer switches the term off for an
    /// epoch whose D? is empty (`critic.initialized = False`).
    pub fn safety_outlives_critic_fit(&self) -> bool {
        self.kind == ScheduleKind::Paper
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_and_every_epoch_schedules() {
        let mut c = RunConfig::default();
        c.training.dynamics_every = 5;
        c.training.critic_every = 10;
        c.training.initial_passes = 7;
        c.training.passes = 2;
        c.training.aux_passes = 3;
        c.training.initial_aux_passes = Some(30);
        c.algorithm.autolabel_every = 4;
        let s = Schedule::from_config(&c);
        let due = |f: fn(&Schedule, u64) -> bool| (0..21).filter(|&j| f(&s, j)).collect::<Vec<_>>();
        assert_eq!(due(Schedule::dynamics_due), [0, 5, 10, 15, 20]);
        assert_eq!(due(Schedule::critic_due), [0, 10, 20]);
        assert_eq!(due(Schedule::autolabel_due), [0, 4, 8, 12, 16, 20]);
        let both = |dynamics, critic| Due { dynamics, critic };
        assert_eq!(
            [s.due(0), s.due(5), s.due(7)],
            [both(true, true), both(true, false), both(false, false)]
        );
        assert_eq!((s.policy_passes(0), s.policy_passes(1)), (7, 2));
        assert_eq!((s.aux_passes(0), s.aux_passes(1)), (30, 3));
        c.training.schedule = ScheduleKind::EveryEpoch;
        let s = Schedule::from_config(&c);
        assert!((0..5).all(|j| s.dynamics_due(j) && s.critic_due(j)));
        assert_eq!((s.aux_passes(0), s.aux_passes(1)), (7, 2));
        assert!(!s.autolabel_due(1));
        assert!(!(0..5).any(|j| s.overlapped(j)), "Algorithm 1's order");
        c.collection.overlap = true;
        let s = Schedule::from_config(&c);
        assert!((1..21).all(|j| s.overlapped(j)) && !s.overlapped(0));
    }
}
