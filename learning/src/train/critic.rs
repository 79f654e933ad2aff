//! Fitting the critic p_hat, eq. (16): binary cross-entropy of D+ (label 1) against D- (label `negative_label`),
//! D- as auto-labelling left it (eq. (19), [`Replay::minus`]).

use super::data::{self, Uploaded};
use super::fit::{fit, Budget, Mean, Opt, AUX_PRECISION};
use super::Trainer;
use crate::record::Record;
use crate::replay::{Replay, Store};
use cabc_models::{Critic, Network};
use cabc_proto::config::{CriticNegatives, RunConfig};
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

/// The critic's training set: the states of D+ then of its negatives ([N, 6] on `device`), and their labels (1 for
/// D+, `negative_label` for the negatives): D- as the last labelling left it (`critic_negatives = "d-minus"`, ours;
/// never a D? point that labelling did not see), or all of D? as it is now (`"uncertain"`, the reference's
/// full-state trainer).
pub fn critic_examples(
    replay: &Replay,
    negatives: CriticNegatives,
    negative_label: f64,
    device: Device,
) -> (Tensor, Tensor) {
    examples(
        &Uploaded::of(replay, device, None),
        negatives,
        negative_label,
    )
}

/// [`critic_examples`] from the epoch's uploaded replay.
fn examples(data: &Uploaded, negatives: CriticNegatives, negative_label: f64) -> (Tensor, Tensor) {
    let minus = negatives_of(data, negatives);
    let device = minus.device();
    let (n_plus, n_minus) = (data.plus.len as i64, minus.size()[0]);
    let x = Tensor::cat(&[&data.plus.states, minus], 0);
    let labels = Tensor::cat(
        &[
            Tensor::ones([n_plus], (Kind::Float, device)),
            Tensor::full([n_minus], negative_label, (Kind::Float, device)),
        ],
        0,
    );
    (x, labels)
}

fn negatives_of(data: &Uploaded, which: CriticNegatives) -> &Tensor {
    match which {
        CriticNegatives::DMinus => &data.minus,
        CriticNegatives::Uncertain => &data.uncertain.states,
    }
}

impl Trainer {
    /// One fit call of p_hat, eq. (16), on D+ against its negatives ([`critic_examples`]). None (nothing trained,
    /// the rng untouched) when the negatives are not more than `critic_min_uncertain` or the examples fewer than
    /// `batch_size`; under the every-epoch schedule that also turns L_safety off until the critic trains again
    /// (the reference's `critic.initialized = False`). Marks the critic trained.
    pub fn fit_critic(&mut self, replay: &Replay, passes: usize) -> Option<CriticFit> {
        self.fit_critic_on(&self.upload(replay), passes)
    }

    /// [`Trainer::fit_critic`] on the epoch's uploaded replay.
    pub(crate) fn fit_critic_on(&mut self, data: &Uploaded, passes: usize) -> Option<CriticFit> {
        let (t, a) = (&self.config.training, &self.config.algorithm);
        let n_minus = negatives_of(data, a.critic_negatives).size()[0] as usize;
        let n = data.plus.len + n_minus;
        if n_minus <= t.critic_min_uncertain || n < t.batch_size {
            if !self.schedule.safety_outlives_critic_fit() {
                self.critic_trained = false;
            }
            return None;
        }
        let (x, labels) = examples(data, a.critic_negatives, a.negative_label);
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

impl Trainer {
    /// p_hat as it stands before this epoch's fits, on D_new's rows of D+ (safe) and of D? (failures, as this epoch's
    /// labelling left them when it labelled), none of which it has trained on (issue 45): None before its first fit
    /// or without new rows. Its balanced accuracy is what `training.safety_gate` reads until the next measure.
    pub fn measure_critic(&mut self, replay: &Replay) -> Option<Heldout> {
        if !self.critic_trained {
            return None;
        }
        self.standardise_from(replay);
        let new_rows = |store: &Store, rows: std::ops::Range<usize>| {
            data::states(&store.states[rows], self.device, self.standardiser.as_ref())
        };
        let h = heldout(
            &self.critic,
            &new_rows(&replay.plus, replay.fresh_plus()),
            &new_rows(&replay.uncertain, replay.fresh_uncertain()),
        )?;
        if h.balanced.is_some() {
            self.heldout_balanced = h.balanced;
        }
        Some(h)
    }
}

/// What one pass of a critic fit reports.
#[derive(Default)]
struct Pass {
    loss: Mean,
    /// Per batch, the share of points on the right side of p = 0.5 (batches are all `batch_size` long).
    accuracy: Mean,
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
        AUX_PRECISION,
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
            if b.reported {
                pass.loss.add(&loss);
                let right = logits.gt(0.0).eq_tensor(&target.gt(0.5));
                pass.accuracy
                    .add(&right.to_kind(Kind::Float).mean(Kind::Float));
            }
            Ok(loss)
        },
    )
    .expect("the critic loss does not fail");
    let positives = labels.eq(1.0).sum(Kind::Int64).int64_value(&[]) as usize;
    CriticFit {
        loss: pass.loss.get(),
        accuracy: pass.accuracy.get(),
        samples,
        points: n,
        positives,
    }
}

/// The critic on rows it has not trained on: what [`heldout`] reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Heldout {
    pub points: usize,
    /// Of these, the positives (D+'s rows): the accuracy of always saying "safe" is `positives / points`.
    pub positives: usize,
    /// The share on the right side of p = 0.5.
    pub accuracy: f64,
    /// The mean of the two classes' accuracies (None without rows of both): what a critic that calls every state
    /// safe scores 0.5 on, however few the negatives.
    pub balanced: Option<f64>,
    /// The Brier score, mean of (p - y)^2.
    pub brier: f64,
    /// The expected calibration error over `ECE_BINS` equal-width bins of p: sum over bins of
    /// (points in bin / points) |mean p - mean y|.
    pub ece: f64,
}

impl Heldout {
    /// The measure in the epoch's record: accuracy, balanced accuracy (with rows of both classes), Brier score and
    /// calibration error.
    pub fn put(&self, record: &mut Record) {
        record.count("critic_heldout_points", self.points);
        record.count("critic_heldout_positives", self.positives);
        record.real("critic_heldout_accuracy", self.accuracy, 6);
        if let Some(balanced) = self.balanced {
            record.real("critic_heldout_balanced", balanced, 6);
        }
        record.real("critic_heldout_brier", self.brier, 6);
        record.real("critic_heldout_ece", self.ece, 6);
    }
}

/// The bins of [`Heldout::ece`].
pub const ECE_BINS: usize = 10;

/// p_hat on `safe` rows (label 1) and `unsafe_` rows (label 0), states as the critic takes them; None without rows.
pub fn heldout(critic: &Critic, safe: &Tensor, unsafe_: &Tensor) -> Option<Heldout> {
    let (n_safe, n_unsafe) = (safe.size()[0] as usize, unsafe_.size()[0] as usize);
    let points = n_safe + n_unsafe;
    if points == 0 {
        return None;
    }
    let p = tch::no_grad(|| critic.probability(&Tensor::cat(&[safe, unsafe_], 0)));
    let p = Vec::<f32>::try_from(p.to_kind(Kind::Float).to_device(Device::Cpu).reshape([-1]))
        .expect("a float tensor");
    let label = |i: usize| if i < n_safe { 1.0 } else { 0.0 };
    let (mut right, mut right_safe, mut brier) = (0usize, 0usize, 0.0f64);
    let mut bins = [(0usize, 0.0f64, 0.0f64); ECE_BINS];
    for (i, &p) in p.iter().enumerate() {
        let (p, y) = (f64::from(p), label(i));
        let hit = usize::from((p > 0.5) == (y > 0.5));
        right += hit;
        right_safe += if i < n_safe { hit } else { 0 };
        brier += (p - y) * (p - y);
        let bin = &mut bins[((p * ECE_BINS as f64) as usize).min(ECE_BINS - 1)];
        *bin = (bin.0 + 1, bin.1 + p, bin.2 + y);
    }
    let n = points as f64;
    let ece = bins.iter().map(|&(_, p, y)| (p - y).abs() / n).sum();
    Some(Heldout {
        points,
        positives: n_safe,
        accuracy: right as f64 / n,
        balanced: (n_safe > 0 && n_unsafe > 0).then(|| {
            let right_unsafe = right - right_safe;
            (right_safe as f64 / n_safe as f64 + right_unsafe as f64 / n_unsafe as f64) / 2.0
        }),
        brier: brier / n,
        ece,
    })
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
