//! The policy pi_theta(y) (algorithm.md 4): the same code trains in the learner and drives in the actor.
//!
//! * full state: y = x (6) -> MLP -> [a, delta];
//! * camera: y = (image, [v_long, v_tran, omega]); trunk(image / 255, NCHW) ++ velocity -> MLP -> [a, delta].

use crate::init::{kaiming_normal, Fan};
use crate::vision::Trunk;
use crate::weights::Network;
use crate::{weights, Mlp, ModelError};
use cabc_proto::config::{MlpSize, ObservationKind, RunConfig, VisionTrunk};
use cabc_proto::messages::{Image, ACTION_DIM, STATE_DIM};
use std::fmt;
use std::str::FromStr;
use tch::{nn, nn::Module, nn::ModuleT, Device, Kind, Tensor};

/// Velocities the camera policy sees beside the image.
pub const VELOCITY_DIM: usize = 3;

/// The policy's architecture; its [`Display`](fmt::Display) is the name stored with the weights and sent in
/// `PolicyUpdate.architecture`, e.g. `policy-state-mlp-3x128` or `policy-camera-resnet18-mlp-3x128`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolicyArch {
    State { mlp: MlpSize },
    Camera { trunk: VisionTrunk, mlp: MlpSize },
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
            PolicyArch::Camera { trunk, mlp } => write!(
                f,
                "policy-camera-{}-mlp-{}x{}",
                trunk_name(*trunk),
                mlp.layers,
                mlp.width
            ),
        }
    }
}

fn parse_mlp(s: &str) -> Option<MlpSize> {
    let (l, w) = s.strip_prefix("mlp-")?.split_once('x')?;
    Some(MlpSize {
        layers: l.parse().ok()?,
        width: w.parse().ok()?,
    })
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
        for trunk in [VisionTrunk::Resnet18, VisionTrunk::SmallCnn] {
            if let Some(mlp) = rest
                .strip_prefix(trunk_name(trunk))
                .and_then(|r| r.strip_prefix('-'))
            {
                return Ok(PolicyArch::Camera {
                    trunk,
                    mlp: parse_mlp(mlp).ok_or_else(unknown)?,
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

/// One observation, as an actor holds it.
#[derive(Clone, Copy, Debug)]
pub enum Observation<'a> {
    State(&'a [f32; STATE_DIM]),
    Camera {
        image: &'a Image,
        velocity: [f32; VELOCITY_DIM],
    },
}

/// u8 NHWC -> float NCHW in [0, 1] (no mean/std normalisation, as the reference).
pub fn images_to_float(images_nhwc_u8: &Tensor) -> Tensor {
    images_nhwc_u8.permute([0, 3, 1, 2]).to_kind(Kind::Float) / 255.0
}

#[derive(Debug)]
enum Net {
    State(Mlp),
    Camera { trunk: Box<Trunk>, head: Mlp },
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
            PolicyArch::Camera { trunk, mlp } => Net::Camera {
                trunk: Box::new(Trunk::new(&(&root / "trunk"), trunk)),
                head: Mlp::new(
                    &(&root / "mlp"),
                    Trunk::features(trunk) + VELOCITY_DIM as i64,
                    out,
                    mlp,
                ),
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

    /// A policy built from weights alone: the architecture is read from the bytes (the actor's entry point).
    pub fn from_bytes(bytes: &[u8], device: Device) -> Result<Self, ModelError> {
        let arch: PolicyArch = weights::architecture_of(bytes)?.parse()?;
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
            (Net::Camera { trunk, head }, PolicyInput::Camera { images, velocity }) => {
                let features = trunk.forward_t(&images_to_float(&images.to_device(device)), train);
                head.forward(&Tensor::cat(&[features, velocity.to_device(device)], 1))
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

    /// Shorthand for a full-state policy.
    pub fn act_states(
        &self,
        states: &[[f32; STATE_DIM]],
    ) -> Result<Vec<[f32; ACTION_DIM]>, ModelError> {
        let obs: Vec<Observation> = states.iter().map(Observation::State).collect();
        self.act(&obs)
    }

    fn input_of(&self, observations: &[Observation]) -> Result<PolicyInput, ModelError> {
        let n = observations.len() as i64;
        match self.arch {
            PolicyArch::State { .. } => {
                let mut flat = Vec::with_capacity(observations.len() * STATE_DIM);
                for o in observations {
                    match o {
                        Observation::State(x) => flat.extend_from_slice(&x[..]),
                        Observation::Camera { .. } => {
                            return Err(ModelError::Observation(format!(
                                "{} takes states, got a camera observation",
                                self.arch
                            )))
                        }
                    }
                }
                Ok(PolicyInput::State(
                    Tensor::from_slice(&flat).view([n, STATE_DIM as i64]),
                ))
            }
            PolicyArch::Camera { .. } => {
                let (w, h) = match observations[0] {
                    Observation::Camera { image, .. } => (image.width, image.height),
                    Observation::State(_) => (0, 0),
                };
                let per = w as usize * h as usize * 3;
                let mut pixels = Vec::with_capacity(per * observations.len());
                let mut velocity = Vec::with_capacity(VELOCITY_DIM * observations.len());
                for o in observations {
                    match o {
                        Observation::Camera { image, velocity: v }
                            if image.width == w && image.height == h && image.rgb.len() == per =>
                        {
                            pixels.extend_from_slice(&image.rgb);
                            velocity.extend_from_slice(v);
                        }
                        _ => {
                            return Err(ModelError::Observation(format!(
                                "{} takes camera images of one size ({w}x{h}, {per} bytes each)",
                                self.arch
                            )))
                        }
                    }
                }
                Ok(PolicyInput::Camera {
                    images: Tensor::from_slice(&pixels).view([n, h as i64, w as i64, 3]),
                    velocity: Tensor::from_slice(&velocity).view([n, VELOCITY_DIM as i64]),
                })
            }
        }
    }
}

impl Network for Policy {
    fn var_store(&self) -> &nn::VarStore {
        &self.vs
    }

    fn var_store_mut(&mut self) -> &mut nn::VarStore {
        &mut self.vs
    }

    /// The architecture's name (`PolicyUpdate.architecture`).
    fn architecture(&self) -> String {
        self.arch.to_string()
    }
}
