//! Fitting the policy pi_theta on D+, eq. (14): L_CA = L_clone + L_safety, through the frozen f_hat and p_hat
//! (Fig. 4: their variables are frozen, so gradients reach theta only).

use super::data::Uploaded;
use super::fit::{fit, Budget, Mean};
use super::{TrainError, Trainer};
use crate::replay::Replay;
use cabc_models::{Critic, Dynamics, Network, PolicyArch, PolicyInput};
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

impl Trainer {
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

    /// lambda_j, L_safety's weight in the epoch the trainer trains next ([`RunConfig::lambda`]: `algorithm.lambda`,
    /// or its warm-up from `lambda_start`). The one derivation: j is the trainer's own count of the epochs it has
    /// trained, which its checkpoint keeps, so Algorithm 1's epoch ([`Trainer::train`]), a bare policy fit
    /// ([`Trainer::fit_policy`]: benchmarks, tests) and a resumed trainer read the same lambda_j.
    pub fn lambda(&self) -> f64 {
        self.config.lambda(self.epochs_trained)
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
        let plus = &replay.plus;
        if plus.len() < self.config.training.batch_size {
            return Ok(PolicyFit::default());
        }
        let lambda = self.lambda();
        let safety_active = lambda > 0.0 && self.critic_trusted();
        let cloned = self.cloned_uncertain(replay);
        let images = match (self.policy.arch(), &plus.images, &replay.uncertain.images) {
            (PolicyArch::Camera { .. }, None, _) => return Err(TrainError::NoImages("D+")),
            (PolicyArch::Camera { .. }, Some(_), None) if !cloned.is_empty() => {
                return Err(TrainError::NoImages("D?"))
            }
            (PolicyArch::Camera { .. }, Some(plus), uncertain) => Some((plus, uncertain)),
            (PolicyArch::State { .. }, ..) => None,
        };
        let dev = self.device;
        let (x_all, label_all) = self.clone_set(data, &cloned);
        let (x_all, label_all) = (&x_all, &label_all);
        let n_plus = plus.len();
        // Ours: f_hat and p_hat frozen (Fig. 4), the clip over theta alone. The reference: they stay trainable, so
        // L_safety accumulates into their gradients (never zeroed here, their optimisers do not step), and the clip
        // measures theta's gradient together with theirs.
        let clip_also = match self.config.training.clip_scope {
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
        };
        let (policy, dynamics, critic) = (&self.policy, &self.dynamics, &self.critic);
        let (safety_states, safety_term) = (
            self.config.training.safety_states,
            self.config.training.safety_term,
        );
        let fitted = fit(
            &mut self.policy_opt,
            &self.config.training,
            dev,
            &mut self.rng,
            x_all.size()[0] as usize,
            Budget {
                passes,
                max_batches: self.config.training.policy_max_batches,
            },
            &clip_also,
            |b, pass: &mut Pass| {
                let x = x_all.index_select(0, &b.idx);
                let input = match images {
                    Some((images, uncertain_images)) => PolicyInput::camera(
                        images.width,
                        images.height,
                        b.rows.iter().map(|&i| {
                            let i = i as usize;
                            match uncertain_images {
                                Some(u) if i >= n_plus => {
                                    let j = cloned[i - n_plus] as usize;
                                    (u.get(j), velocity_of(&replay.uncertain.states[j]))
                                }
                                _ => (images.get(i), velocity_of(&plus.states[i])),
                            }
                        }),
                    )?,
                    None => PolicyInput::State(x.shallow_clone()),
                };
                let u = policy.forward_t(&input, true);
                let label = label_all.index_select(0, &b.idx);
                let l_clone = l_clone(&u, &label);
                pass.clone.add(&l_clone);
                if !safety_active {
                    return Ok(l_clone);
                }
                // L_safety's rows: every row of the batch (eq. (14), `safety_states = "clone"`), or its D+ rows alone
                // (the first `n_plus` of the clone set; the recorded runs).
                let (x, u, label) =
                    if safety_states == SafetyStates::DPlus && x_all.size()[0] as usize > n_plus {
                        let rows = b.idx.lt(n_plus as i64).nonzero().squeeze_dim(1);
                        if rows.size()[0] == 0 {
                            return Ok(l_clone);
                        }
                        let pick = |t: &Tensor| t.index_select(0, &rows);
                        (pick(&x), pick(&u), pick(&label))
                    } else {
                        (x, u, label)
                    };
                let l_safety = match safety_term {
                    SafetyTerm::Absolute => l_safety(dynamics, critic, &x, &u, lambda),
                    SafetyTerm::Hinged => l_safety_hinged(dynamics, critic, &x, &u, &label, lambda),
                };
                pass.safety.add(&l_safety);
                Ok(l_clone + l_safety)
            },
        );
        self.dynamics.var_store_mut().unfreeze();
        self.critic.var_store_mut().unfreeze();
        let (pass, samples) = fitted?;
        Ok(PolicyFit {
            imitation: pass.clone.get(),
            safety: pass.safety.get(),
            safety_active,
            samples,
        })
    }
}
