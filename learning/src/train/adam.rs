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

use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use tch::{nn, Tensor};

/// libtorch's defaults (`AdamOptions`).
const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

/// The variables and their moments, each one contiguous buffer; each variable (and its moments, once it has any) a
/// view of its stretch.
struct Flat {
    params: Tensor,
    /// The gradients' buffer: after the first step each variable's gradient is a view of its stretch, which autograd
    /// accumulates into in place (a step with no gradient yet, or one autograd replaced, moves them back in).
    grads: Tensor,
    exp_avg: Tensor,
    exp_avg_sq: Tensor,
    /// Each variable's stretch: (offset, length).
    stretches: Vec<(i64, i64)>,
}

/// The alignment of each variable's stretch in the flat buffers, in elements (64 bytes of f32).
const ALIGN: i64 = 16;

/// The metadata of a state file, checked on load.
const FORMAT: &str = "cabc-adam-1";

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
pub(crate) struct Adam {
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
        Adam {
            params,
            flat,
            lr,
            weight_decay,
            keep_grads: false,
            per_variable: false,
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
            let total_norm = f64::try_from(Tensor::stack(&norms, 0).norm()).expect("a scalar");
            let clip_coef = max / (total_norm + 1e-6);
            if clip_coef < 1.0 {
                let own: Vec<Tensor> = self.params.iter().map(|p| p.var.grad()).collect();
                let in_place = self.flat.holds(&own);
                if in_place {
                    let _ = self.flat.grads.shallow_clone().g_mul_scalar_(clip_coef);
                }
                for mut grad in grads.into_iter().skip(if in_place { own.len() } else { 0 }) {
                    let _ = grad.g_mul_scalar_(clip_coef);
                }
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

    /// The moments and step counts as safetensors bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut tensors: BTreeMap<String, (&str, Vec<i64>, Vec<u8>)> = BTreeMap::new();
        for p in &self.params {
            let Some(m) = &p.state else { continue };
            for (suffix, t) in [("exp_avg", &m.exp_avg), ("exp_avg_sq", &m.exp_avg_sq)] {
                let bytes = cabc_models::weights::f32_le_bytes(t);
                tensors.insert(format!("{}.{suffix}", p.name), ("F32", t.size(), bytes));
            }
            let step = m.step.to_le_bytes().to_vec();
            tensors.insert(format!("{}.step", p.name), ("I64", vec![], step));
        }
        for p in self.params.iter().filter(|_| self.keep_grads) {
            let grad = p.var.grad();
            if grad.defined() {
                let bytes = cabc_models::weights::f32_le_bytes(&grad);
                tensors.insert(format!("{}.grad", p.name), ("F32", grad.size(), bytes));
            }
        }
        let mut header = Map::new();
        let mut data = Vec::new();
        for (name, (dtype, shape, bytes)) in tensors {
            let start = data.len();
            data.extend_from_slice(&bytes);
            header.insert(
                name,
                json!({"dtype": dtype, "shape": shape, "data_offsets": [start, data.len()]}),
            );
        }
        cabc_models::weights::frame(header, json!({ "format": FORMAT }), &data)
    }

    /// Restores what [`Adam::to_bytes`] wrote. Refuses a file that does not match these variables (unknown or missing
    /// tensors, other shapes) before it changes anything; a variable without entries has not stepped yet.
    pub fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), String> {
        let mut tensors = parse(bytes)?;
        let mut states = Vec::with_capacity(self.params.len());
        let mut grads = Vec::with_capacity(self.params.len());
        for p in &self.params {
            grads.push(match tensors.remove(&format!("{}.grad", p.name)) {
                Some((shape, raw)) => Some(f32_tensor(&p.name, "grad", &p.var, shape, raw)?),
                None => None,
            });
            let Some((_, step)) = tensors.remove(&format!("{}.step", p.name)) else {
                states.push(None);
                continue;
            };
            let step = i64::from_le_bytes(step.try_into().map_err(|_| format!("{}.step", p.name))?);
            let mut moment = |suffix: &str| -> Result<Tensor, String> {
                let key = format!("{}.{suffix}", p.name);
                let (shape, raw) = tensors
                    .remove(&key)
                    .ok_or_else(|| format!("tensor `{key}` is missing"))?;
                f32_tensor(&p.name, suffix, &p.var, shape, raw)
            };
            let exp_avg = moment("exp_avg")?;
            let exp_avg_sq = moment("exp_avg_sq")?;
            states.push(Some((step, exp_avg, exp_avg_sq)));
        }
        if let Some(extra) = tensors.keys().next() {
            return Err(format!("tensor `{extra}` matches no variable"));
        }
        let flat = &self.flat;
        for (((p, state), grad), &(offset, len)) in self
            .params
            .iter_mut()
            .zip(states)
            .zip(grads)
            .zip(&flat.stretches)
        {
            // The moments into the flat buffers' stretches.
            p.state = state.map(|(step, exp_avg, exp_avg_sq)| {
                let mut m = flat.moments(&p.var, offset, len);
                m.step = step;
                tch::no_grad(|| {
                    m.exp_avg.copy_(&exp_avg);
                    m.exp_avg_sq.copy_(&exp_avg_sq);
                });
                m
            });
            if let Some(grad) = grad {
                // d(sum(var * g))/d(var) = g exactly: the gradient as it was saved.
                p.var.zero_grad();
                (&p.var * grad).sum(p.var.kind()).backward();
            }
        }
        Ok(())
    }
}

impl Flat {
    /// Moves `params`' variables into one buffer (each becomes a view of its stretch, with its values) and makes the
    /// moments' buffers.
    fn of(params: &mut [Param]) -> Self {
        // Each stretch starts on a 64-byte boundary, as a variable of its own would (libtorch's CPU allocator aligns
        // to 64 bytes): a GEMM's kernel may round differently on an unaligned operand. The padding holds zeros, whose
        // Adam update is zero.
        let stretches: Vec<(i64, i64)> = params
            .iter()
            .scan(0, |offset, p| {
                let len = p.var.numel() as i64;
                let start = *offset;
                *offset = (start + len + ALIGN - 1) / ALIGN * ALIGN;
                Some((start, len))
            })
            .collect();
        let Some(first) = params.first() else {
            let empty = Tensor::zeros([0], (tch::Kind::Float, tch::Device::Cpu));
            return Flat {
                grads: empty.zeros_like(),
                exp_avg: empty.zeros_like(),
                exp_avg_sq: empty.zeros_like(),
                params: empty,
                stretches,
            };
        };
        let kind = first.var.kind();
        let total = stretches.last().map_or(0, |&(offset, len)| offset + len);
        let flat = Tensor::zeros([total], (kind, first.var.device()));
        for (p, &(offset, len)) in params.iter_mut().zip(&stretches) {
            let shape = p.var.size();
            let stretch = flat.narrow(0, offset, len).view(shape.as_slice());
            tch::no_grad(|| stretch.shallow_clone().copy_(&p.var));
            p.var.set_data(&stretch);
        }
        Flat {
            grads: flat.zeros_like(),
            exp_avg: flat.zeros_like(),
            exp_avg_sq: flat.zeros_like(),
            params: flat,
            stretches,
        }
    }

    /// Whether `grads` (one per variable, in order) are the views of the gradients' buffer.
    fn holds(&self, grads: &[Tensor]) -> bool {
        let base = self.grads.data_ptr() as usize;
        let width = self.grads.kind().elt_size_in_bytes();
        grads.len() == self.stretches.len()
            && !grads.is_empty()
            && grads
                .iter()
                .zip(&self.stretches)
                .all(|(g, &(offset, len))| {
                    g.defined()
                        && g.data_ptr() as usize == base + offset as usize * width
                        && g.numel() as i64 == len
                        && g.is_contiguous()
                })
    }

    /// Fresh (zero) moments of the variable `var` at its stretch: views of the moments' buffers.
    fn moments(&self, var: &Tensor, offset: i64, len: i64) -> Moments {
        let shape = var.size();
        let view = |buffer: &Tensor| {
            let mut v = buffer.narrow(0, offset, len).view(shape.as_slice());
            let _ = tch::no_grad(|| v.zero_());
            v
        };
        Moments {
            step: 0,
            exp_avg: view(&self.exp_avg),
            exp_avg_sq: view(&self.exp_avg_sq),
        }
    }
}

/// The F32 tensor `<name>.<suffix>` of a state file, checked against the variable's shape, on its device.
fn f32_tensor(
    name: &str,
    suffix: &str,
    var: &Tensor,
    shape: Vec<i64>,
    raw: &[u8],
) -> Result<Tensor, String> {
    if shape != var.size() || raw.len() != 4 * var.numel() {
        return Err(format!(
            "tensor `{name}.{suffix}` has shape {shape:?}, expected {:?}",
            var.size()
        ));
    }
    let values: Vec<f32> = raw
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    Ok(Tensor::from_slice(&values)
        .reshape(shape.as_slice())
        .to_kind(var.kind())
        .to_device(var.device()))
}

/// The tensors of a state file: name -> (shape, raw little-endian bytes).
type Raw<'a> = BTreeMap<String, (Vec<i64>, &'a [u8])>;

fn parse(bytes: &[u8]) -> Result<Raw<'_>, String> {
    let n = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")) as usize)
        .ok_or("shorter than the 8-byte header length")?;
    let header = bytes
        .get(8..8usize.saturating_add(n))
        .ok_or("header length beyond the end")?;
    let data = &bytes[8 + n..];
    let header: Map<String, Value> =
        serde_json::from_slice(header).map_err(|e| format!("header JSON: {e}"))?;
    let format = header
        .get("__metadata__")
        .and_then(|m| m.get("format"))
        .and_then(Value::as_str);
    if format != Some(FORMAT) {
        return Err(format!("format {format:?}, expected {FORMAT:?}"));
    }
    let mut tensors = BTreeMap::new();
    for (name, entry) in header.iter().filter(|(k, _)| *k != "__metadata__") {
        let bad = |what: &str| format!("tensor `{name}`: {what}");
        let width = match entry.get("dtype").and_then(Value::as_str) {
            Some("F32") => 4,
            Some("I64") => 8,
            _ => return Err(bad("dtype is neither F32 nor I64")),
        };
        let shape: Vec<i64> = entry
            .get("shape")
            .and_then(|s| serde_json::from_value(s.clone()).ok())
            .ok_or_else(|| bad("no shape"))?;
        let [start, end]: [usize; 2] = entry
            .get("data_offsets")
            .and_then(|s| serde_json::from_value(s.clone()).ok())
            .ok_or_else(|| bad("no data_offsets"))?;
        let numel: i64 = shape.iter().product();
        if end < start || end > data.len() || (end - start) as i64 != width * numel {
            return Err(bad("data_offsets do not fit"));
        }
        tensors.insert(name.clone(), (shape, &data[start..end]));
    }
    Ok(tensors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::{Module, OptimizerConfig};
    use tch::{Device, Kind};

    /// A small network: 5 -> 37 -> 3 (stretches of 185, 37, 111 and 3 values, none a multiple of a vector's width).
    fn net(vs: &nn::VarStore) -> nn::Sequential {
        nn::seq()
            .add(nn::linear(vs.root() / "l1", 5, 37, Default::default()))
            .add_fn(|x| x.tanh())
            .add(nn::linear(vs.root() / "l2", 37, 3, Default::default()))
    }

    /// Two identical networks; one trained by tch's Adam, the other by ours.
    fn pair() -> (nn::VarStore, nn::VarStore, nn::Sequential, nn::Sequential) {
        let a = nn::VarStore::new(Device::Cpu);
        let mut b = nn::VarStore::new(Device::Cpu);
        let (na, nb) = (net(&a), net(&b));
        b.copy(&a).unwrap();
        (a, b, na, nb)
    }

    /// A copy of the network `template` holds.
    fn copy_of(template: &nn::VarStore) -> (nn::VarStore, nn::Sequential) {
        let mut vs = nn::VarStore::new(Device::Cpu);
        let n = net(&vs);
        vs.copy(template).unwrap();
        (vs, n)
    }

    /// Inputs from a seeded generator of this test's own (the tests run in parallel: libtorch's global generator is
    /// shared).
    fn inputs(rng: &mut rand_chacha::ChaCha8Rng) -> Tensor {
        use rand::Rng;
        let v: Vec<f32> = (0..80).map(|_| rng.gen_range(-2.0..2.0)).collect();
        Tensor::from_slice(&v).view([16, 5])
    }

    #[test]
    fn matches_tch_adam_bit_for_bit() {
        tch::set_num_threads(1);
        for wd in [0.0, 1e-4] {
            let (a, b, na, nb) = pair();
            let mut theirs = nn::Adam::default().wd(wd).build(&a, 1e-2).unwrap();
            let mut ours = Adam::new(&b, 1e-2, wd);
            for i in 0..200 {
                let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
                let y = Tensor::randn([16, 3], (Kind::Float, Device::Cpu));
                let lr = 1e-2 * 0.97f64.powi(i / 10);
                theirs.set_lr(lr);
                ours.lr = lr;
                let la = na.forward(&x).mse_loss(&y, tch::Reduction::Mean);
                theirs.zero_grad();
                la.backward();
                theirs.clip_grad_norm(0.5);
                theirs.step();
                let lb = nb.forward(&x).mse_loss(&y, tch::Reduction::Mean);
                ours.zero_grad();
                lb.backward();
                ours.clip_grad_norm(0.5, &[]);
                ours.step();
                assert_eq!(
                    la.double_value(&[]).to_bits(),
                    lb.double_value(&[]).to_bits()
                );
            }
            let (va, vb) = (a.variables(), b.variables());
            for (name, t) in &va {
                assert!(t.equal(&vb[name]), "wd {wd}: {name} differs");
            }
            assert_eq!(ours.steps(), vec![200; 4]);
        }
    }

    #[test]
    fn flat_and_per_variable_steps_agree() {
        tch::set_num_threads(1);
        let (a, b, na, nb) = pair();
        let mut each = Adam::new(&a, 1e-2, 1e-4);
        let mut flat = Adam::new(&b, 1e-2, 1e-4);
        for _ in 0..100 {
            let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
            for (adam, net) in [(&mut each, &na), (&mut flat, &nb)] {
                adam.zero_grad();
                net.forward(&x).square().sum(Kind::Float).backward();
                adam.clip_grad_norm(0.01, &[]);
            }
            each.step_each();
            flat.step();
        }
        let (va, vb) = (a.variables(), b.variables());
        for (name, t) in &va {
            assert!(t.equal(&vb[name]), "{name} differs");
        }
        assert_eq!(each.to_bytes(), flat.to_bytes());
    }

    #[test]
    fn flat_steps_keep_the_bits_when_another_networks_gradients_count_in_the_clip() {
        tch::set_num_threads(1);
        // The reference's clip scope: the policy's loss reaches the critic's weights, whose gradients (left from the
        // critic's own fit and accumulated into) count in the policy's clip and are scaled by it.
        let (policy_template, critic_template, _, _) = pair();
        let run = |flat: bool| {
            let (policy_vs, policy) = copy_of(&policy_template);
            let (critic_vs, critic) = copy_of(&critic_template);
            let mut policy_adam = Adam::new(&policy_vs, 1e-2, 1e-4);
            let mut critic_adam = Adam::new(&critic_vs, 1e-2, 1e-4);
            let step = |adam: &mut Adam| match flat {
                true => adam.step(),
                false => adam.step_each(),
            };
            let mut rng = rand::SeedableRng::seed_from_u64(9);
            let mut losses = Vec::new();
            for _ in 0..30 {
                let x = inputs(&mut rng);
                for _ in 0..3 {
                    critic_adam.zero_grad();
                    critic.forward(&x).square().mean(Kind::Float).backward();
                    critic_adam.clip_grad_norm(0.1, &[]);
                    step(&mut critic_adam);
                }
                for _ in 0..3 {
                    policy_adam.zero_grad();
                    let u = policy.forward(&x);
                    let inputs = Tensor::cat(&[&u, &x.narrow(1, 0, 2)], 1);
                    let loss =
                        u.square().mean(Kind::Float) + critic.forward(&inputs).mean(Kind::Float);
                    loss.backward();
                    losses.push(loss.double_value(&[]).to_bits());
                    policy_adam.clip_grad_norm(0.1, &critic_vs.trainable_variables());
                    step(&mut policy_adam);
                }
            }
            (losses, policy_adam.to_bytes(), critic_adam.to_bytes())
        };
        let (each, flat) = (run(false), run(true));
        assert_eq!(each.0, flat.0, "the losses");
        assert_eq!(each.1, flat.1, "the policy's moments");
        assert_eq!(each.2, flat.2, "the critic's moments");
    }

    #[test]
    fn a_variable_without_a_gradient_is_not_stepped_as_in_libtorch() {
        tch::set_num_threads(1);
        let (a, b, na, nb) = pair();
        let mut theirs = nn::Adam::default().wd(1e-4).build(&a, 1e-2).unwrap();
        let mut ours = Adam::new(&b, 1e-2, 1e-4);
        for i in 0..40 {
            let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
            // The first 10 steps train the first layer alone: the second's gradients are undefined, then its step
            // counts trail the first's.
            let loss = |net: &nn::Sequential, vs: &nn::VarStore| match i < 10 {
                true => {
                    let v = vs.variables();
                    (x.matmul(&v["l1.weight"].tr()) + &v["l1.bias"]).sum(Kind::Float)
                }
                false => net.forward(&x).sum(Kind::Float),
            };
            theirs.zero_grad();
            loss(&na, &a).backward();
            theirs.step();
            ours.zero_grad();
            loss(&nb, &b).backward();
            ours.step();
        }
        let (va, vb) = (a.variables(), b.variables());
        for (name, t) in &va {
            assert!(t.equal(&vb[name]), "{name} differs");
        }
        assert_eq!(ours.steps(), vec![40, 40, 30, 30]);
    }

    #[test]
    fn state_round_trips() {
        let (_, b, _, nb) = pair();
        let mut ours = Adam::new(&b, 1e-3, 1e-4);
        let x = Tensor::randn([8, 5], (Kind::Float, Device::Cpu));
        for _ in 0..3 {
            ours.zero_grad();
            nb.forward(&x).sum(Kind::Float).backward();
            ours.step();
        }
        let bytes = ours.to_bytes();
        let mut other = Adam::new(&b, 1e-3, 1e-4);
        assert_eq!(other.steps(), vec![0; 4]);
        other.load_bytes(&bytes).unwrap();
        assert_eq!(other.steps(), vec![3; 4]);
        assert_eq!(other.to_bytes(), bytes);
        let fresh = Adam::new(&b, 1e-3, 1e-4).to_bytes();
        other.load_bytes(&fresh).unwrap();
        assert_eq!(other.steps(), vec![0; 4]);
        assert!(other.load_bytes(&bytes[..bytes.len() - 4]).is_err());
        assert!(other.load_bytes(b"junk").is_err());
    }

    #[test]
    fn the_clip_counts_other_gradients_and_gradients_survive_a_checkpoint() {
        let (a, b, na, nb) = pair();
        let x = Tensor::randn([8, 5], (Kind::Float, Device::Cpu));
        let mut own = Adam::new(&a, 1e-3, 0.0);
        own.zero_grad();
        na.forward(&x).sum(Kind::Float).backward();
        let other = Adam::new(&b, 1e-3, 0.0);
        nb.forward(&x).sum(Kind::Float).backward();
        let norm = |vs: &nn::VarStore| -> f64 {
            let sq: f64 = vs
                .trainable_variables()
                .iter()
                .map(|v| v.grad().square().sum(Kind::Double).double_value(&[]))
                .sum();
            sq.sqrt()
        };
        let (own_before, other_before) = (norm(&a), norm(&b));
        assert!(
            (own_before - other_before).abs() < 1e-9,
            "identical nets, identical gradients"
        );
        // Alone, the clip scales to 1; with the other network's gradients counted, each half gets 1 / sqrt(2).
        own.clip_grad_norm(1.0, &b.trainable_variables());
        let joint = (norm(&a).powi(2) + norm(&b).powi(2)).sqrt();
        assert!((joint - 1.0).abs() < 1e-4, "joint norm {joint}");
        assert!(
            (norm(&a) - 0.5f64.sqrt()).abs() < 1e-4,
            "own norm {}",
            norm(&a)
        );
        // The gradients travel with the state when asked to, and come back exactly.
        let mut keeper = other;
        keeper.keep_grads = true;
        let bytes = keeper.to_bytes();
        let saved: Vec<Tensor> = b
            .trainable_variables()
            .iter()
            .map(|v| v.grad().copy())
            .collect();
        for mut v in b.trainable_variables() {
            v.zero_grad();
        }
        keeper.load_bytes(&bytes).unwrap();
        for (v, g) in b.trainable_variables().iter().zip(&saved) {
            assert!(v.grad().equal(g));
        }
        keeper.keep_grads = false;
        assert!(
            keeper.to_bytes().len() < bytes.len(),
            "no gradients unless kept"
        );
    }
}
