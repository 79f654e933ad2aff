//! cabc-models: the three networks of constraint-aware behaviour cloning (algorithm.md 4) in tch, shared by the
//! learner (training) and the actor (inference):
//!
//! * [`Policy`] pi_theta(y): an MLP on the full state, or a vision trunk (ResNet-18 / small CNN) on the camera image
//!   concatenated with the velocities, then an MLP;
//! * [`Dynamics`] f_hat(x, u) = x + MLP([x, u]) (residual), trained by eq. (15);
//! * [`Critic`] the logit of p_hat(x in the backward reachable tube), trained by eq. (16).
//!
//! Each network owns its `VarStore` and carries its architecture's name; weights travel as safetensors bytes with
//! that name in the metadata ([`weights`]), so weights of another architecture are refused by a typed error.

pub mod critic;
pub mod device;
pub mod dynamics;
pub mod error;
pub mod init;
pub mod mlp;
pub mod policy;
pub mod precision;
pub mod pretrained;
pub mod vision;
pub mod weights;

pub use critic::Critic;
pub use device::{cuda_available, device_name, flush_denormals, parse_device};
pub use dynamics::Dynamics;
pub use error::ModelError;
pub use mlp::Mlp;
pub use policy::{Observation, Policy, PolicyArch, PolicyCheck, PolicyInput, VelocityMask};
pub use weights::Network;
