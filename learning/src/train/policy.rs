//! Fitting the policy pi_theta on D+, eq. (14): L_CA = L_clone + L_safety, through the frozen f_hat and p_hat
//! (Fig. 4: their variables are frozen, so gradients reach theta only).

use super::data::Uploaded;
use super::fit::{fit, Budget, Mean};
use super::{TrainError, Trainer};
use crate::replay::{ImageStore, Replay};
use cabc_models::{Critic, Dynamics, ModelError, Network, PolicyArch, PolicyInput};
#[allow(unused_imports)] // the doc link
use cabc_proto::config::RunConfig;
use cabc_proto::config::{ClipScope, SafetyStates, SafetyTerm};
use cabc_proto::messages::{velocity_of, ACTION_DIM};
use tch::{Kind, Reduction, Tensor};

/// L_clone, eq. (6) and the first term of eq. (14): || pi_theta(y) - pi_beta(x) ||^2, mean over batch and action.
pub fn l_clone(u: &Tensor, expert: &Tensor) -> Tensor {
    u.mse_loss(expert, Reduction::Mean)
}

/// L_safety, eq. (14): -lambda log p_hat(f_hat(x, u)), mean over the batch (-log sigmoid as a stable log_sigmoid).
pub fn l_safety(
    dynamics: &Dynamics,
    critic: &Critic,
    x: &Tensor,
    u: &Tensor,
    lambda: f64,
) -> Tensor {
    (-log_safety(dynamics, critic, x, u)).mean(Kind::Float) * lambda
}

/// L_safety relative to the expert (`training.safety_term = "hinged"`, issue 45): lambda max(0, log p_hat(f_hat(x,
/// u_expert)) - log p_hat(f_hat(x, u))), mean over the batch. The expert's side is a constant (no gradient reaches
/// any network through it): an action predicted at least as safe as the expert's costs nothing.
pub fn l_safety_hinged(
    dynamics: &Dynamics,
    critic: &Critic,
    x: &Tensor,
    u: &Tensor,
    expert: &Tensor,
    lambda: f64,
) -> Tensor {
    let bar = tch::no_grad(|| log_safety(dynamics, critic, x, expert));
    (bar - log_safety(dynamics, critic, x, u))
        .relu()
        .mean(Kind::Float)
        * lambda
}

/// log p_hat(f_hat(x, u)) per row.
fn log_safety(dynamics: &Dynamics, critic: &Critic, x: &Tensor, u: &Tensor) -> Tensor {
    critic.logits(&dynamics.forward(x, u)).log_sigmoid()
}

/// The result of a policy fit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PolicyFit {
    /// L_clone, mean over the last pass.
    pub imitation: f64,
    /// L_safety, mean over the last pass; 0 while inactive.
    pub safety: f64,
    /// Whether L_safety took part (lambda > 0, the critic has trained and passes `training.safety_gate`).
    pub safety_active: bool,
    /// Samples seen (all passes); 0 when D+ holds fewer than `batch_size` steps and nothing trained.
    pub samples: usize,
}

/// What one pass of a policy fit reports.
#[derive(Default)]
struct Pass {
    clone: Mean,
    safety: Mean,
}

/// L_safety's term as the run chooses it (`training.safety_term`), at lambda_j, through f_hat and p_hat.
struct Safety<'a> {
    dynamics: &'a Dynamics,
    critic: &'a Critic,
    term: SafetyTerm,
    lambda: f64,
}

impl Safety<'_> {
    /// L_safety of actions `u` at states `x`: eq. (14)'s, or relative to the expert's `label` ("hinged").
    fn loss(&self, x: &Tensor, u: &Tensor, label: &Tensor) -> Tensor {
        let (dynamics, critic, lambda) = (self.dynamics, self.critic, self.lambda);
        match self.term {
            SafetyTerm::Absolute => l_safety(dynamics, critic, x, u, lambda),
            SafetyTerm::Hinged => l_safety_hinged(dynamics, critic, x, u, label, lambda),
        }
    }
}

/// A batch's rows of the clone set: the states, pi_theta's actions and the expert's labels.
struct BatchRows {
    x: Tensor,
    u: Tensor,
    label: Tensor,
}

/// L_safety's rows of a batch (`idx`, into a clone set of `n_all` rows whose first `n_plus` are D+'s): every row
/// (eq. (14), `safety_states = "clone"`, or a clone set of D+ alone), or its D+ rows alone (the recorded runs);
/// None when the batch holds none of them.
fn safety_rows(
    states: SafetyStates,
    n_plus: usize,
    n_all: usize,
    idx: &Tensor,
    rows: BatchRows,
) -> Option<BatchRows> {
    if states != SafetyStates::DPlus || n_all <= n_plus {
        return Some(rows);
    }
    let plus = idx.lt(n_plus as i64).nonzero().squeeze_dim(1);
    if plus.size()[0] == 0 {
        return None;
    }
    let pick = |t: &Tensor| t.index_select(0, &plus);
    Some(BatchRows {
        x: pick(&rows.x),
        u: pick(&rows.u),
        label: pick(&rows.label),
    })
}

/// What pi_theta sees of the clone set's rows: their states, or (a camera policy) each row's image and velocities,
/// from D+'s images and, past D+, from the D? rows L_clone fits too.
enum Inputs<'a> {
    State,
    Camera {
        replay: &'a Replay,
        plus: &'a ImageStore,
        uncertain: Option<&'a ImageStore>,
        /// D?'s rows in the clone set, after D+'s ([`Trainer::cloned_uncertain`]).
        cloned: &'a [i64],
    },
}

impl<'a> Inputs<'a> {
    /// The inputs of `arch` for the clone set of `replay`'s D+ and D?'s `cloned` rows; a camera policy needs their
    /// images.
    fn of(arch: PolicyArch, replay: &'a Replay, cloned: &'a [i64]) -> Result<Self, TrainError> {
        match (arch, &replay.plus.images, &replay.uncertain.images) {
            (PolicyArch::Camera { .. }, None, _) => Err(TrainError::NoImages("D+")),
            (PolicyArch::Camera { .. }, Some(_), None) if !cloned.is_empty() => {
                Err(TrainError::NoImages("D?"))
            }
            (PolicyArch::Camera { .. }, Some(plus), uncertain) => Ok(Inputs::Camera {
                replay,
                plus,
                uncertain: uncertain.as_ref(),
                cloned,
            }),
            (PolicyArch::State { .. }, ..) => Ok(Inputs::State),
        }
    }

    /// The input of a batch: the clone set's `rows`, whose states are `x`.
    fn batch(&self, rows: &[i64], x: &Tensor) -> Result<PolicyInput, ModelError> {
        let Inputs::Camera {
            replay,
            plus,
            uncertain,
            cloned,
        } = self
        else {
            return Ok(PolicyInput::State(x.shallow_clone()));
        };
        let n_plus = replay.plus.len();
        let frame = |i: i64| {
            let i = i as usize;
            match uncertain {
                Some(u) if i >= n_plus => {
                    let j = cloned[i - n_plus] as usize;
                    (u.get(j), velocity_of(&replay.uncertain.states[j]))
                }
                _ => (plus.get(i), velocity_of(&replay.plus.states[i])),
            }
        };
        PolicyInput::camera(plus.width, plus.height, rows.iter().map(|&i| frame(i)))
    }
}

impl Trainer {
    /// lambda_j, L_safety's weight in the epoch the trainer trains next ([`RunConfig::lambda`]: `algorithm.lambda`,
    /// or its warm-up from `lambda_start`). The one derivation: j is the trainer's own count of the epochs it has
    /// trained, which its checkpoint keeps, so Algorithm 1's epoch ([`Trainer::train_epoch`]), a bare policy fit
    /// ([`Trainer::fit_policy`]: benchmarks, tests) and a resumed trainer read the same lambda_j.
    pub fn lambda(&self) -> f64 {
        self.config.lambda(self.epochs_trained)
    }

    /// D?'s rows that L_clone fits besides D+ (Algorithm 1 and the reference: none): with
    /// `training.clone_uncertain`, the D? steps whose label is the expert's (the actor labels a step where the
    /// expert failed with [0, 0], `cabc_actor::collect`; an exact zero from MPCC has measure zero), in D?'s order.
    fn cloned_uncertain(&self, replay: &Replay) -> Vec<i64> {
        if !self.config.training.clone_uncertain {
            return Vec::new();
        }
        let labelled = |a: &[f32; ACTION_DIM]| a.iter().map(|v| v.abs()).sum::<f32>() > 0.0;
        (0..replay.uncertain.len() as i64)
            .filter(|&i| labelled(&replay.uncertain.expert_actions[i as usize]))
            .collect()
    }

    /// The states and expert labels L_clone fits: D+, then D?'s `cloned` rows ([`Trainer::cloned_uncertain`]).
    fn clone_set(&self, data: &Uploaded, cloned: &[i64]) -> (Tensor, Tensor) {
        let plus = (
            data.plus.states.shallow_clone(),
            data.plus.expert_actions.shallow_clone(),
        );
        if cloned.is_empty() {
            return plus;
        }
        let u = &data.uncertain;
        let rows = Tensor::from_slice(cloned).to_device(self.device);
        (
            Tensor::cat(&[&plus.0, &u.states.index_select(0, &rows)], 0),
            Tensor::cat(&[&plus.1, &u.expert_actions.index_select(0, &rows)], 0),
        )
    }

    /// f_hat and p_hat for a policy fit, as `training.clip_scope` says; the variables the gradient clip measures
    /// besides theta. Ours: frozen (Fig. 4), the clip over theta alone. The reference: they stay trainable, so
    /// L_safety accumulates into their gradients (never zeroed here, their optimisers do not step), and the clip
    /// measures theta's gradient together with theirs. [`Trainer::thaw`] undoes it.
    fn freeze_for_clip(&mut self) -> Vec<Tensor> {
        match self.config.training.clip_scope {
            ClipScope::Policy => {
                self.dynamics.var_store_mut().freeze();
                self.critic.var_store_mut().freeze();
                Vec::new()
            }
            ClipScope::PolicyCriticDynamics => {
                let mut vars = self.critic.var_store().trainable_variables();
                vars.extend(self.dynamics.var_store().trainable_variables());
                vars
            }
        }
    }

    /// f_hat and p_hat trainable again after a policy fit.
    fn thaw(&mut self) {
        self.dynamics.var_store_mut().unfreeze();
        self.critic.var_store_mut().unfreeze();
    }

    /// One fit call of pi_theta on D+, eq. (14), at lambda_j ([`Trainer::lambda`]). With fewer than `batch_size`
    /// steps in D+ nothing trains (the rng and the learning-rate schedule untouched) and the fit is all zeros. A
    /// camera policy needs D+'s images (and D?'s, when it clones D? too).
    pub fn fit_policy(&mut self, replay: &Replay, passes: usize) -> Result<PolicyFit, TrainError> {
        let data = self.upload(replay);
        self.fit_policy_on(replay, &data, passes)
    }

    /// [`Trainer::fit_policy`] on the epoch's uploaded replay (D+'s images, when the policy sees them, are batched
    /// from `replay` on the host).
    pub(crate) fn fit_policy_on(
        &mut self,
        replay: &Replay,
        data: &Uploaded,
        passes: usize,
    ) -> Result<PolicyFit, TrainError> {
        let n_plus = replay.plus.len();
        if n_plus < self.config.training.batch_size {
            return Ok(PolicyFit::default());
        }
        let lambda = self.lambda();
        let safety_active = lambda > 0.0 && self.critic_trusted();
        let cloned = self.cloned_uncertain(replay);
        let inputs = Inputs::of(self.policy.arch(), replay, &cloned)?;
        let (x_all, label_all) = self.clone_set(data, &cloned);
        let n_all = x_all.size()[0] as usize;
        let clip_also = self.freeze_for_clip();
        let t = &self.config.training;
        let policy = &self.policy;
        let safety = Safety {
            dynamics: &self.dynamics,
            critic: &self.critic,
            term: t.safety_term,
            lambda,
        };
        let budget = Budget {
            passes,
            max_batches: t.policy_max_batches,
        };
        let fitted = fit(
            &mut self.policy_opt,
            t,
            t.precision,
            self.device,
            &mut self.rng,
            n_all,
            budget,
            &clip_also,
            |b, pass: &mut Pass| {
                let x = x_all.index_select(0, &b.idx);
                let u = policy.forward_t(&inputs.batch(b.rows, &x)?, true);
                let label = label_all.index_select(0, &b.idx);
                // Eq. (14): L_CA = L_clone + L_safety, L_safety while active and on its rows.
                let l_clone = l_clone(&u, &label);
                if b.reported {
                    pass.clone.add(&l_clone);
                }
                let rows = BatchRows { x, u, label };
                let Some(rows) = safety_active
                    .then(|| safety_rows(t.safety_states, n_plus, n_all, &b.idx, rows))
                    .flatten()
                else {
                    return Ok(l_clone);
                };
                let l_safety = safety.loss(&rows.x, &rows.u, &rows.label);
                if b.reported {
                    pass.safety.add(&l_safety);
                }
                Ok(l_clone + l_safety)
            },
        );
        self.thaw();
        let (pass, samples) = fitted?;
        Ok(PolicyFit {
            imitation: pass.clone.get(),
            safety: pass.safety.get(),
            safety_active,
            samples,
        })
    }
}
