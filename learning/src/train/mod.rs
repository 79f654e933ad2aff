//! Constraint-aware training: the training part of Algorithm 1 and Fig. 4 of the paper.
//!
//! Per epoch j, in the order of Algorithm 1 ([`Trainer::train_epoch`], when due by the [`Schedule`]): the dynamics
//! model f_hat (eq. (15), on every stored (x, u, x'), [`Trainer::fit_dynamics`]), the critic p_hat (eq. (16), D+
//! against D-, [`Trainer::fit_critic`]), then the policy on D+ ([`Trainer::fit_policy`]) with
//!
//! ```text
//!     L_CA = L_clone + L_safety,                                  eq. (14)
//!     L_clone  = || pi_theta(y) - pi_beta(x) ||^2                  eq. (6)  (mean over batch and action dims)
//!     L_safety = -lambda * log p_hat( f_hat(x, pi_theta(y)) )      eq. (14) (mean over the batch)
//! ```
//!
//! through the frozen f_hat and p_hat. L_safety is used once the critic has trained at least once; lambda = 0 is the
//! behaviour-cloning baseline.
//!
//! Optimisation (all numbers from `TrainingSection`): one fit loop for the three networks ([`fit`]): Adam with weight
//! decay (`adam.rs`: libtorch's update, bit-identical to tch's `nn::Adam`, but with its moments in our hands),
//! gradient-norm clip, ExponentialLR stepped once per fit call, shuffled mini-batches with the last partial batch
//! dropped. Deterministic for a seed on one device: weights are initialised from the seed (cabc_models::init) and
//! batches are shuffled by one seeded ChaCha, consumed in the order dynamics, critic, policy. Nothing is lost on
//! resume (`state.rs`): the checkpoint holds the weights, Adam's moments and step counts, the schedules and the RNG,
//! so a resumed run continues bit for bit as the uninterrupted one.

mod adam;
mod critic;
mod data;
mod dynamics;
mod fit;
mod policy;
mod standardise;
mod state;

pub use adam::Adam;
pub use critic::{critic_examples, heldout, CriticFit, CriticTrainer, Heldout, ECE_BINS};
pub use dynamics::Fit;
pub use fit::{profiled, FitProfile};
pub use policy::{l_clone, l_safety, l_safety_hinged, PolicyFit};
pub use standardise::{Standardiser, MIN_STD};

use crate::checkpoint::CheckpointError;
use crate::record::Record;
use crate::replay::Replay;
use crate::schedule::Schedule;
use cabc_models::{parse_device, Critic, Dynamics, ModelError, Network, Policy, PolicyArch};
use cabc_proto::config::{ClipScope, Precision, RunConfig, VisionTrunk};
use cabc_proto::messages::STATE_DIM;
use data::Uploaded;
use fit::{limit_cpu_threads, Opt};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::time::Instant;
use tch::Device;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: {message}")]
    State { path: String, message: String },
    #[error("the camera policy needs images, and {0} holds none")]
    NoImages(&'static str),
}

/// The three networks, their optimisers, the epoch counter and the batch-shuffling RNG.
pub struct Trainer {
    config: RunConfig,
    /// The run's schedule, built once from `config`: what trains in an epoch and for how many passes.
    schedule: Schedule,
    device: Device,
    policy: Policy,
    dynamics: Dynamics,
    critic: Critic,
    policy_opt: Opt,
    dynamics_opt: Opt,
    critic_opt: Opt,
    /// Epochs trained so far.
    pub epochs_trained: u64,
    critic_trained: bool,
    rng: ChaCha8Rng,
    /// The state's standardisation (`training.standardise`), from D+ at the first policy fit.
    standardiser: Option<Standardiser>,
    /// The moving average of the policy's weights (`training.policy_ema`), from the first policy fit on.
    ema: Option<Policy>,
    /// The critic's last held-out balanced accuracy (`training.safety_gate`).
    heldout_balanced: Option<f64>,
}

impl Trainer {
    /// Networks and optimisers from the configuration, on `training.device`.
    pub fn new(config: &RunConfig) -> Result<Self, TrainError> {
        let device = parse_device(&config.training.device)?;
        Ok(Self::with_device(config, device))
    }

    /// Logs the arithmetic training will use (bf16 asked for on a CPU is fp32, said once).
    fn log_precision(config: &RunConfig, device: Device) {
        let asked = config.training.precision;
        if asked == Precision::Bf16 && !cabc_models::precision::mixed(asked, device) {
            tracing::warn!(
                ?device,
                "training.precision = \"bf16\" applies on CUDA only: training in fp32"
            );
        }
    }

    pub fn with_device(config: &RunConfig, device: Device) -> Self {
        let seed = config.run.seed;
        let nets = &config.networks;
        Self::log_precision(config, device);
        let policy = Policy::new(PolicyArch::from_config(config), device, seed);
        let dynamics = Dynamics::new(nets.dynamics, device, seed.wrapping_add(1));
        let critic = Critic::new(STATE_DIM, nets.critic, device, seed.wrapping_add(2));
        let t = &config.training;
        let mut dynamics_opt = Opt::adam(dynamics.var_store(), t);
        let mut critic_opt = Opt::adam(critic.var_store(), t);
        // Under the reference's clip their gradients count in the policy's clip, so a checkpoint keeps them.
        let keep_grads = t.clip_scope == ClipScope::PolicyCriticDynamics;
        dynamics_opt.adam.keep_grads = keep_grads;
        critic_opt.adam.keep_grads = keep_grads;
        let policy_opt = Opt::with_gamma(
            policy.var_store(),
            t,
            t.policy_lr_gamma.unwrap_or(t.lr_gamma),
        );
        Trainer {
            config: config.clone(),
            schedule: Schedule::from_config(config),
            device,
            policy_opt,
            dynamics_opt,
            critic_opt,
            policy,
            dynamics,
            critic,
            epochs_trained: 0,
            critic_trained: false,
            rng: ChaCha8Rng::seed_from_u64(seed.wrapping_add(3)),
            standardiser: None,
            ema: None,
            heldout_balanced: None,
        }
    }

    pub fn device(&self) -> Device {
        self.device
    }

    /// The run's schedule (k_f, k_p, the auto-labelling period, the passes): the one Algorithm 1's loop reads.
    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    /// The policy as it trains: on standardised states when `training.standardise` is on ([`Trainer::standardiser`]).
    /// What actors drive is [`Trainer::deployed_policy`].
    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    /// The state's standardisation the networks train under, once taken (`training.standardise`).
    pub fn standardiser(&self) -> Option<&Standardiser> {
        self.standardiser.as_ref()
    }

    /// The moving average of the policy's weights, once the policy has trained (`training.policy_ema` > 0).
    pub fn policy_ema(&self) -> Option<&Policy> {
        self.ema.as_ref()
    }

    /// The replay's arrays on the training device, standardised as the networks train.
    fn upload(&self, replay: &Replay) -> Uploaded {
        Uploaded::of(replay, self.device, self.standardiser.as_ref())
    }

    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    pub fn critic(&self) -> &Critic {
        &self.critic
    }

    /// The published policy's weights for a `PolicyUpdate` (safetensors, architecture in the metadata): the moving
    /// average when `training.policy_ema` > 0, else the trained weights, with the state's standardisation folded
    /// into the first layer, so that it takes raw states.
    pub fn policy_bytes(&self) -> Vec<u8> {
        let source = self.ema.as_ref().unwrap_or(&self.policy);
        match (&self.standardiser, source.arch()) {
            (Some(s), PolicyArch::State { .. }) => {
                let mut deployed = Policy::new(source.arch(), Device::Cpu, 0);
                deployed
                    .var_store_mut()
                    .copy(source.var_store())
                    .expect("a policy's copy of the same architecture");
                deployed
                    .fold_input_standardisation(&s.mean, &s.std)
                    .expect("a full-state policy");
                deployed.to_bytes()
            }
            _ => source.to_bytes(),
        }
    }

    /// The published policy ([`Trainer::policy_bytes`]) on the CPU: what the actors drive.
    pub fn deployed_policy(&self) -> Policy {
        Policy::from_bytes(&self.policy_bytes(), Device::Cpu).expect("the trainer's own weights")
    }

    /// `PolicyUpdate.architecture`.
    pub fn policy_architecture(&self) -> String {
        self.policy.architecture()
    }

    /// Whether the critic has trained at least once (L_safety is active from then on when lambda > 0).
    pub fn critic_trained(&self) -> bool {
        self.critic_trained
    }

    /// Whether L_safety may act: the critic has trained and, under `training.safety_gate` > 0, its last held-out
    /// balanced accuracy reached the gate.
    fn critic_trusted(&self) -> bool {
        let gate = self.config.training.safety_gate;
        self.critic_trained && (gate <= 0.0 || self.heldout_balanced.is_some_and(|b| b >= gate))
    }

    /// Loads `observation.pretrained` (torchvision ResNet-18 weights) into the policy's trunk; returns what the
    /// trunk starts from, for the run's summary.
    pub fn init_trunk(&mut self) -> Result<String, TrainError> {
        let arch = self.policy.arch();
        let PolicyArch::Camera { trunk, .. } = arch else {
            return Ok("none (full-state policy)".into());
        };
        match (&self.config.observation.pretrained, trunk) {
            (None, VisionTrunk::Resnet18) => {
                tracing::warn!(
                    "the ResNet-18 trunk starts from random weights (observation.pretrained is not set; the \
                     reference starts from ImageNet's)"
                );
                Ok("random (observation.pretrained not set)".into())
            }
            (None, _) => Ok("random".into()),
            (Some(path), _) => {
                let bytes = std::fs::read(path).map_err(|e| TrainError::State {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
                let n =
                    self.policy
                        .load_pretrained_trunk(&bytes)
                        .map_err(|e| TrainError::State {
                            path: path.clone(),
                            message: e.to_string(),
                        })?;
                tracing::info!(
                    path,
                    tensors = n,
                    "the trunk starts from pretrained weights"
                );
                Ok(format!("pretrained: {path} ({n} tensors)"))
            }
        }
    }

    /// Steps the three optimisers parameter by parameter, as libtorch's Adam does, instead of over their flat
    /// buffers: the reference the flat step's bits are tested against.
    #[doc(hidden)]
    pub fn per_variable_steps(&mut self) {
        for opt in [
            &mut self.policy_opt,
            &mut self.dynamics_opt,
            &mut self.critic_opt,
        ] {
            opt.adam.per_variable = true;
        }
    }

    /// Marks the critic as trained (benchmarks and tests of L_safety with a hand-set critic).
    pub fn set_critic_trained(&mut self, trained: bool) {
        self.critic_trained = trained;
    }

    pub fn critic_mut(&mut self) -> &mut Critic {
        &mut self.critic
    }

    pub fn dynamics_mut(&mut self) -> &mut Dynamics {
        &mut self.dynamics
    }

    /// The policy's learning rate for its next fit call.
    pub fn lr_policy(&self) -> f64 {
        self.policy_opt.lr()
    }

    /// ema = d * ema + (1 - d) * theta after a policy fit, d = `training.policy_ema`; the first fit starts it at
    /// theta.
    fn update_ema(&mut self) {
        let d = self.config.training.policy_ema;
        if d == 0.0 {
            return;
        }
        match &mut self.ema {
            None => {
                let mut ema = Policy::new(self.policy.arch(), self.device, 0);
                ema.var_store_mut()
                    .copy(self.policy.var_store())
                    .expect("a policy's copy of the same architecture");
                self.ema = Some(ema);
            }
            Some(ema) => {
                let theta = self.policy.var_store().variables();
                tch::no_grad(|| {
                    for (name, mut average) in ema.var_store().variables() {
                        let next = &average * d + &theta[&name] * (1.0 - d);
                        average.copy_(&next);
                    }
                });
            }
        }
    }

    /// Takes the state's standardisation from D+, once (`training.standardise`): before anything trains on, or is
    /// measured on, standardised states.
    fn standardise_from(&mut self, replay: &Replay) {
        if self.config.training.standardise && self.standardiser.is_none() {
            self.standardiser = Standardiser::of(&replay.plus.states);
            if let Some(s) = &self.standardiser {
                tracing::info!(mean = ?s.mean, std = ?s.std, "the state's standardisation, from D+");
            }
        }
    }

    /// One epoch of Algorithm 1's training part, the one place an epoch trains (the learner's, a test's, a
    /// benchmark's): p_hat's held-out measure before this epoch's fits ([`Trainer::measure_critic`]: the record's
    /// `critic_heldout_*`, and what `training.safety_gate` reads in this epoch's policy fit), then, as the run's
    /// [`Schedule`] says for `epoch` (the record's epoch), f_hat when due (eq. (15), j mod k_f = 0), p_hat when due
    /// (eq. (16), D+ against its negatives, j mod k_p = 0) and pi_theta (eq. (14), at the trainer's lambda_j,
    /// [`Trainer::lambda`]), each for the schedule's passes. Auto-labelling is the caller's
    /// ([`Replay::apply_labels`]), before this call. The losses, and the samples each network saw, go into the epoch's
    /// `record`, the one place they are kept.
    pub fn train_epoch(
        &mut self,
        epoch: u64,
        replay: &Replay,
        record: &mut Record,
    ) -> Result<(), TrainError> {
        if let Some(heldout) = self.measure_critic(replay) {
            heldout.put(record);
        }
        let due = self.schedule.due(epoch);
        let start = Instant::now();
        limit_cpu_threads(self.device);
        self.standardise_from(replay);
        let data = self.upload(replay);
        if due.dynamics {
            if let Some(fit) = self.fit_dynamics_on(&data, self.schedule.aux_passes(epoch)) {
                // Eq. (15)'s MSE, a mean over the fit call's last pass.
                record.real("dynamics_loss", fit.loss, 6);
                // Samples each network saw this epoch (all passes).
                record.count("dynamics_samples", fit.samples);
            }
        }
        if due.critic {
            if let Some(fit) = self.fit_critic_on(&data, self.schedule.aux_passes(epoch)) {
                // Eq. (16)'s BCE, and the share of its points on the right side of p = 0.5 (last pass).
                record.real("critic_loss", fit.loss, 6);
                record.real("critic_accuracy", fit.accuracy, 6);
                // The critic's training set, |D+| + |D-|: its positives and negatives.
                record.count("critic_points", fit.points);
                record.count("critic_positives", fit.positives);
                record.count("critic_negatives", fit.points.saturating_sub(fit.positives));
                record.count("critic_samples", fit.samples);
            }
        }
        record.exact("lr_policy", self.lr_policy());
        if self.config.algorithm.lambda_start.is_some() {
            record.real("lambda", self.lambda(), 6);
        }
        let fit = self.fit_policy_on(replay, &data, self.schedule.policy_passes(epoch))?;
        if fit.samples > 0 {
            self.update_ema();
        }
        // L_clone (eq. (14)'s first term) and L_safety = lambda * mean(-log p_hat(f_hat(x, pi(y)))) (its second; 0
        // while inactive: lambda = 0 or no critic trained yet).
        record.real("imitation_loss", fit.imitation, 6);
        record.real("safety_loss", fit.safety, 6);
        record.flag("safety_active", fit.safety_active);
        record.count("policy_samples", fit.samples);
        self.epochs_trained = self.epochs_trained.max(epoch + 1);
        record.real("train_s", start.elapsed().as_secs_f64(), 3);
        Ok(())
    }
}
