//! Constraint-aware training (algorithm.md 1 and 4; Algorithm 1 and Fig. 4 of the paper).
//!
//! Per epoch j, in the order of Algorithm 1: the dynamics model f_hat (eq. (16), on every stored (x, u, x')), the
//! critic p_hat (eq. (17), D+ against D-), then the policy on D+ with
//!
//! ```text
//!     L_CA = L_clone + L_safety,                                  eq. (15)
//!     L_clone  = || pi_theta(y) - pi_beta(x) ||^2                  (mean over batch and action dims)
//!     L_safety = -lambda * log p_hat( f_hat(x, pi_theta(y)) )      (mean over the batch)
//! ```
//!
//! through the frozen f_hat and p_hat (their variables are frozen, so gradients reach theta only). L_safety is used
//! once the critic has trained at least once; lambda = 0 is the behaviour-cloning baseline.
//!
//! Optimisation (all numbers from `TrainingSection`): Adam with weight decay, gradient-norm clip, ExponentialLR
//! stepped once per fit call, shuffled mini-batches with the last partial batch dropped. Deterministic for a seed on
//! one device: weights are initialised from the seed (cabc_models::init) and batches are shuffled by a seeded ChaCha.
//! Limitation: tch's optimiser does not expose Adam's moments, so `save` keeps weights, learning-rate schedule,
//! epoch counter and RNG, and Adam's moments restart on resume.

use crate::replay::{Replay, Store};
use cabc_models::Network;
use cabc_models::{parse_device, Critic, Dynamics, ModelError, Policy, PolicyArch, PolicyInput};
use cabc_proto::config::{RunConfig, ScheduleKind};
use cabc_proto::messages::{ACTION_DIM, STATE_DIM};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;
use tch::{nn, nn::OptimizerConfig, Device, Kind, Reduction, Tensor};

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    State { path: String, message: String },
    #[error("the camera policy needs images, and D+ holds none")]
    NoImages,
}

/// Every loss term of one epoch, for logging. Losses are means over the last pass of their fit call.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EpochLosses {
    pub epoch: u64,
    /// L_clone, eq. (15): MSE between pi_theta(y) and the expert's label.
    pub imitation: f64,
    /// L_safety, eq. (15): lambda * mean(-log sigmoid(critic(f_hat(x, pi_theta(y))))); 0 while inactive.
    pub safety: f64,
    /// Whether L_safety took part (lambda > 0 and the critic has trained).
    pub safety_active: bool,
    /// Eq. (16) MSE, when the dynamics model trained this epoch.
    pub dynamics: Option<f64>,
    /// Eq. (17) BCE, when the critic trained this epoch.
    pub critic: Option<f64>,
    /// Fraction of the critic's training points on the right side of p = 0.5 (last pass).
    pub critic_accuracy: Option<f64>,
    pub n_plus: usize,
    pub n_minus: usize,
    pub n_dynamics: usize,
    /// Samples seen by each network this epoch (all passes).
    pub policy_samples: usize,
    pub dynamics_samples: usize,
    pub critic_samples: usize,
    pub lr_policy: f64,
    pub seconds: f64,
}

/// One network's optimiser and learning-rate schedule.
struct Opt {
    opt: nn::Optimizer,
    /// Fit calls so far: lr = lr0 * gamma^fits.
    fits: u64,
}

/// What `save` writes beside the weights.
#[derive(Serialize, Deserialize)]
struct TrainerState {
    epochs_trained: u64,
    critic_trained: bool,
    fits: [u64; 3],
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    architectures: [String; 3],
}

/// The three networks, their optimisers and the epoch counter.
pub struct Trainer {
    config: RunConfig,
    device: Device,
    policy: Policy,
    dynamics: Dynamics,
    critic: Critic,
    opts: [Opt; 3],
    /// Epochs trained so far.
    pub epochs_trained: u64,
    critic_trained: bool,
    rng: ChaCha8Rng,
}

/// libtorch's intra-op threads on the CPU. These networks are small (batch 64, widths <= 256): with more threads
/// OpenMP's spinning costs more than it gains, up to 20x slower on a loaded 2-core machine (measured), and one thread
/// also makes CPU runs bit-reproducible. OpenMP keeps the setting per OS thread, so it is set on each fit call.
const CPU_THREADS: i32 = 1;

fn limit_cpu_threads(device: Device) {
    if device == Device::Cpu {
        tch::set_num_threads(CPU_THREADS);
    }
}

const POLICY: usize = 0;
const DYNAMICS: usize = 1;
const CRITIC: usize = 2;

impl Trainer {
    /// Networks and optimisers from the configuration, on `training.device`.
    pub fn new(config: &RunConfig) -> Result<Self, TrainError> {
        let device = parse_device(&config.training.device)?;
        Ok(Self::with_device(config, device))
    }

    pub fn with_device(config: &RunConfig, device: Device) -> Self {
        let seed = config.run.seed;
        let nets = &config.networks;
        let policy = Policy::new(PolicyArch::from_config(config), device, seed);
        let dynamics = Dynamics::new(nets.dynamics, device, seed.wrapping_add(1));
        let critic = Critic::new(STATE_DIM, nets.critic, device, seed.wrapping_add(2));
        let t = &config.training;
        let adam = |vs: &nn::VarStore| Opt {
            opt: nn::Adam::default()
                .wd(t.weight_decay)
                .build(vs, t.lr)
                .expect("Adam builds"),
            fits: 0,
        };
        let opts = [
            adam(policy.var_store()),
            adam(dynamics.var_store()),
            adam(critic.var_store()),
        ];
        Trainer {
            config: config.clone(),
            device,
            policy,
            dynamics,
            critic,
            opts,
            epochs_trained: 0,
            critic_trained: false,
            rng: ChaCha8Rng::seed_from_u64(seed.wrapping_add(3)),
        }
    }

    pub fn device(&self) -> Device {
        self.device
    }

    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    pub fn critic(&self) -> &Critic {
        &self.critic
    }

    /// The policy's weights for a `PolicyUpdate` (safetensors, architecture in the metadata).
    pub fn policy_bytes(&self) -> Vec<u8> {
        self.policy.to_bytes()
    }

    /// `PolicyUpdate.architecture`.
    pub fn policy_architecture(&self) -> String {
        self.policy.architecture()
    }

    /// Whether the critic has trained at least once (L_safety is active from then on when lambda > 0).
    pub fn critic_trained(&self) -> bool {
        self.critic_trained
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

    /// One epoch of Algorithm 1's training part. D- is D? where `d_minus` is true (None: all of D?, i.e. after
    /// [`Replay::remove_uncertain`] has applied the last labelling).
    pub fn train_epoch(
        &mut self,
        epoch: u64,
        replay: &Replay,
        d_minus: Option<&[bool]>,
    ) -> Result<EpochLosses, TrainError> {
        let start = Instant::now();
        limit_cpu_threads(self.device);
        let t = self.config.training.clone();
        let passes = if epoch == 0 {
            t.initial_passes
        } else {
            t.passes
        };
        let (dyn_due, critic_due, aux_passes) = match t.schedule {
            ScheduleKind::Paper => (
                epoch % t.dynamics_every == 0,
                epoch % t.critic_every == 0,
                t.aux_passes,
            ),
            ScheduleKind::EveryEpoch => (true, true, passes),
        };
        let minus: Vec<usize> = match d_minus {
            Some(mask) => (0..replay.uncertain.len())
                .filter(|&i| mask.get(i) == Some(&true))
                .collect(),
            None => (0..replay.uncertain.len()).collect(),
        };
        let mut losses = EpochLosses {
            epoch,
            n_plus: replay.plus.len(),
            n_minus: minus.len(),
            ..Default::default()
        };
        let dev = self.device;

        // Dynamics, eq. (16): every (x, u_applied, x') there is.
        let stores = [&replay.plus, &replay.uncertain, &replay.dynamics_only];
        losses.n_dynamics = stores.iter().map(|s| s.len()).sum();
        if dyn_due && losses.n_dynamics >= t.batch_size {
            let x = cat_rows(
                stores.iter().map(|s| s.states.as_flattened()),
                STATE_DIM,
                dev,
            );
            let u = cat_rows(
                stores.iter().map(|s| s.applied_actions.as_flattened()),
                ACTION_DIM,
                dev,
            );
            let x_next = cat_rows(
                stores.iter().map(|s| s.next_states.as_flattened()),
                STATE_DIM,
                dev,
            );
            let (loss, samples) = self.fit_dynamics(&x, &u, &x_next, aux_passes);
            losses.dynamics = Some(loss);
            losses.dynamics_samples = samples;
        }

        // Critic, eq. (17): D+ labelled 1, D- labelled `negative_label`.
        if critic_due
            && minus.len() > t.critic_min_uncertain
            && losses.n_plus + minus.len() >= t.batch_size
        {
            let neg: Vec<f32> = minus
                .iter()
                .flat_map(|&i| replay.uncertain.states[i])
                .collect();
            let x = cat_rows(
                [replay.plus.states.as_flattened(), neg.as_slice()].into_iter(),
                STATE_DIM,
                dev,
            );
            let labels = Tensor::cat(
                &[
                    Tensor::ones([losses.n_plus as i64], (Kind::Float, dev)),
                    Tensor::full(
                        [minus.len() as i64],
                        self.config.algorithm.negative_label,
                        (Kind::Float, dev),
                    ),
                ],
                0,
            );
            let opt = &mut self.opts[CRITIC];
            let fit = fit_critic(
                &self.critic,
                opt,
                &x,
                &labels,
                aux_passes,
                &self.config,
                &mut self.rng,
            );
            losses.critic = Some(fit.loss);
            losses.critic_accuracy = Some(fit.accuracy);
            losses.critic_samples = fit.samples;
            self.critic_trained = true;
        }

        // Policy, eq. (15), on D+.
        losses.lr_policy = self.lr(POLICY);
        if losses.n_plus >= t.batch_size {
            let fit = self.fit_policy(&replay.plus, passes)?;
            losses.imitation = fit.0;
            losses.safety = fit.1;
            losses.safety_active = fit.2;
            losses.policy_samples = fit.3;
        }
        self.epochs_trained = self.epochs_trained.max(epoch + 1);
        losses.seconds = start.elapsed().as_secs_f64();
        Ok(losses)
    }

    fn lr(&self, which: usize) -> f64 {
        let t = &self.config.training;
        t.lr * t.lr_gamma.powi(self.opts[which].fits as i32)
    }

    pub(crate) fn fit_dynamics(
        &mut self,
        x: &Tensor,
        u: &Tensor,
        x_next: &Tensor,
        passes: usize,
    ) -> (f64, usize) {
        limit_cpu_threads(self.device);
        let lr = self.lr(DYNAMICS);
        let (batch, clip) = (
            self.config.training.batch_size,
            self.config.training.grad_clip,
        );
        let opt = &mut self.opts[DYNAMICS];
        opt.opt.set_lr(lr);
        let n = x.size()[0] as usize;
        let mut last = Mean::default();
        let mut samples = 0;
        for _ in 0..passes {
            last = Mean::default();
            for idx in shuffled_batches(n, batch, &mut self.rng) {
                let idx = Tensor::from_slice(&idx).to_device(self.device);
                let xb = x.index_select(0, &idx);
                let pred = self.dynamics.forward(&xb, &u.index_select(0, &idx));
                let loss = pred.mse_loss(&x_next.index_select(0, &idx), Reduction::Mean);
                step(&mut opt.opt, &loss, clip);
                last.add(loss.double_value(&[]));
                samples += batch;
            }
        }
        opt.fits += 1;
        (last.get(), samples)
    }

    /// Returns (L_clone, L_safety, safety active, samples).
    pub(crate) fn fit_policy(
        &mut self,
        plus: &Store,
        passes: usize,
    ) -> Result<(f64, f64, bool, usize), TrainError> {
        limit_cpu_threads(self.device);
        let lr = self.lr(POLICY);
        let (batch, clip) = (
            self.config.training.batch_size,
            self.config.training.grad_clip,
        );
        let lambda = self.config.algorithm.lambda;
        let safety_active = lambda > 0.0 && self.critic_trained;
        let camera = matches!(self.policy.arch(), PolicyArch::Camera { .. });
        if camera && plus.images.is_none() {
            return Err(TrainError::NoImages);
        }
        let dev = self.device;
        let n = plus.len();
        let x_all = cat_rows(std::iter::once(plus.states.as_flattened()), STATE_DIM, dev);
        let label_all = cat_rows(
            std::iter::once(plus.expert_actions.as_flattened()),
            ACTION_DIM,
            dev,
        );
        let mut pixels: Vec<u8> = Vec::new();
        // Frozen f_hat and p_hat: no gradients into their variables (Fig. 4: non-bold blocks).
        self.dynamics.var_store_mut().freeze();
        self.critic.var_store_mut().freeze();
        self.opts[POLICY].opt.set_lr(lr);
        let (mut clone_mean, mut safety_mean) = (Mean::default(), Mean::default());
        let mut samples = 0;
        for _ in 0..passes {
            clone_mean = Mean::default();
            safety_mean = Mean::default();
            for idx_cpu in shuffled_batches(n, batch, &mut self.rng) {
                let idx = Tensor::from_slice(&idx_cpu).to_device(dev);
                let x = x_all.index_select(0, &idx);
                let label = label_all.index_select(0, &idx);
                let input = if camera {
                    let images = plus.images.as_ref().expect("checked above");
                    let len = images.image_len();
                    pixels.clear();
                    pixels.reserve(len * batch);
                    for &i in &idx_cpu {
                        pixels.extend_from_slice(images.get(i as usize));
                    }
                    PolicyInput::Camera {
                        images: Tensor::from_slice(&pixels).view([
                            batch as i64,
                            images.height as i64,
                            images.width as i64,
                            3,
                        ]),
                        velocity: x.narrow(1, 0, 3),
                    }
                } else {
                    PolicyInput::State(x.shallow_clone())
                };
                let u = self.policy.forward_t(&input, true);
                let l_clone = l_clone(&u, &label);
                let loss = if safety_active {
                    let l_safety = l_safety(&self.dynamics, &self.critic, &x, &u, lambda);
                    safety_mean.add(l_safety.double_value(&[]));
                    &l_clone + l_safety
                } else {
                    l_clone.shallow_clone()
                };
                step(&mut self.opts[POLICY].opt, &loss, clip);
                clone_mean.add(l_clone.double_value(&[]));
                samples += batch;
            }
        }
        self.opts[POLICY].fits += 1;
        self.dynamics.var_store_mut().unfreeze();
        self.critic.var_store_mut().unfreeze();
        Ok((clone_mean.get(), safety_mean.get(), safety_active, samples))
    }

    /// Writes the three networks (safetensors) and the trainer's state (JSON) into `dir`.
    pub fn save(&self, dir: &Path) -> Result<(), TrainError> {
        let io = |path: &Path| {
            let path = path.display().to_string();
            move |source| TrainError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        for (name, bytes) in [
            ("policy.safetensors", self.policy.to_bytes()),
            ("dynamics.safetensors", self.dynamics.to_bytes()),
            ("critic.safetensors", self.critic.to_bytes()),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, bytes).map_err(io(&path))?;
        }
        let state = TrainerState {
            epochs_trained: self.epochs_trained,
            critic_trained: self.critic_trained,
            fits: [self.opts[0].fits, self.opts[1].fits, self.opts[2].fits],
            rng_seed: self.rng.get_seed(),
            rng_stream: self.rng.get_stream(),
            rng_word_pos: self.rng.get_word_pos(),
            architectures: [
                self.policy.architecture(),
                self.dynamics.architecture(),
                self.critic.architecture(),
            ],
        };
        let path = dir.join("trainer.json");
        let text = serde_json::to_string_pretty(&state).expect("serialises");
        std::fs::write(&path, text).map_err(io(&path))
    }

    /// Restores what [`Trainer::save`] wrote into this trainer (built from the same configuration). Adam's moments
    /// restart (see the module doc).
    pub fn load(&mut self, dir: &Path) -> Result<(), TrainError> {
        let read = |name: &str| {
            let path = dir.join(name);
            std::fs::read(&path).map_err(|source| TrainError::Io {
                path: path.display().to_string(),
                source,
            })
        };
        let state_path = dir.join("trainer.json");
        let state: TrainerState =
            serde_json::from_slice(&read("trainer.json")?).map_err(|e| TrainError::State {
                path: state_path.display().to_string(),
                message: e.to_string(),
            })?;
        self.policy.load_bytes(&read("policy.safetensors")?)?;
        self.dynamics.load_bytes(&read("dynamics.safetensors")?)?;
        self.critic.load_bytes(&read("critic.safetensors")?)?;
        self.epochs_trained = state.epochs_trained;
        self.critic_trained = state.critic_trained;
        for (o, f) in self.opts.iter_mut().zip(state.fits) {
            o.fits = f;
        }
        let mut rng = ChaCha8Rng::from_seed(state.rng_seed);
        rng.set_stream(state.rng_stream);
        rng.set_word_pos(state.rng_word_pos);
        self.rng = rng;
        Ok(())
    }

    /// A trainer from `config`, restored from `dir`.
    pub fn resume(config: &RunConfig, dir: &Path) -> Result<Self, TrainError> {
        let mut t = Trainer::new(config)?;
        t.load(dir)?;
        Ok(t)
    }
}

/// L_clone of eq. (15): || pi_theta(y) - pi_beta(x) ||^2, mean over batch and action dimensions (reference).
pub fn l_clone(u: &Tensor, expert: &Tensor) -> Tensor {
    u.mse_loss(expert, Reduction::Mean)
}

/// L_safety of eq. (15): lambda * mean_batch( -log sigmoid( critic( f_hat(x, u) ) ) ), with
/// -log sigmoid(z) computed stably as -logsigmoid(z).
pub fn l_safety(
    dynamics: &Dynamics,
    critic: &Critic,
    x: &Tensor,
    u: &Tensor,
    lambda: f64,
) -> Tensor {
    let logits = critic.logits(&dynamics.forward(x, u));
    (-logits.log_sigmoid()).mean(Kind::Float) * lambda
}

/// The result of a critic fit.
#[derive(Clone, Copy, Debug, Default)]
pub struct CriticFit {
    /// Eq. (17) BCE, mean over the last pass.
    pub loss: f64,
    pub accuracy: f64,
    pub samples: usize,
}

/// Trains the critic by BCE-with-logits on (x, label) for `passes` (eq. (17)); one fit call: the learning rate is
/// lr0 * gamma^fits and the schedule steps once at the end. Shared by the trainer and the Fig. 3 demo.
fn fit_critic(
    critic: &Critic,
    opt: &mut Opt,
    x: &Tensor,
    labels: &Tensor,
    passes: usize,
    config: &RunConfig,
    rng: &mut ChaCha8Rng,
) -> CriticFit {
    limit_cpu_threads(x.device());
    let t = &config.training;
    opt.opt.set_lr(t.lr * t.lr_gamma.powi(opt.fits as i32));
    let n = x.size()[0] as usize;
    let mut fit = CriticFit::default();
    for _ in 0..passes {
        let (mut loss_mean, mut correct, mut seen) = (Mean::default(), 0i64, 0i64);
        for idx in shuffled_batches(n, t.batch_size, rng) {
            let idx = Tensor::from_slice(&idx).to_device(x.device());
            let target = labels.index_select(0, &idx);
            let logits = critic.logits(&x.index_select(0, &idx));
            let loss = logits.binary_cross_entropy_with_logits::<Tensor>(
                &target,
                None,
                None,
                Reduction::Mean,
            );
            step(&mut opt.opt, &loss, t.grad_clip);
            loss_mean.add(loss.double_value(&[]));
            correct += logits
                .gt(0.0)
                .eq_tensor(&target.gt(0.5))
                .sum(Kind::Int64)
                .int64_value(&[]);
            seen += idx.size()[0];
            fit.samples += t.batch_size;
        }
        fit.loss = loss_mean.get();
        fit.accuracy = correct as f64 / seen.max(1) as f64;
    }
    opt.fits += 1;
    fit
}

/// A critic with its own optimiser, for uses outside the trainer (the Fig. 3 demo).
pub struct CriticTrainer {
    pub critic: Critic,
    opt: Opt,
    rng: ChaCha8Rng,
}

impl CriticTrainer {
    /// A critic on `in_dim` inputs with the configured size and optimiser.
    pub fn new(in_dim: usize, config: &RunConfig, device: Device, seed: u64) -> Self {
        let critic = Critic::new(in_dim, config.networks.critic, device, seed);
        let t = &config.training;
        let opt = nn::Adam::default()
            .wd(t.weight_decay)
            .build(critic.var_store(), t.lr)
            .expect("Adam builds");
        CriticTrainer {
            critic,
            opt: Opt { opt, fits: 0 },
            rng: ChaCha8Rng::seed_from_u64(seed.wrapping_add(1)),
        }
    }

    /// One fit call of `passes` over (x [N, d], labels [N]).
    pub fn fit(
        &mut self,
        x: &Tensor,
        labels: &Tensor,
        passes: usize,
        config: &RunConfig,
    ) -> CriticFit {
        fit_critic(
            &self.critic,
            &mut self.opt,
            x,
            labels,
            passes,
            config,
            &mut self.rng,
        )
    }
}

fn step(opt: &mut nn::Optimizer, loss: &Tensor, clip: f64) {
    opt.zero_grad();
    loss.backward();
    opt.clip_grad_norm(clip);
    opt.step();
}

/// Shuffled index batches of exactly `batch` (the last partial batch is dropped).
fn shuffled_batches(n: usize, batch: usize, rng: &mut ChaCha8Rng) -> Vec<Vec<i64>> {
    let mut perm: Vec<i64> = (0..n as i64).collect();
    perm.shuffle(rng);
    perm.chunks_exact(batch.max(1))
        .map(|c| c.to_vec())
        .collect()
}

/// Row-major f32 slices of `cols` columns, stacked into one [N, cols] tensor on `device`.
fn cat_rows<'a>(parts: impl Iterator<Item = &'a [f32]>, cols: usize, device: Device) -> Tensor {
    let mut flat: Vec<f32> = Vec::new();
    for p in parts {
        flat.extend_from_slice(p);
    }
    let n = (flat.len() / cols) as i64;
    Tensor::from_slice(&flat)
        .view([n, cols as i64])
        .to_device(device)
}

#[derive(Default)]
struct Mean {
    sum: f64,
    n: usize,
}

impl Mean {
    fn add(&mut self, v: f64) {
        self.sum += v;
        self.n += 1;
    }

    fn get(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum / self.n as f64
        }
    }
}
