//! Weights as safetensors bytes, with the architecture's name in the metadata.
//!
//! The format (https://github.com/huggingface/safetensors): an 8-byte little-endian header length, a JSON header
//! `{name: {dtype, shape, data_offsets}, "__metadata__": {...}}`, then the raw little-endian data. It is written and
//! read here directly (f32 only), because tch's safetensors support goes through files; the bytes are the ones
//! `safetensors.torch.load` reads, so weights can be inspected from Python.

use crate::ModelError;
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use tch::{nn, Device, Kind, Tensor};

/// The metadata key holding the architecture's name.
pub const ARCHITECTURE_KEY: &str = "architecture";

/// A network with named weights: the policy, the dynamics model and the critic share their weight handling here.
pub trait Network {
    fn var_store(&self) -> &nn::VarStore;
    fn var_store_mut(&mut self) -> &mut nn::VarStore;
    /// The architecture's name, stored in the weights' metadata (`PolicyUpdate.architecture` for the policy).
    fn architecture(&self) -> String;

    fn device(&self) -> Device {
        self.var_store().device()
    }

    /// safetensors bytes with the architecture's name in the metadata.
    fn to_bytes(&self) -> Vec<u8> {
        to_bytes(self.var_store(), &self.architecture())
    }

    /// Replaces the weights; weights of another architecture are refused ([`ModelError::ArchitectureMismatch`]).
    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), ModelError> {
        let name = self.architecture();
        load_bytes(self.var_store_mut(), &name, bytes)
    }
}

/// [`Network`] for a network whose weights are its field `vs`, the architecture's name an expression over `self`:
/// `network!(Critic, |self| format!(...))`. The policy, the dynamics model and the critic differ in their names only.
macro_rules! network {
    ($network:ty, |$self:ident| $architecture:expr) => {
        impl $crate::weights::Network for $network {
            fn var_store(&self) -> &tch::nn::VarStore {
                &self.vs
            }

            fn var_store_mut(&mut self) -> &mut tch::nn::VarStore {
                &mut self.vs
            }

            fn architecture(&$self) -> String {
                $architecture
            }
        }
    };
}
pub(crate) use network;

/// Serialises every variable of `vs` (trainable or not, e.g. batch-norm statistics) as f32.
pub fn to_bytes(vs: &nn::VarStore, architecture: &str) -> Vec<u8> {
    let named: BTreeMap<String, Tensor> = vs.variables().into_iter().collect();
    let mut header = Map::new();
    let mut data: Vec<u8> = Vec::new();
    for (name, t) in &named {
        let start = data.len();
        data.extend_from_slice(&f32_le_bytes(t));
        let shape: Vec<i64> = t.size();
        header.insert(
            name.clone(),
            json!({"dtype": "F32", "shape": shape, "data_offsets": [start, data.len()]}),
        );
    }
    frame(
        header,
        json!({ ARCHITECTURE_KEY: architecture, "format": "pt" }),
        &data,
    )
}

/// A tensor's values as little-endian f32 bytes (on the CPU, contiguous, flattened).
pub fn f32_le_bytes(t: &Tensor) -> Vec<u8> {
    let flat = t
        .detach()
        .to_device(Device::Cpu)
        .to_kind(Kind::Float)
        .contiguous()
        .view(-1);
    let values = Vec::<f32>::try_from(&flat).expect("a float tensor converts to Vec<f32>");
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A safetensors file: `header` (name -> {dtype, shape, data_offsets} into `data`) with `metadata`, padded to 8
/// bytes, then `data`.
pub fn frame(mut header: Map<String, Value>, metadata: Value, data: &[u8]) -> Vec<u8> {
    header.insert("__metadata__".into(), metadata);
    let mut header = serde_json::to_vec(&Value::Object(header)).expect("JSON serialises");
    while header.len() % 8 != 0 {
        header.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + data.len());
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(data);
    out
}

/// The parsed header: the architecture's name and the tensors' (shape, byte range).
struct Parsed<'a> {
    architecture: String,
    tensors: BTreeMap<String, (Vec<i64>, &'a [u8])>,
}

/// Elements of a tensor of `shape`; None for a negative dimension or an overflow (bytes from the bus may declare
/// any shape: nothing is allocated from it before it is checked against the bytes present).
fn numel(shape: &[i64]) -> Option<usize> {
    shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(usize::try_from(d).ok()?))
}

/// A safetensors file's tensors: name -> (dtype, shape, raw little-endian bytes), and its metadata (if any).
pub struct Tensors<'a> {
    pub metadata: Option<Value>,
    pub tensors: BTreeMap<String, (String, Vec<i64>, &'a [u8])>,
}

/// Reads a safetensors header of any dtypes; every tensor's declared size is checked against the bytes present.
/// Allocates in proportion to the header's length only, never to a declared shape or offset.
pub fn tensors(bytes: &[u8]) -> Result<Tensors<'_>, ModelError> {
    let bad = |why: &str| ModelError::MalformedWeights(why.to_string());
    let (len, rest) = bytes
        .split_first_chunk::<8>()
        .ok_or_else(|| bad("shorter than the 8-byte header length"))?;
    let n = usize::try_from(u64::from_le_bytes(*len))
        .ok()
        .filter(|&n| n <= rest.len())
        .ok_or_else(|| bad("header length beyond the end"))?;
    let (header, data) = rest.split_at(n);
    let header: Map<String, Value> =
        serde_json::from_slice(header).map_err(|e| bad(&format!("header JSON: {e}")))?;
    let mut out = Tensors {
        metadata: header.get("__metadata__").cloned(),
        tensors: BTreeMap::new(),
    };
    for (name, entry) in &header {
        if name == "__metadata__" {
            continue;
        }
        let dtype = entry
            .get("dtype")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(&format!("tensor `{name}`: no dtype")))?;
        let width = match dtype {
            "F64" | "I64" | "U64" => 8,
            "F32" | "I32" | "U32" => 4,
            "F16" | "BF16" | "I16" | "U16" => 2,
            "I8" | "U8" | "BOOL" => 1,
            other => return Err(bad(&format!("tensor `{name}`: unknown dtype {other}"))),
        };
        let shape: Vec<i64> = entry
            .get("shape")
            .and_then(|s| serde_json::from_value(s.clone()).ok())
            .ok_or_else(|| bad(&format!("tensor `{name}`: no shape")))?;
        let [start, end]: [usize; 2] = entry
            .get("data_offsets")
            .and_then(|s| serde_json::from_value(s.clone()).ok())
            .ok_or_else(|| bad(&format!("tensor `{name}`: no data_offsets")))?;
        let want = numel(&shape)
            .and_then(|n| n.checked_mul(width))
            .ok_or_else(|| bad(&format!("tensor `{name}`: shape {shape:?} is not a size")))?;
        let raw = data
            .get(start..end)
            .filter(|raw| raw.len() == want)
            .ok_or_else(|| bad(&format!("tensor `{name}`: data_offsets do not fit")))?;
        out.tensors
            .insert(name.clone(), (dtype.to_string(), shape, raw));
    }
    Ok(out)
}

/// Reads cabc's own weights: every tensor F32, the architecture's name in the metadata.
fn parse(bytes: &[u8]) -> Result<Parsed<'_>, ModelError> {
    let bad = |why: &str| ModelError::MalformedWeights(why.to_string());
    let all = tensors(bytes)?;
    let architecture = all
        .metadata
        .as_ref()
        .and_then(|m| m.get(ARCHITECTURE_KEY))
        .and_then(Value::as_str)
        .ok_or_else(|| bad("no architecture in the metadata"))?
        .to_string();
    let mut tensors = BTreeMap::new();
    for (name, (dtype, shape, raw)) in all.tensors {
        if dtype != "F32" {
            return Err(bad(&format!("tensor `{name}` is not F32")));
        }
        tensors.insert(name, (shape, raw));
    }
    Ok(Parsed {
        architecture,
        tensors,
    })
}

/// The architecture's name stored in `bytes`.
pub fn architecture_of(bytes: &[u8]) -> Result<String, ModelError> {
    Ok(parse(bytes)?.architecture)
}

/// Checks `bytes` against a network's architecture name and its tensors' shapes (name -> shape), without building
/// or allocating anything from them: weights from the bus go through this before a network is touched.
pub fn check(
    bytes: &[u8],
    architecture: &str,
    shapes: &BTreeMap<String, Vec<i64>>,
) -> Result<(), ModelError> {
    check_parsed(&parse(bytes)?, architecture, shapes)
}

fn check_parsed(
    parsed: &Parsed<'_>,
    architecture: &str,
    shapes: &BTreeMap<String, Vec<i64>>,
) -> Result<(), ModelError> {
    if parsed.architecture != architecture {
        return Err(ModelError::ArchitectureMismatch {
            expected: architecture.to_string(),
            found: parsed.architecture.clone(),
        });
    }
    for (name, expected) in shapes {
        let (shape, _) = parsed
            .tensors
            .get(name)
            .ok_or_else(|| ModelError::MissingTensor(name.clone()))?;
        if shape != expected {
            return Err(ModelError::ShapeMismatch {
                name: name.clone(),
                expected: expected.clone(),
                found: shape.clone(),
            });
        }
    }
    if let Some(extra) = parsed.tensors.keys().find(|k| !shapes.contains_key(*k)) {
        return Err(ModelError::UnexpectedTensor(extra.clone()));
    }
    Ok(())
}

/// The shapes of `vs`'s variables (what [`check`] compares weights against).
pub fn shapes_of(vs: &nn::VarStore) -> BTreeMap<String, Vec<i64>> {
    vs.variables()
        .into_iter()
        .map(|(name, t)| (name, t.size()))
        .collect()
}

/// Copies the weights in `bytes` into `vs`. Refuses another architecture's weights, and missing, extra or
/// differently shaped tensors, before it changes anything.
pub fn load_bytes(
    vs: &mut nn::VarStore,
    architecture: &str,
    bytes: &[u8],
) -> Result<(), ModelError> {
    let parsed = parse(bytes)?;
    check_parsed(&parsed, architecture, &shapes_of(vs))?;
    tch::no_grad(|| {
        for (name, mut var) in vs.variables() {
            let Some((shape, raw)) = parsed.tensors.get(&name) else {
                continue; // checked above: every variable has its tensor
            };
            let values: Vec<f32> = raw
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let t = Tensor::from_slice(&values)
                .f_reshape(shape.as_slice())?
                .f_to_kind(var.kind())?
                .f_to_device(var.device())?;
            var.f_copy_(&t)?;
        }
        Ok(())
    })
}
