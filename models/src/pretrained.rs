//! ImageNet weights for the camera policy's ResNet-18 trunk (`observation.pretrained`): the reference starts its
//! trunk from torchvision's ImageNet weights, which cannot be fetched on this project's machines, so a run loads
//! them from a file the user provides:
//!
//! ```python
//! import torchvision, safetensors.torch
//! m = torchvision.models.resnet18(weights="IMAGENET1K_V1")
//! safetensors.torch.save_file(m.state_dict(), "resnet18-imagenet.safetensors")
//! ```
//!
//! The state dict's names are torchvision's (`conv1.weight`, `layer2.0.downsample.1.running_var`, ...), which are
//! the trunk's own under `trunk.`; the classifier (`fc.*`) and BatchNorm's `num_batches_tracked` counters have no
//! place in the trunk and are skipped. Every trunk variable must be in the file with its shape, or nothing is loaded.

use crate::policy::{Policy, PolicyArch};
use crate::weights::{self, Network};
use crate::ModelError;
use cabc_proto::config::VisionTrunk;
use tch::{Kind, Tensor};

/// The prefix of the trunk's variables in a policy's `VarStore`.
const TRUNK: &str = "trunk.";

/// Whether a state-dict entry has no place in the trunk: the classifier, BatchNorm's batch counters.
fn skipped(name: &str) -> bool {
    name.starts_with("fc.") || name.ends_with("num_batches_tracked")
}

impl Policy {
    /// Loads torchvision ResNet-18 weights (safetensors bytes of its state dict, F32, F16 or BF16) into the trunk.
    /// Refused, with nothing changed, for a policy without a ResNet-18 trunk, a file that lacks a trunk variable,
    /// holds a tensor of another shape, or holds a tensor the trunk does not have (besides `fc.*` and the counters).
    /// Returns how many tensors were loaded.
    pub fn load_pretrained_trunk(&mut self, bytes: &[u8]) -> Result<usize, ModelError> {
        if !matches!(
            self.arch(),
            PolicyArch::Camera {
                trunk: VisionTrunk::Resnet18,
                ..
            }
        ) {
            return Err(ModelError::Observation(format!(
                "pretrained weights are for a ResNet-18 trunk; this policy is {}",
                self.arch()
            )));
        }
        let file = weights::tensors(bytes)?;
        let vars = self.var_store().variables();
        let trunk: Vec<(&String, &Tensor)> =
            vars.iter().filter(|(n, _)| n.starts_with(TRUNK)).collect();
        // Check everything before changing anything.
        for (name, (_, shape, _)) in file.tensors.iter().filter(|(n, _)| !skipped(n)) {
            let var = vars
                .get(&format!("{TRUNK}{name}"))
                .ok_or_else(|| ModelError::UnexpectedTensor(name.clone()))?;
            if var.size() != *shape {
                return Err(ModelError::ShapeMismatch {
                    name: name.clone(),
                    expected: var.size(),
                    found: shape.clone(),
                });
            }
        }
        for (name, _) in &trunk {
            let key = &name[TRUNK.len()..];
            if !file.tensors.contains_key(key) {
                return Err(ModelError::MissingTensor(key.to_string()));
            }
        }
        tch::no_grad(|| {
            for (name, var) in &trunk {
                let (dtype, shape, raw) = &file.tensors[&name[TRUNK.len()..]];
                let kind = match dtype.as_str() {
                    "F32" => Kind::Float,
                    "F16" => Kind::Half,
                    "BF16" => Kind::BFloat16,
                    other => {
                        return Err(ModelError::MalformedWeights(format!(
                            "tensor `{name}` is {other}, not a float"
                        )))
                    }
                };
                let t = Tensor::f_from_data_size(raw, shape, kind)?
                    .f_to_kind(var.kind())?
                    .f_to_device(var.device())?;
                let mut var = var.shallow_clone();
                var.f_copy_(&t)?;
            }
            Ok(trunk.len())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::VelocityMask;
    use cabc_proto::config::{MlpSize, VisionTrunk};
    use serde_json::{json, Map};
    use tch::Device;

    fn resnet_policy(seed: u64) -> Policy {
        let arch = PolicyArch::Camera {
            trunk: VisionTrunk::Resnet18,
            mlp: MlpSize {
                layers: 1,
                width: 8,
            },
            sees: VelocityMask::ALL,
        };
        Policy::new(arch, Device::Cpu, seed)
    }

    /// A torchvision-style state dict of `policy`'s trunk (its names without `trunk.`), with a classifier and
    /// BatchNorm counters as torchvision writes them, and `change` applied to the entries.
    fn state_dict(
        policy: &Policy,
        change: impl Fn(&mut Vec<(String, String, Vec<i64>, Vec<u8>)>),
    ) -> Vec<u8> {
        let mut entries: Vec<(String, String, Vec<i64>, Vec<u8>)> = policy
            .var_store()
            .variables()
            .into_iter()
            .filter_map(|(n, t)| Some((n.strip_prefix(TRUNK)?.to_string(), t)))
            .map(|(n, t)| ("F32".to_string(), n, t.size(), weights::f32_le_bytes(&t)))
            .map(|(d, n, s, b)| (n, d, s, b))
            .collect();
        entries.push((
            "fc.weight".into(),
            "F32".into(),
            vec![1000, 512],
            vec![0; 4 * 512_000],
        ));
        entries.push((
            "bn1.num_batches_tracked".into(),
            "I64".into(),
            vec![],
            vec![0; 8],
        ));
        change(&mut entries);
        let mut header = Map::new();
        let mut data = Vec::new();
        for (name, dtype, shape, bytes) in entries {
            let start = data.len();
            data.extend_from_slice(&bytes);
            header.insert(
                name,
                json!({"dtype": dtype, "shape": shape, "data_offsets": [start, data.len()]}),
            );
        }
        weights::frame(header, json!({"format": "pt"}), &data)
    }

    fn trunk_of(p: &Policy) -> Vec<(String, Tensor)> {
        let mut v: Vec<_> = p
            .var_store()
            .variables()
            .into_iter()
            .filter(|(n, _)| n.starts_with(TRUNK))
            .collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    #[test]
    fn a_torchvision_state_dict_loads_into_the_trunk_and_nothing_else() {
        let source = resnet_policy(1);
        let bytes = state_dict(&source, |_| {});
        let mut target = resnet_policy(2);
        let head_before = weights::to_bytes(target.var_store(), "x");
        let loaded = target.load_pretrained_trunk(&bytes).unwrap();
        assert_eq!(loaded, trunk_of(&source).len());
        for ((a, x), (b, y)) in trunk_of(&source).iter().zip(trunk_of(&target).iter()) {
            assert_eq!(a, b);
            assert!(x.equal(y), "{a} not loaded");
        }
        // The head keeps its own initialisation.
        let head = |p: &Policy| p.var_store().variables()["mlp.0.weight"].copy();
        assert!(!head(&target).equal(&head(&source)));
        assert_ne!(weights::to_bytes(target.var_store(), "x"), head_before);
    }

    #[test]
    fn a_wrong_file_is_refused_and_changes_nothing() {
        let source = resnet_policy(1);
        let mut target = resnet_policy(2);
        let before = weights::to_bytes(target.var_store(), "x");
        let missing = state_dict(&source, |e| {
            e.retain(|(n, ..)| n != "layer3.1.bn2.running_var")
        });
        let e = target
            .load_pretrained_trunk(&missing)
            .unwrap_err()
            .to_string();
        assert!(e.contains("layer3.1.bn2.running_var"), "{e}");
        let reshaped = state_dict(&source, |e| {
            let conv = e.iter_mut().find(|(n, ..)| n == "conv1.weight").unwrap();
            conv.2 = vec![64, 3, 49];
        });
        let e = target
            .load_pretrained_trunk(&reshaped)
            .unwrap_err()
            .to_string();
        assert!(e.contains("conv1.weight"), "{e}");
        let extra = state_dict(&source, |e| {
            e.push(("layer9.w".into(), "F32".into(), vec![1], vec![0; 4]))
        });
        assert!(target.load_pretrained_trunk(&extra).is_err());
        assert!(target.load_pretrained_trunk(b"not safetensors").is_err());
        assert_eq!(
            weights::to_bytes(target.var_store(), "x"),
            before,
            "nothing loaded"
        );
        // A policy without a ResNet-18 trunk refuses.
        let arch = PolicyArch::Camera {
            trunk: VisionTrunk::SmallCnn,
            mlp: MlpSize {
                layers: 1,
                width: 8,
            },
            sees: VelocityMask::ALL,
        };
        let mut small = Policy::new(arch, Device::Cpu, 3);
        assert!(small
            .load_pretrained_trunk(&state_dict(&source, |_| {}))
            .is_err());
    }
}
