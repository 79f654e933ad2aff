//! The learned one-step dynamics f_hat(x, u) = x + MLP([x, u]) (algorithm.md 1, residual), trained by eq. (15).

use crate::init::{kaiming_normal, Fan};
use crate::weights::network;
use crate::Mlp;
use cabc_proto::config::MlpSize;
use cabc_proto::messages::{ACTION_DIM, STATE_DIM};
use tch::{nn, nn::Module, Device, Tensor};

#[derive(Debug)]
pub struct Dynamics {
    vs: nn::VarStore,
    size: MlpSize,
    mlp: Mlp,
}

impl Dynamics {
    pub fn new(size: MlpSize, device: Device, seed: u64) -> Self {
        let vs = nn::VarStore::new(device);
        let mlp = Mlp::new(
            &(vs.root() / "mlp"),
            (STATE_DIM + ACTION_DIM) as i64,
            STATE_DIM as i64,
            size,
        );
        kaiming_normal(&vs, seed, |_, _| Fan::In);
        Dynamics { vs, size, mlp }
    }

    /// x' = x + MLP([x, u]); x [N, 6], u [N, 2].
    pub fn forward(&self, x: &Tensor, u: &Tensor) -> Tensor {
        x + self.mlp.forward(&Tensor::cat(&[x, u], 1))
    }
}

// e.g. `dynamics-residual-mlp-3x64`.
network!(Dynamics, |self| format!(
    "dynamics-residual-mlp-{}x{}",
    self.size.layers, self.size.width
));
