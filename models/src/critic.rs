//! The safety critic: a logit whose sigmoid p_hat(x) estimates P(x in the backward reachable tube), trained by
//! binary cross-entropy, eq. (16). The input dimension is free (6 for the state, 2 in the Fig. 3 example).

use crate::init::{kaiming_normal, Fan};
use crate::weights::network;
use crate::Mlp;
use cabc_proto::config::MlpSize;
use tch::{nn, nn::Module, Device, Tensor};

#[derive(Debug)]
pub struct Critic {
    vs: nn::VarStore,
    in_dim: usize,
    size: MlpSize,
    mlp: Mlp,
}

impl Critic {
    pub fn new(in_dim: usize, size: MlpSize, device: Device, seed: u64) -> Self {
        let vs = nn::VarStore::new(device);
        let mlp = Mlp::new(&(vs.root() / "mlp"), in_dim as i64, 1, size);
        kaiming_normal(&vs, seed, |_, _| Fan::In);
        Critic {
            vs,
            in_dim,
            size,
            mlp,
        }
    }

    /// Logits [N] for states [N, d].
    pub fn logits(&self, x: &Tensor) -> Tensor {
        self.mlp.forward(x).squeeze_dim(1)
    }

    /// p_hat(x) = sigmoid(logit) [N].
    pub fn probability(&self, x: &Tensor) -> Tensor {
        self.logits(x).sigmoid()
    }

    pub fn in_dim(&self) -> usize {
        self.in_dim
    }
}

// e.g. `critic-6-mlp-4x256`.
network!(Critic, |self| format!(
    "critic-{}-mlp-{}x{}",
    self.in_dim, self.size.layers, self.size.width
));
