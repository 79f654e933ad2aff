//! The policy pi_theta(y) (algorithm.md 4): the same code trains in the learner and drives in the actor.
//!
//! * full state: y = x (6) -> MLP -> [a, delta];
//! * camera: y = (image, [v_long, v_tran, omega]); trunk(image / 255, NCHW) ++ velocity -> MLP -> [a, delta].
//!
//! Observations become tensors in one place, [`PolicyInput::states`] and [`PolicyInput::camera`], for the actor's
//! [`Observation`]s and the learner's D+ batches alike.

use crate::init::{kaiming_normal, Fan};
use crate::vision::Trunk;
use crate::weights::{network, Network};
use crate::{mlp, weights, Mlp, ModelError};
use cabc_proto::config::{MlpSize, ObservationKind, RunConfig, Velocity, VisionTrunk};
use cabc_proto::messages::{image_bytes, velocity_of, Image, ACTION_DIM, STATE_DIM};
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;
use tch::{nn, nn::Module, nn::ModuleT, Device, Kind, Tensor};

pub use cabc_proto::messages::VELOCITY_DIM;

/// The policy's architecture; its [`Display`](fmt::Display) is the name stored with the weights and sent in
/// `PolicyUpdate.architecture`, e.g. `policy-state-mlp-3x128` or `policy-camera-resnet18-mlp-3x128` (a camera policy
/// that sees fewer than the three velocities says which: `policy-camera-small-cnn-mlp-3x128-sees-v_long`,
/// `...-sees-none`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolicyArch {
    State {
        mlp: MlpSize,
    },
    Camera {
        trunk: VisionTrunk,
        mlp: MlpSize,
        /// The velocities the network sees ([`velocity_of`]'s order, `observation.velocity_inputs`); the others are
        /// zero in its input.
        sees: VelocityMask,
    },
}

/// Which of [v_long, v_tran, omega] a camera policy sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VelocityMask(pub [bool; VELOCITY_DIM]);

impl VelocityMask {
    /// All three: the paper's camera policy.
    pub const ALL: VelocityMask = VelocityMask([true; VELOCITY_DIM]);

    pub fn of(seen: &[Velocity]) -> Self {
        let mut mask = [false; VELOCITY_DIM];
        for v in seen {
            mask[v.index()] = true;
        }
        VelocityMask(mask)
    }

    /// 1 for a velocity seen, 0 for one masked: what multiplies the velocities before the head.
    fn factors(self) -> [f32; VELOCITY_DIM] {
        self.0.map(|seen| if seen { 1.0 } else { 0.0 })
    }

    /// The name's suffix: empty for all three, else `-sees-` and the names joined by `+` (or `none`).
    fn suffix(self) -> String {
        if self == VelocityMask::ALL {
            return String::new();
        }
        let names: Vec<&str> = Velocity::ALL
            .iter()
            .filter(|v| self.0[v.index()])
            .map(|v| v.as_str())
            .collect();
        match names.is_empty() {
            true => "-sees-none".into(),
            false => format!("-sees-{}", names.join("+")),
        }
    }

    fn parse(suffix: &str) -> Option<Self> {
        if suffix == "none" {
            return Some(VelocityMask([false; VELOCITY_DIM]));
        }
        let mut seen = Vec::new();
        for name in suffix.split('+') {
            let v = Velocity::ALL.into_iter().find(|v| v.as_str() == name)?;
            if seen.last().is_some_and(|last| *last >= v) {
                return None;
            }
            seen.push(v);
        }
        let mask = VelocityMask::of(&seen);
        (mask != VelocityMask::ALL).then_some(mask)
    }
}

impl PolicyArch {
    /// The architecture a run configuration asks for.
    pub fn from_config(config: &RunConfig) -> Self {
        let mlp = config.networks.policy;
        match config.observation.kind {
            ObservationKind::State => PolicyArch::State { mlp },
            ObservationKind::Camera => PolicyArch::Camera {
                trunk: config.observation.trunk,
                mlp,
                sees: VelocityMask::of(&config.observation.velocity_inputs),
            },
        }
    }
}

fn trunk_name(t: VisionTrunk) -> &'static str {
    match t {
        VisionTrunk::Resnet18 => "resnet18",
        VisionTrunk::SmallCnn => "small-cnn",
    }
}

impl fmt::Display for PolicyArch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PolicyArch::State { mlp } => write!(f, "policy-state-mlp-{}x{}", mlp.layers, mlp.width),
            PolicyArch::Camera { trunk, mlp, sees } => write!(
                f,
                "policy-camera-{}-mlp-{}x{}{}",
                trunk_name(*trunk),
                mlp.layers,
                mlp.width,
                sees.suffix()
            ),
        }
    }
}

/// An MLP size from its name, within what [`Mlp`] builds ([`mlp::MAX_LAYERS`], [`mlp::MAX_WIDTH`]).
fn parse_mlp(s: &str) -> Option<MlpSize> {
    let (l, w) = s.strip_prefix("mlp-")?.split_once('x')?;
    let size = MlpSize {
        layers: l.parse().ok()?,
        width: w.parse().ok()?,
    };
    (size.layers <= mlp::MAX_LAYERS && (1..=mlp::MAX_WIDTH).contains(&size.width)).then_some(size)
}

impl FromStr for PolicyArch {
    type Err = ModelError;

    fn from_str(s: &str) -> Result<Self, ModelError> {
        let unknown = || ModelError::UnknownArchitecture(s.to_string());
        if let Some(rest) = s.strip_prefix("policy-state-") {
            return Ok(PolicyArch::State {
                mlp: parse_mlp(rest).ok_or_else(unknown)?,
            });
        }
        let rest = s.strip_prefix("policy-camera-").ok_or_else(unknown)?;
        let (rest, sees) = match rest.split_once("-sees-") {
            Some((rest, seen)) => (rest, VelocityMask::parse(seen).ok_or_else(unknown)?),
            None => (rest, VelocityMask::ALL),
        };
        for trunk in [VisionTrunk::Resnet18, VisionTrunk::SmallCnn] {
            if let Some(mlp) = rest
                .strip_prefix(trunk_name(trunk))
                .and_then(|r| r.strip_prefix('-'))
            {
                return Ok(PolicyArch::Camera {
                    trunk,
                    mlp: parse_mlp(mlp).ok_or_else(unknown)?,
                    sees,
                });
            }
        }
        Err(unknown())
    }
}

/// A batch of observations as tensors (on any device; the policy moves them).
#[derive(Debug)]
pub enum PolicyInput {
    /// [N, 6] float.
    State(Tensor),
    /// `images`: [N, H, W, 3] u8 (HWC, as the camera delivers); `velocity`: [N, 3] float.
    Camera { images: Tensor, velocity: Tensor },
}

impl PolicyInput {
    /// Full states, stacked into [N, 6].
    pub fn states<'a>(states: impl IntoIterator<Item = &'a [f32; STATE_DIM]>) -> Self {
        let flat: Vec<f32> = states.into_iter().flatten().copied().collect();
        PolicyInput::State(Tensor::from_slice(&flat).view([-1, STATE_DIM as i64]))
    }

    /// The one camera batching routine (the actor's observations and the learner's D+ batches): frames of
    /// `width` x `height` RGB bytes (HWC) with their velocities, stacked into [N, H, W, 3] u8 and [N, 3].
    pub fn camera<'a>(
        width: u16,
        height: u16,
        frames: impl IntoIterator<Item = (&'a [u8], [f32; VELOCITY_DIM])>,
    ) -> Result<Self, ModelError> {
        let per = image_bytes(width.into(), height.into());
        let frames = frames.into_iter();
        let mut pixels = Vec::with_capacity(per * frames.size_hint().0);
        let mut velocity = Vec::with_capacity(VELOCITY_DIM * frames.size_hint().0);
        for (rgb, v) in frames {
            if rgb.len() != per {
                return Err(ModelError::Observation(format!(
                    "an image of {} bytes in a batch of {width}x{height} RGB images ({per} bytes each)",
                    rgb.len()
                )));
            }
            pixels.extend_from_slice(rgb);
            velocity.extend_from_slice(&v);
        }
        let n = (velocity.len() / VELOCITY_DIM) as i64;
        Ok(PolicyInput::Camera {
            images: Tensor::from_slice(&pixels).view([n, height as i64, width as i64, 3]),
            velocity: Tensor::from_slice(&velocity).view([n, VELOCITY_DIM as i64]),
        })
    }
}

/// One observation, as an actor holds it.
#[derive(Clone, Copy, Debug)]
pub enum Observation<'a> {
    State(&'a [f32; STATE_DIM]),
    Camera {
        image: &'a Image,
        velocity: [f32; VELOCITY_DIM],
    },
}

impl<'a> Observation<'a> {
    /// The camera observation at `state`: the image and the state's velocities ([`velocity_of`]).
    pub fn camera(image: &'a Image, state: &[f32; STATE_DIM]) -> Self {
        Observation::Camera {
            image,
            velocity: velocity_of(state),
        }
    }
}

/// u8 NHWC -> float NCHW in [0, 1] (no mean/std normalisation, as the reference).
pub fn images_to_float(images_nhwc_u8: &Tensor) -> Tensor {
    images_nhwc_u8.permute([0, 3, 1, 2]).to_kind(Kind::Float) / 255.0
}

#[derive(Debug)]
enum Net {
    State(Mlp),
    Camera {
        trunk: Box<Trunk>,
        head: Mlp,
        /// [1, 3]: 1 for a velocity the policy sees, 0 for one masked ([`VelocityMask`]).
        sees: Tensor,
    },
}

/// pi_theta with its variables.
#[derive(Debug)]
pub struct Policy {
    vs: nn::VarStore,
    arch: PolicyArch,
    net: Net,
}

impl Policy {
    /// A freshly initialised policy; the same `seed` gives the same weights.
    pub fn new(arch: PolicyArch, device: Device, seed: u64) -> Self {
        let vs = nn::VarStore::new(device);
        let root = vs.root();
        let out = ACTION_DIM as i64;
        let net = match arch {
            PolicyArch::State { mlp } => {
                Net::State(Mlp::new(&(&root / "mlp"), STATE_DIM as i64, out, mlp))
            }
            PolicyArch::Camera { trunk, mlp, sees } => Net::Camera {
                trunk: Box::new(Trunk::new(&(&root / "trunk"), trunk)),
                head: Mlp::new(
                    &(&root / "mlp"),
                    Trunk::features(trunk) + VELOCITY_DIM as i64,
                    out,
                    mlp,
                ),
                sees: Tensor::from_slice(&sees.factors())
                    .view([1, VELOCITY_DIM as i64])
                    .to_device(device),
            },
        };
        // Linear layers: fan-in (the reference's init_weights); convolutions: fan-out (torchvision's ResNet).
        kaiming_normal(
            &vs,
            seed,
            |_, dims| if dims == 4 { Fan::Out } else { Fan::In },
        );
        Policy { vs, arch, net }
    }

    /// A policy built from weights alone: the architecture is read from the bytes. Refused before anything is built
    /// when the name is not one of [`PolicyArch`]'s or the bytes hold fewer values than its MLP head alone (so the
    /// size of what is built follows the bytes' length, not a name). An actor uses [`PolicyCheck`] instead, which
    /// also holds the weights to the run's architecture.
    pub fn from_bytes(bytes: &[u8], device: Device) -> Result<Self, ModelError> {
        let arch: PolicyArch = weights::architecture_of(bytes)?.parse()?;
        let (in_dim, mlp) = match arch {
            PolicyArch::State { mlp } => (STATE_DIM, mlp),
            PolicyArch::Camera { trunk, mlp, .. } => {
                (Trunk::features(trunk) as usize + VELOCITY_DIM, mlp)
            }
        };
        let head = mlp::params(in_dim, ACTION_DIM, mlp).and_then(|n| n.checked_mul(4));
        if head.is_none_or(|head| head > bytes.len()) {
            return Err(ModelError::MalformedWeights(format!(
                "{} bytes cannot hold the weights of {arch}",
                bytes.len()
            )));
        }
        let mut policy = Policy::new(arch, device, 0);
        policy.load_bytes(bytes)?;
        Ok(policy)
    }

    pub fn arch(&self) -> PolicyArch {
        self.arch
    }

    /// Actions [N, 2] (training: `train` = true updates batch-norm statistics of the ResNet trunk).
    pub fn forward_t(&self, input: &PolicyInput, train: bool) -> Tensor {
        let device = self.device();
        match (&self.net, input) {
            (Net::State(mlp), PolicyInput::State(x)) => mlp.forward(&x.to_device(device)),
            (Net::Camera { trunk, head, sees }, PolicyInput::Camera { images, velocity }) => {
                // From pageable memory, which waits for the kernels queued before: pinning each batch first
                // (`_pin_memory`, then a copy that does not wait) made the policy's fit at 224x224 a third slower on
                // an H200 (issue 56, docs/GPU.md).
                let features = trunk.forward_t(&images_to_float(&images.to_device(device)), train);
                let velocity = velocity.to_device(device) * sees.to_device(device);
                head.forward(&Tensor::cat(&[features, velocity], 1))
            }
            _ => panic!(
                "policy {} given the other kind of input (use Policy::act for checked input)",
                self.arch
            ),
        }
    }

    /// Actions for a batch of observations, in evaluation mode and without gradients (the actor's call).
    pub fn act(&self, observations: &[Observation]) -> Result<Vec<[f32; ACTION_DIM]>, ModelError> {
        if observations.is_empty() {
            return Ok(Vec::new());
        }
        let input = self.input_of(observations)?;
        let actions = tch::no_grad(|| self.forward_t(&input, false))
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .contiguous()
            .view(-1);
        let flat = Vec::<f32>::try_from(&actions)?;
        Ok(flat
            .chunks_exact(ACTION_DIM)
            .map(|c| [c[0], c[1]])
            .collect())
    }

    /// Folds a standardisation of the state, x_n = (x - mean) / std, into the first layer of a full-state policy
    /// trained on x_n: W' = W / std (per input column), b' = b - W' mean, so that the policy then takes raw states
    /// (the learner's `training.standardise`). Refused for a camera policy.
    pub fn fold_input_standardisation(
        &mut self,
        mean: &[f32; STATE_DIM],
        std: &[f32; STATE_DIM],
    ) -> Result<(), ModelError> {
        if !matches!(self.arch, PolicyArch::State { .. }) {
            return Err(ModelError::Observation(format!(
                "{} takes images: no state standardisation to fold",
                self.arch
            )));
        }
        let vars = self.vs.variables();
        let (Some(w), Some(b)) = (vars.get("mlp.0.weight"), vars.get("mlp.0.bias")) else {
            return Err(ModelError::MissingTensor("mlp.0.weight".into()));
        };
        let (mut w, mut b) = (w.shallow_clone(), b.shallow_clone());
        let device = w.device();
        let inv_std = Tensor::from_slice(std).to_device(device).reciprocal();
        let mean = Tensor::from_slice(mean).to_device(device);
        tch::no_grad(|| {
            let w_folded = &w * inv_std.unsqueeze(0);
            let b_folded = &b - w_folded.matmul(&mean);
            w.copy_(&w_folded);
            b.copy_(&b_folded);
        });
        Ok(())
    }

    /// Shorthand for a full-state policy.
    pub fn act_states(
        &self,
        states: &[[f32; STATE_DIM]],
    ) -> Result<Vec<[f32; ACTION_DIM]>, ModelError> {
        let obs: Vec<Observation> = states.iter().map(Observation::State).collect();
        self.act(&obs)
    }

    fn input_of(&self, observations: &[Observation]) -> Result<PolicyInput, ModelError> {
        let wrong = |what: String| ModelError::Observation(format!("{} takes {what}", self.arch));
        match self.arch {
            PolicyArch::State { .. } => {
                let states = observations
                    .iter()
                    .map(|o| match o {
                        Observation::State(x) => Ok(*x),
                        Observation::Camera { .. } => {
                            Err(wrong("states, got a camera observation".into()))
                        }
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                Ok(PolicyInput::states(states))
            }
            PolicyArch::Camera { .. } => {
                let (w, h) = match observations[0] {
                    Observation::Camera { image, .. } => (image.width, image.height),
                    Observation::State(_) => (0, 0),
                };
                let one_size = || {
                    let per = w as usize * h as usize * 3;
                    wrong(format!(
                        "camera images of one size ({w}x{h}, {per} bytes each)"
                    ))
                };
                let frames = observations
                    .iter()
                    .map(|o| match o {
                        Observation::Camera { image, velocity }
                            if image.width == w && image.height == h =>
                        {
                            Ok((image.rgb.as_slice(), *velocity))
                        }
                        _ => Err(one_size()),
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                PolicyInput::camera(w, h, frames).map_err(|_| one_size())
            }
        }
    }
}

// The architecture's name (`PolicyUpdate.architecture`).
network!(Policy, |self| self.arch.to_string());

/// The run's policy architecture with its tensors' shapes: weights received from the bus are checked against it
/// (the update's architecture name, the name in the weights' metadata, every tensor's shape) before anything is
/// built from them, so a malformed or foreign update is a typed error, never a panic or a network of its own size.
#[derive(Clone, Debug)]
pub struct PolicyCheck {
    arch: PolicyArch,
    name: String,
    shapes: BTreeMap<String, Vec<i64>>,
}

impl PolicyCheck {
    /// The check for `arch` (a run configuration's, [`PolicyArch::from_config`]; built once to learn the shapes).
    pub fn new(arch: PolicyArch) -> Self {
        let template = Policy::new(arch, Device::Cpu, 0);
        PolicyCheck {
            arch,
            name: arch.to_string(),
            shapes: weights::shapes_of(&template.vs),
        }
    }

    pub fn arch(&self) -> PolicyArch {
        self.arch
    }

    /// Checks an update's `architecture` and its weights against the run's architecture; builds nothing.
    pub fn check(&self, architecture: &str, bytes: &[u8]) -> Result<(), ModelError> {
        if architecture != self.name {
            return Err(ModelError::ArchitectureMismatch {
                expected: self.name.clone(),
                found: architecture.to_string(),
            });
        }
        weights::check(bytes, &self.name, &self.shapes)
    }

    /// The policy of checked weights: [`PolicyCheck::check`], then the run's architecture filled with them.
    pub fn policy(
        &self,
        architecture: &str,
        bytes: &[u8],
        device: Device,
    ) -> Result<Policy, ModelError> {
        self.check(architecture, bytes)?;
        let mut policy = Policy::new(self.arch, device, 0);
        policy.load_bytes(bytes)?;
        Ok(policy)
    }
}
