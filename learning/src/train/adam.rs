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
pub(crate) struct Adam {
    params: Vec<Param>,
    /// The learning rate of the next steps.
    pub lr: f64,
    weight_decay: f64,
    /// Whether the state file also holds the gradients (`<variable>.grad`): where they outlive a fit and count in
    /// another network's clip (`training.clip_scope = "policy-critic-dynamics"`), a resumed run needs them.
    pub keep_grads: bool,
}

impl Adam {
    /// Adam over the trainable variables `vs` holds now (in their order), with fresh moments.
    pub fn new(vs: &nn::VarStore, lr: f64, weight_decay: f64) -> Self {
        let named = vs.variables();
        let params = vs
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
        Adam {
            params,
            lr,
            weight_decay,
            keep_grads: false,
        }
    }

    /// Zeroes the gradients (in place, as tch's `Tensor::zero_grad`).
    pub fn zero_grad(&mut self) {
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
                for mut grad in grads {
                    let _ = grad.g_mul_scalar_(clip_coef);
                }
            }
        })
    }

    /// One Adam step of every parameter that has a gradient.
    pub fn step(&mut self) {
        let (lr, wd) = (self.lr, self.weight_decay);
        tch::no_grad(|| {
            for p in &mut self.params {
                let grad = p.var.grad();
                if !grad.defined() {
                    continue;
                }
                let m = p.state.get_or_insert_with(|| Moments {
                    step: 0,
                    exp_avg: p.var.zeros_like(),
                    exp_avg_sq: p.var.zeros_like(),
                });
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
            states.push(Some(Moments {
                step,
                exp_avg,
                exp_avg_sq,
            }));
        }
        if let Some(extra) = tensors.keys().next() {
            return Err(format!("tensor `{extra}` matches no variable"));
        }
        for ((p, state), grad) in self.params.iter_mut().zip(states).zip(grads) {
            p.state = state;
            if let Some(grad) = grad {
                // d(sum(var * g))/d(var) = g exactly: the gradient as it was saved.
                p.var.zero_grad();
                (&p.var * grad).sum(p.var.kind()).backward();
            }
        }
        Ok(())
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

    /// Two identical linear layers; one trained by tch's Adam, the other by ours.
    fn pair() -> (nn::VarStore, nn::VarStore, nn::Sequential, nn::Sequential) {
        tch::manual_seed(5);
        let a = nn::VarStore::new(Device::Cpu);
        let mut b = nn::VarStore::new(Device::Cpu);
        let net = |vs: &nn::VarStore| {
            nn::seq()
                .add(nn::linear(vs.root() / "l1", 5, 37, Default::default()))
                .add_fn(|x| x.tanh())
                .add(nn::linear(vs.root() / "l2", 37, 3, Default::default()))
        };
        let (na, nb) = (net(&a), net(&b));
        b.copy(&a).unwrap();
        (a, b, na, nb)
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
