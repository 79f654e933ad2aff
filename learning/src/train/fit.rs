//! The one fit loop the three networks share: one fit call is `passes` passes of shuffled mini-batches (the last
//! partial batch dropped), each batch a zero_grad / backward / gradient-norm clip / Adam step, at the learning rate
//! lr0 * gamma^fits (ExponentialLR stepped once per fit call); the figures reported are those of the last pass, and
//! only its batches compute them. The loss (the forward pass) runs at the fit's precision (`training.precision` for
//! the policy: bf16 autocast on CUDA; fp32 for f_hat and p_hat), the backward pass and the step in fp32.

use cabc_models::precision::with_precision;
use cabc_models::ModelError;
use cabc_proto::config::{Precision, TrainingSection};
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use std::cell::RefCell;
use std::time::Instant;
use tch::{nn, Device, Kind, Tensor};

use super::adam::Adam;

/// One network's optimiser and learning-rate schedule.
pub(crate) struct Opt {
    pub adam: Adam,
    /// Fit calls so far: lr = max(lr0 * gamma^fits, lr_min).
    pub fits: u64,
    lr0: f64,
    gamma: f64,
    lr_min: f64,
}

impl Opt {
    /// Adam with the configured learning rate, weight decay and `training.lr_gamma` on `vs`.
    pub fn adam(vs: &nn::VarStore, t: &TrainingSection) -> Self {
        Self::with_gamma(vs, t, t.lr_gamma)
    }

    /// The same with its own ExponentialLR gamma (the policy's `training.policy_lr_gamma`).
    pub fn with_gamma(vs: &nn::VarStore, t: &TrainingSection, gamma: f64) -> Self {
        Opt {
            adam: Adam::new(vs, t.lr, t.weight_decay),
            fits: 0,
            lr0: t.lr,
            gamma,
            lr_min: t.lr_min,
        }
    }

    /// The learning rate of the next fit call.
    pub fn lr(&self) -> f64 {
        (self.lr0 * self.gamma.powi(self.fits as i32)).max(self.lr_min)
    }
}

/// libtorch's intra-op threads on the CPU. These networks are small (batch 64, widths <= 256): with more threads
/// OpenMP's spinning costs more than it gains, up to 20x slower on a loaded 2-core machine (measured), and one thread
/// also makes CPU runs bit-reproducible. OpenMP keeps the setting per OS thread, so it is set on each fit call.
const CPU_THREADS: i32 = 1;

pub(crate) fn limit_cpu_threads(device: Device) {
    if device == Device::Cpu {
        tch::set_num_threads(CPU_THREADS);
    }
    // Subnormal floats cost a pass 4-9x its time late in a run (cabc_models::flush_denormals).
    cabc_models::flush_denormals();
}

/// One mini-batch: its row indices, on the CPU and as a tensor on the training device.
pub(crate) struct Batch<'a> {
    pub rows: &'a [i64],
    pub idx: Tensor,
    /// Whether the batch is of the fit's last pass, whose figures are reported: the loss adds to its pass's record
    /// only then (the records of earlier passes are dropped, and each addition is a few more kernels on a GPU).
    pub reported: bool,
}

/// How much one fit call trains: `passes` over the examples, stopped after `max_batches` mini-batches (0: no cap).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Budget {
    pub passes: usize,
    pub max_batches: usize,
}

/// The precision of the forward passes of f_hat's and p_hat's fits: fp32 whatever `training.precision` says. They
/// are small MLPs on 64-row batches, whose time on a GPU is the calls' (measured 2 ms a mini-batch at 224x224 in bf16,
/// issue 56), which autocast's casts of every layer's input, weight and bias (and their backward) add to; bf16 is
/// for the policy's trunk.
pub(crate) const AUX_PRECISION: Precision = Precision::Fp32;

/// Where the fit calls' time went, by phase of a mini-batch (`cabc bench epoch`): summed over the fit calls made on
/// this thread inside [`profiled`]. On the CPU each phase is timed as it runs; on CUDA the clip's host read is the one
/// sync, so the phases there are what the host waited for, not the kernels' time.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FitProfile {
    /// Mini-batches trained.
    pub batches: usize,
    /// The batch's rows to the device and the loss: the forward pass.
    pub forward_s: f64,
    /// Zeroing the gradients and the backward pass.
    pub backward_s: f64,
    /// The gradient-norm clip.
    pub clip_s: f64,
    /// Adam's step.
    pub step_s: f64,
}

thread_local! {
    static PROFILE: RefCell<Option<FitProfile>> = const { RefCell::new(None) };
}

/// Runs `f` and returns, with its result, where the fit calls it made on this thread spent their time.
pub fn profiled<R>(f: impl FnOnce() -> R) -> (R, FitProfile) {
    let outer = PROFILE.with(|p| p.borrow_mut().replace(FitProfile::default()));
    let result = f();
    let profile = PROFILE.with(|p| std::mem::replace(&mut *p.borrow_mut(), outer));
    (result, profile.unwrap_or_default())
}

/// The clock of one mini-batch's phases, when [`profiled`] is on (else nothing is read).
struct Clock(Option<(Instant, FitProfile)>);

impl Clock {
    fn start() -> Self {
        let on = PROFILE.with(|p| p.borrow().is_some());
        Clock(on.then(|| (Instant::now(), FitProfile::default())))
    }

    /// Adds the time since the last lap to `phase`.
    fn lap(&mut self, phase: fn(&mut FitProfile) -> &mut f64) {
        if let Some((at, profile)) = &mut self.0 {
            let now = Instant::now();
            *phase(profile) += (now - *at).as_secs_f64();
            *at = now;
        }
    }

    /// Adds this batch to the thread's profile.
    fn end(self) {
        if let Some((_, batch)) = self.0 {
            PROFILE.with(|p| {
                if let Some(total) = p.borrow_mut().as_mut() {
                    total.batches += 1;
                    total.forward_s += batch.forward_s;
                    total.backward_s += batch.backward_s;
                    total.clip_s += batch.clip_s;
                    total.step_s += batch.step_s;
                }
            });
        }
    }
}

/// One fit call over `n` examples: `loss` gives the batch's loss to minimise and records what it wants to report
/// into the pass's `M` (a fresh `M` each pass). Returns the last pass's `M` and the samples seen (all passes).
/// The gradients of `clip_also` (variables this optimiser does not step) count in the gradient-norm clip
/// (`training.clip_scope`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit<M: Default>(
    opt: &mut Opt,
    t: &TrainingSection,
    precision: Precision,
    device: Device,
    rng: &mut ChaCha8Rng,
    n: usize,
    budget: Budget,
    clip_also: &[Tensor],
    mut loss: impl FnMut(&Batch, &mut M) -> Result<Tensor, ModelError>,
) -> Result<(M, usize), ModelError> {
    limit_cpu_threads(device);
    opt.adam.lr = opt.lr();
    let mut last = M::default();
    let mut samples = 0;
    let mut left = match budget.max_batches {
        0 => usize::MAX,
        cap => cap,
    };
    for pass in 0..budget.passes {
        if left == 0 {
            break;
        }
        last = M::default();
        let mut batches = shuffled_batches(n, t.batch_size, rng);
        batches.truncate(left);
        left -= batches.len();
        let reported = pass + 1 == budget.passes || left == 0;
        // The pass's indices go to the device in one copy: a copy from the host waits for the device's queue to
        // drain (libtorch synchronises after a blocking upload), which once per batch would idle a GPU each step.
        let indices = Tensor::from_slice(&batches.concat())
            .view([batches.len() as i64, t.batch_size.max(1) as i64])
            .to_device(device);
        for (i, rows) in batches.iter().enumerate() {
            let mut clock = Clock::start();
            let batch = Batch {
                idx: indices.get(i as i64),
                rows,
                reported,
            };
            let l = with_precision(precision, device, || loss(&batch, &mut last))?;
            clock.lap(|p| &mut p.forward_s);
            opt.adam.zero_grad();
            l.backward();
            clock.lap(|p| &mut p.backward_s);
            opt.adam.clip_grad_norm(t.grad_clip, clip_also);
            clock.lap(|p| &mut p.clip_s);
            opt.adam.step();
            clock.lap(|p| &mut p.step_s);
            clock.end();
            samples += t.batch_size;
        }
    }
    opt.fits += 1;
    Ok((last, samples))
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
pub(crate) fn cat_rows<'a>(
    parts: impl IntoIterator<Item = &'a [f32]>,
    cols: usize,
    device: Device,
) -> Tensor {
    let flat: Vec<f32> = parts.into_iter().flatten().copied().collect();
    let n = (flat.len() / cols) as i64;
    Tensor::from_slice(&flat)
        .view([n, cols as i64])
        .to_device(device)
}

/// The mean of the scalar tensors added, summed where they are (in f64, detached): reading it is the one host
/// sync of a pass, not one per mini-batch (on a GPU, `double_value` per batch would stall the queue each time).
#[derive(Default)]
pub(crate) struct Mean {
    sum: Option<Tensor>,
    n: usize,
}

impl Mean {
    pub fn add(&mut self, v: &Tensor) {
        let v = v.detach().to_kind(Kind::Double);
        self.sum = Some(match self.sum.take() {
            Some(sum) => sum + v,
            None => v,
        });
        self.n += 1;
    }

    pub fn get(&self) -> f64 {
        match &self.sum {
            Some(sum) if self.n > 0 => sum.double_value(&[]) / self.n as f64,
            _ => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Counts the batches one fit call makes over `n` examples under `budget`.
    fn batches(n: usize, budget: Budget) -> (usize, usize) {
        let (count, _, samples) = batches_reported(n, budget);
        (count, samples)
    }

    /// The batches one fit call makes over `n` examples under `budget`, those of them reported, and the samples.
    fn batches_reported(n: usize, budget: Budget) -> (usize, usize, usize) {
        let vs = nn::VarStore::new(Device::Cpu);
        let w = vs.root().zeros("w", &[1]);
        let t = TrainingSection {
            batch_size: 10,
            ..Default::default()
        };
        let mut opt = Opt::adam(&vs, &t);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (mut count, mut reported) = (0, 0);
        let (_, samples) = fit(
            &mut opt,
            &t,
            t.precision,
            Device::Cpu,
            &mut rng,
            n,
            budget,
            &[],
            |b, _: &mut Mean| {
                count += 1;
                reported += usize::from(b.reported);
                Ok((&w * 2.0).sum(tch::Kind::Float))
            },
        )
        .unwrap();
        (count, reported, samples)
    }

    #[test]
    fn only_the_last_pass_is_reported() {
        let capped = |max_batches| Budget {
            passes: 3,
            max_batches,
        };
        // 9 batches a pass: the third pass is the last.
        assert_eq!(batches_reported(95, capped(0)), (27, 9, 270));
        // The cap ends the fit in its second pass, which is then the last.
        assert_eq!(batches_reported(95, capped(13)), (13, 4, 130));
        // A cap at a pass's end: the pass it ends is the last.
        assert_eq!(batches_reported(95, capped(9)), (9, 9, 90));
    }

    #[test]
    fn whole_passes_unless_capped() {
        // 95 examples in batches of 10: 9 a pass (the partial batch dropped).
        let capped = |max_batches| Budget {
            passes: 3,
            max_batches,
        };
        assert_eq!(batches(95, capped(0)), (27, 270), "0: no cap");
        assert_eq!(batches(95, capped(5)), (5, 50));
        assert_eq!(batches(95, capped(13)), (13, 130), "the cap spans passes");
        assert_eq!(
            batches(95, capped(100)),
            (27, 270),
            "a cap above the passes changes nothing"
        );
    }
}
