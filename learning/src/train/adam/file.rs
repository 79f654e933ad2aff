//! The optimiser's state as a safetensors file, for the checkpoint: `<variable>.exp_avg`, `<variable>.exp_avg_sq`
//! (F32), `<variable>.step` (a 0-dim I64) and, when kept, `<variable>.grad`.

use super::Adam;
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use tch::Tensor;

/// The metadata of a state file, checked on load.
const FORMAT: &str = "cabc-adam-1";

impl Adam {
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
