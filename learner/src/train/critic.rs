//! Fitting the critic p_hat, eq. (16): binary cross-entropy of D+ (label 1) against D- (label `negative_label`),
//! D- as auto-labelling left it (eq. (19), [`Replay::minus`]).

use super::fit::{cat_rows, fit, Budget, Mean, Opt};
use super::Trainer;
use crate::replay::Replay;
use cabc_models::{Critic, Network};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::STATE_DIM;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Reduction, Tensor};

/// The result of a critic fit.
#[derive(Clone, Copy, Debug, Default)]
pub struct CriticFit {
    /// Eq. (16) BCE, mean over the last pass.
    pub loss: f64,
    /// Fraction of the training points on the right side of p = 0.5 (last pass).
    pub accuracy: f64,
    /// Samples seen (all passes).
    pub samples: usize,
    /// The training set's size: |D+| + |D-| in the trainer.
    pub points: usize,
}

/// The critic's training set: the states of D+ then of D- ([N, 6] on `device`), and their labels (1 for D+,
/// `negative_label` for D-). Never a D? point that the last labelling did not see.
pub fn critic_examples(replay: &Replay, negative_label: f64, device: Device) -> (Tensor, Tensor) {
    let (n_plus, n_minus) = (replay.len_plus() as i64, replay.len_minus() as i64);
    let x = cat_rows(
        [
            replay.plus.states.as_flattened(),
            replay.minus().as_flattened(),
        ],
        STATE_DIM,
        device,
    );
    let labels = Tensor::cat(
        &[
            Tensor::ones([n_plus], (Kind::Float, device)),
            Tensor::full([n_minus], negative_label, (Kind::Float, device)),
        ],
        0,
    );
    (x, labels)
}

impl Trainer {
    /// One fit call of p_hat, eq. (16), on D+ against D-. None (nothing trained, the rng untouched) when |D-| is
    /// not above `critic_min_uncertain` or D+ and D- hold fewer than `batch_size` points. Marks the critic trained.
    pub fn fit_critic(&mut self, replay: &Replay, passes: usize) -> Option<CriticFit> {
        let t = &self.config.training;
        let n = replay.len_plus() + replay.len_minus();
        if replay.len_minus() <= t.critic_min_uncertain || n < t.batch_size {
            return None;
        }
        let (x, labels) =
            critic_examples(replay, self.config.algorithm.negative_label, self.device);
        let fit = fit_critic(
            &self.critic,
            &mut self.critic_opt,
            &x,
            &labels,
            passes,
            &self.config,
            &mut self.rng,
        );
        self.critic_trained = true;
        Some(fit)
    }
}

/// What one pass of a critic fit reports.
#[derive(Default)]
struct Pass {
    loss: Mean,
    correct: i64,
    seen: i64,
}

/// Trains `critic` by BCE-with-logits on (x, labels) for `passes`: one fit call. Shared by the trainer and
/// [`CriticTrainer`].
fn fit_critic(
    critic: &Critic,
    opt: &mut Opt,
    x: &Tensor,
    labels: &Tensor,
    passes: usize,
    config: &RunConfig,
    rng: &mut ChaCha8Rng,
) -> CriticFit {
    let n = x.size()[0] as usize;
    let (pass, samples) = fit(
        opt,
        &config.training,
        x.device(),
        rng,
        n,
        Budget {
            passes,
            max_batches: config.training.aux_max_batches,
        },
        |b, pass: &mut Pass| {
            let target = labels.index_select(0, &b.idx);
            let logits = critic.logits(&x.index_select(0, &b.idx));
            let loss = logits.binary_cross_entropy_with_logits::<Tensor>(
                &target,
                None,
                None,
                Reduction::Mean,
            );
            pass.loss.add(loss.double_value(&[]));
            pass.correct += logits
                .gt(0.0)
                .eq_tensor(&target.gt(0.5))
                .sum(Kind::Int64)
                .int64_value(&[]);
            pass.seen += b.rows.len() as i64;
            Ok(loss)
        },
    )
    .expect("the critic loss does not fail");
    CriticFit {
        loss: pass.loss.get(),
        accuracy: pass.correct as f64 / pass.seen.max(1) as f64,
        samples,
        points: n,
    }
}

/// A critic with its own optimiser, for uses outside the trainer (the Fig. 3 demo, benchmarks).
pub struct CriticTrainer {
    pub critic: Critic,
    opt: Opt,
    rng: ChaCha8Rng,
}

impl CriticTrainer {
    /// A critic on `in_dim` inputs with the configured size and optimiser.
    pub fn new(in_dim: usize, config: &RunConfig, device: Device, seed: u64) -> Self {
        let critic = Critic::new(in_dim, config.networks.critic, device, seed);
        let opt = Opt::adam(critic.var_store(), &config.training);
        CriticTrainer {
            critic,
            opt,
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
