//! Adam of our own over a `VarStore`'s trainable variables, so that its moments can be checkpointed (tch's
//! `nn::Optimizer` keeps them inside libtorch, out of reach).
//!
//! The update is libtorch's `torch::optim::Adam::step` (amsgrad off, weight decay added to the gradient, not
//! decoupled), op for op, so that training is bit-identical to tch's `nn::Adam` on the CPU:
//!
//! ```text
//!     grad = grad.add(param, wd)                                   (when wd != 0)
//!     exp_avg.mul_(beta1).add_(grad, 1 - beta1)
//!     exp_avg_sq.mul_(beta2).addcmul_(grad, grad, 1 - beta2)
//!     denom = (exp_avg_sq.sqrt() / sqrt(1 - beta2^step)).add_(eps)
//!     param.addcdiv_(exp_avg, denom, -lr / (1 - beta1^step))
//! ```
//!
//! tch's generated API drops the `alpha` of `add` and the `value` of `addcmul` / `addcdiv`, so the scalings are moved
//! into operands without changing a bit: `a.add_(b, alpha)` (one fused multiply-add in libtorch's CPU kernel) is
//! `a.addcmul_(b, alpha)` with `alpha` as a 0-dim tensor of the parameter's kind (the same fused `a + 1 * b * alpha`),
//! and `addcmul_(t1, t2, v)` / `addcdiv_(t1, t2, v)`, which compute `self + (v * t1) op t2`, take `v * t1` (rounded
//! as the kernel rounds it) as `t1` with `v = 1`. Gradient-norm clipping is tch's `clip_grad_norm` line for line.
//! A parameter's state (step, exp_avg, exp_avg_sq) is created on its first step with a gradient, as libtorch does.
//!
//! [`Adam::to_bytes`] / [`Adam::load_bytes`]: the state as safetensors (`<variable>.exp_avg`, `<variable>.exp_avg_sq`
//! as F32, `<variable>.step` as a 0-dim I64), for the checkpoint.

mod file;
mod flat;
#[cfg(test)]
mod tests;

use flat::Flat;
use tch::{nn, Kind, Tensor};

/// libtorch's defaults (`AdamOptions`).
const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

/// One parameter's moments.
struct Moments {
    step: i64,
    exp_avg: Tensor,
    exp_avg_sq: Tensor,
}

struct Param {
    /// The variable's name in its `VarStore` (its index when it has none).
    name: String,
    var: Tensor,
    state: Option<Moments>,
}

/// Adam with L2 weight decay and gradient-norm clipping over the trainable variables of one `VarStore`.
///
/// The variables, their gradients and their moments live in one flat buffer each ([`Flat`]): each variable is a view
/// of its stretch of the buffer, so that a step in which every variable has a gradient at the same step count is one
/// update of the whole buffer (about a dozen libtorch calls) rather than one per variable (a dozen each), and zeroing
/// and clipping the gradients one call each. The update is elementwise, so the flat step gives each element the bits
/// the per-variable step gives it (`flat_and_per_variable_steps_agree`, and a recipe run's `metrics.csv` and
/// `evals.csv` bit for bit, issue 46). Each stretch starts 64-byte aligned, as a tensor of its own does: with
/// unaligned weights a recipe run's GEMMs rounded differently from its tenth epoch on (measured).
pub struct Adam {
    params: Vec<Param>,
    flat: Flat,
    /// The learning rate of the next steps.
    pub lr: f64,
    weight_decay: f64,
    /// Whether the state file also holds the gradients (`<variable>.grad`): where they outlive a fit and count in
    /// another network's clip (`training.clip_scope = "policy-critic-dynamics"`), a resumed run needs them.
    pub keep_grads: bool,
    /// Every step parameter by parameter, the gradients where autograd puts them (the flat step's reference, for
    /// tests).
    pub per_variable: bool,
    /// Whether the clip's coefficient stays on the device (the default where the variables live on a GPU) rather
    /// than being read back to the host; the same bits either way (`the_clip_on_the_device_gives_the_hosts_bits`).
    pub device_clip: bool,
}

impl Adam {
    /// Adam over the trainable variables `vs` holds now (in their order), with fresh moments.
    pub fn new(vs: &nn::VarStore, lr: f64, weight_decay: f64) -> Self {
        let named = vs.variables();
        let mut params: Vec<Param> = vs
            .trainable_variables()
            .into_iter()
            .enumerate()
            .map(|(i, var)| {
                let name = named
                    .iter()
                    .find(|(_, t)| t.data_ptr() == var.data_ptr())
                    .map_or_else(|| i.to_string(), |(n, _)| n.clone());
                Param {
                    name,
                    var,
                    state: None,
                }
            })
            .collect();
        let flat = Flat::of(&mut params);
        let device_clip = flat.params.device().is_cuda();
        Adam {
            params,
            flat,
            lr,
            weight_decay,
            keep_grads: false,
            per_variable: false,
            device_clip,
        }
    }

    /// Zeroes the gradients (in place, as tch's `Tensor::zero_grad`).
    pub fn zero_grad(&mut self) {
        let grads: Vec<Tensor> = self.params.iter().map(|p| p.var.grad()).collect();
        if self.flat.holds(&grads) {
            let _ = tch::no_grad(|| self.flat.grads.zero_());
            return;
        }
        for p in &mut self.params {
            p.var.zero_grad();
        }
    }

    /// Scales the gradients so that their joint L2 norm is at most `max` (tch's `Optimizer::clip_grad_norm`). The
    /// gradients of the variables `also` (not stepped by this optimiser) count in the norm and are scaled too, as
    /// torch's `clip_grad_norm_(module.parameters())` does for a module's submodules.
    pub fn clip_grad_norm(&self, max: f64, also: &[Tensor]) {
        tch::no_grad(|| {
            // Fetched afresh: autograd may replace a gradient tensor when it accumulates into it.
            let grads: Vec<Tensor> = self
                .params
                .iter()
                .map(|p| &p.var)
                .chain(also)
                .map(Tensor::grad)
                .filter(Tensor::defined)
                .collect();
            let norms: Vec<Tensor> = grads.iter().map(Tensor::norm).collect();
            if norms.is_empty() {
                return;
            }
            let total_norm = Tensor::stack(&norms, 0).norm();
            // The factor min(1, max / (norm + 1e-6)), in f64 and rounded to the gradients' kind as a scalar is.
            let scale: Box<dyn Fn(&mut Tensor)> = if self.device_clip {
                // On a GPU, reading the norm back would wait for the backward pass to finish and leave the GPU idle
                // while the step's kernels are queued, so the factor stays there (the host's bits: x * 1 = x).
                let max = Tensor::full([], max, (Kind::Double, total_norm.device()));
                let coef = (max / total_norm.to_kind(Kind::Double).g_add_scalar(1e-6))
                    .clamp_max(1.0)
                    .to_kind(total_norm.kind());
                Box::new(move |g| {
                    let _ = g.g_mul_(&coef);
                })
            } else {
                let coef = max / (f64::try_from(total_norm).expect("a scalar") + 1e-6);
                if coef >= 1.0 || coef.is_nan() {
                    return; // as tch's clip: scaled only when the factor is below 1
                }
                Box::new(move |g| {
                    let _ = g.g_mul_scalar_(coef);
                })
            };
            let own: Vec<Tensor> = self.params.iter().map(|p| p.var.grad()).collect();
            let in_place = self.flat.holds(&own);
            if in_place {
                scale(&mut self.flat.grads.shallow_clone());
            }
            for mut grad in grads.into_iter().skip(if in_place { own.len() } else { 0 }) {
                scale(&mut grad);
            }
        })
    }

    /// One Adam step of every parameter that has a gradient: over the flat buffers when every parameter has one and
    /// all have stepped as often (always, in a fit), else parameter by parameter.
    pub fn step(&mut self) {
        let grads: Vec<Tensor> = self.params.iter().map(|p| p.var.grad()).collect();
        let steps = |p: &Param| p.state.as_ref().map_or(0, |m| m.step);
        let uniform = grads.iter().all(Tensor::defined)
            && self.params.windows(2).all(|w| steps(&w[0]) == steps(&w[1]));
        match uniform && !self.params.is_empty() && !self.per_variable {
            true => self.step_flat(&grads),
            false => self.step_each(),
        }
    }

    /// [`Adam::step`] over the flat buffers: the per-parameter update below on the concatenated gradients.
    fn step_flat(&mut self, grads: &[Tensor]) {
        let (lr, wd) = (self.lr, self.weight_decay);
        let flat = &self.flat;
        let mut step = 0;
        for (p, &(offset, len)) in self.params.iter_mut().zip(&flat.stretches) {
            let m = p
                .state
                .get_or_insert_with(|| flat.moments(&p.var, offset, len));
            m.step += 1;
            step = m.step;
        }
        tch::no_grad(|| {
            if !flat.holds(grads) {
                // The gradients into their stretches, which they stay in: autograd accumulates into them in place.
                for (mut g, &(offset, len)) in
                    grads.iter().map(Tensor::shallow_clone).zip(&flat.stretches)
                {
                    let shape = g.size();
                    let stretch = flat.grads.narrow(0, offset, len).view(shape.as_slice());
                    stretch.shallow_clone().copy_(&g);
                    g.set_data(&stretch);
                }
            }
            let grad = flat.grads.shallow_clone();
            let bias_correction1 = 1.0 - BETA1.powf(step as f64);
            let bias_correction2 = 1.0 - BETA2.powf(step as f64);
            let options = (flat.params.kind(), flat.params.device());
            let scalar = |v: f64| Tensor::full([], v, options);
            let grad = if wd != 0.0 {
                grad.addcmul(&flat.params, &scalar(wd))
            } else {
                grad
            };
            let (mut exp_avg, mut exp_avg_sq) = (
                flat.exp_avg.shallow_clone(),
                flat.exp_avg_sq.shallow_clone(),
            );
            let _ = exp_avg
                .g_mul_scalar_(BETA1)
                .addcmul_(&grad, &scalar(1.0 - BETA1));
            let _ = exp_avg_sq
                .g_mul_scalar_(BETA2)
                .addcmul_(&(&grad * (1.0 - BETA2)), &grad);
            let denom = (exp_avg_sq.sqrt() / bias_correction2.sqrt()).g_add_scalar_(EPS);
            let step_size = lr / bias_correction1;
            let _ = flat
                .params
                .shallow_clone()
                .addcdiv_(&(&exp_avg * -step_size), &denom);
        })
    }

    /// [`Adam::step`] parameter by parameter (a parameter without a gradient is not stepped, as in libtorch).
    fn step_each(&mut self) {
        let (lr, wd) = (self.lr, self.weight_decay);
        let flat = &self.flat;
        tch::no_grad(|| {
            for (p, &(offset, len)) in self.params.iter_mut().zip(&flat.stretches) {
                let grad = p.var.grad();
                if !grad.defined() {
                    continue;
                }
                let m = p
                    .state
                    .get_or_insert_with(|| flat.moments(&p.var, offset, len));
                m.step += 1;
                let bias_correction1 = 1.0 - BETA1.powf(m.step as f64);
                let bias_correction2 = 1.0 - BETA2.powf(m.step as f64);
                let scalar = |v: f64| Tensor::full([], v, (p.var.kind(), p.var.device()));
                let grad = if wd != 0.0 {
                    grad.addcmul(&p.var, &scalar(wd))
                } else {
                    grad
                };
                let _ = m
                    .exp_avg
                    .g_mul_scalar_(BETA1)
                    .addcmul_(&grad, &scalar(1.0 - BETA1));
                let _ = m
                    .exp_avg_sq
                    .g_mul_scalar_(BETA2)
                    .addcmul_(&(&grad * (1.0 - BETA2)), &grad);
                let denom = (m.exp_avg_sq.sqrt() / bias_correction2.sqrt()).g_add_scalar_(EPS);
                let step_size = lr / bias_correction1;
                let _ = p.var.addcdiv_(&(&m.exp_avg * -step_size), &denom);
            }
        })
    }

    /// Forgets the moments (the next step starts as a fresh Adam's).
    pub fn reset(&mut self) {
        for p in &mut self.params {
            p.state = None;
        }
    }

    /// The step count of each parameter (0 before its first step), in the `VarStore`'s order.
    #[cfg(test)]
    pub fn steps(&self) -> Vec<i64> {
        self.params
            .iter()
            .map(|p| p.state.as_ref().map_or(0, |m| m.step))
            .collect()
    }
}
