//! Fitting the critic p_hat, eq. (16): binary cross-entropy of D+ (label 1) against D- (label `negative_label`),
//! D- as auto-labelling left it (eq. (19), [`Replay::minus`]).

use super::fit::{cat_rows, fit, Budget, Mean, Opt};
use super::Trainer;
use crate::replay::Replay;
use crate::schedule::Schedule;
use cabc_models::{Critic, Network};
use cabc_proto::config::{CriticNegatives, RunConfig};
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
    /// The training set's size: |D+| + the negatives in the trainer.
    pub points: usize,
    /// Of these, the positives (label 1): `points - positives` are the negatives.
    pub positives: usize,
}

/// The critic's negatives (`algorithm.critic_negatives`): D- as the last labelling left it (ours; never a D? point
/// that labelling did not see), or all of D? as it is now (the reference's full-state trainer).
pub fn critic_negatives(replay: &Replay, which: CriticNegatives) -> &[[f32; STATE_DIM]] {
    match which {
        CriticNegatives::DMinus => replay.minus(),
        CriticNegatives::Uncertain => &replay.uncertain.states,
    }
}

/// The critic's training set: the states of D+ then of the negatives ([N, 6] on `device`), and their labels (1 for
/// D+, `negative_label` for the negatives).
pub fn critic_examples(
    replay: &Replay,
    negatives: CriticNegatives,
    negative_label: f64,
    device: Device,
) -> (Tensor, Tensor) {
    let minus = critic_negatives(replay, negatives);
    let (n_plus, n_minus) = (replay.len_plus() as i64, minus.len() as i64);
    let x = cat_rows(
        [replay.plus.states.as_flattened(), minus.as_flattened()],
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
    /// One fit call of p_hat, eq. (16), on D+ against the negatives ([`critic_negatives`]). None (nothing trained,
    /// the rng untouched) when the negatives are not more than `critic_min_uncertain` or the examples fewer than
    /// `batch_size`; under the every-epoch schedule that also turns L_safety off until the critic trains again
    /// (the reference's `critic.initialized = False`). Marks the critic trained.
    pub fn fit_critic(&mut self, replay: &Replay, passes: usize) -> Option<CriticFit> {
        let (t, a) = (&self.config.training, &self.config.algorithm);
        let n_minus = critic_negatives(replay, a.critic_negatives).len();
        let n = replay.len_plus() + n_minus;
        if n_minus <= t.critic_min_uncertain || n < t.batch_size {
            if !Schedule::from_config(&self.config).safety_outlives_critic_fit() {
                self.critic_trained = false;
            }
            return None;
        }
        let (x, labels) =
            critic_examples(replay, a.critic_negatives, a.negative_label, self.device);
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
        &[],
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
    let positives = labels.eq(1.0).sum(Kind::Int64).int64_value(&[]) as usize;
    CriticFit {
        loss: pass.loss.get(),
        accuracy: pass.correct as f64 / pass.seen.max(1) as f64,
        samples,
        points: n,
        positives,
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
