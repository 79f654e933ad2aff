//! The MLP builder of algorithm.md 4: `layers` hidden Linear+ReLU layers of `width`, then a Linear output.
//! Kaiming-normal weights (ReLU gain), zero biases. (The reference adds BatchNorm only from 5 hidden layers, which
//! no network here has; larger sizes are refused rather than silently built differently.)

use cabc_proto::config::MlpSize;
use tch::{nn, nn::Module, Tensor};

/// Hidden layers an MLP here may have (from 5 the reference adds BatchNorm).
pub const MAX_LAYERS: usize = 4;
/// The widest hidden layer an architecture name may ask for: a name read from bytes cannot make an actor build a
/// network of any size it likes.
pub const MAX_WIDTH: usize = 4096;

/// Parameters of an MLP `in_dim -> size -> out_dim` (weights and biases); None on overflow.
pub fn params(in_dim: usize, out_dim: usize, size: MlpSize) -> Option<usize> {
    let mut n = 0usize;
    let mut dim = in_dim;
    for _ in 0..size.layers {
        n = n.checked_add(dim.checked_add(1)?.checked_mul(size.width)?)?;
        dim = size.width;
    }
    n.checked_add(dim.checked_add(1)?.checked_mul(out_dim)?)
}

/// Linear layers; ReLU between them, none after the last.
#[derive(Debug)]
pub struct Mlp {
    layers: Vec<nn::Linear>,
}

impl Mlp {
    /// Builds the layers under `p` (`p / "0"`, `p / "1"`, ...). Weights are zero until
    /// [`crate::init::kaiming_normal`] fills them (every network constructor does).
    pub fn new(p: &nn::Path, in_dim: i64, out_dim: i64, size: MlpSize) -> Mlp {
        assert!(
            size.layers <= MAX_LAYERS,
            "MLPs of 5 or more hidden layers need BatchNorm (reference), not built here"
        );
        let config = nn::LinearConfig {
            ws_init: nn::Init::Const(0.0),
            bs_init: Some(nn::Init::Const(0.0)),
            bias: true,
        };
        let mut layers = Vec::with_capacity(size.layers + 1);
        let mut dim = in_dim;
        for i in 0..size.layers {
            layers.push(nn::linear(
                p / i.to_string(),
                dim,
                size.width as i64,
                config,
            ));
            dim = size.width as i64;
        }
        layers.push(nn::linear(
            p / size.layers.to_string(),
            dim,
            out_dim,
            config,
        ));
        Mlp { layers }
    }
}

impl Module for Mlp {
    fn forward(&self, xs: &Tensor) -> Tensor {
        let (last, hidden) = self
            .layers
            .split_last()
            .expect("an MLP has an output layer");
        let h = hidden
            .iter()
            .fold(xs.shallow_clone(), |h, l| l.forward(&h).relu());
        last.forward(&h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::{kaiming_normal, Fan};
    use tch::{Device, Kind};

    #[test]
    fn shapes_and_kaiming_init() {
        let vs = nn::VarStore::new(Device::Cpu);
        let size = MlpSize {
            layers: 3,
            width: 512,
        };
        let mlp = Mlp::new(&vs.root(), 6, 2, size);
        kaiming_normal(&vs, 7, |_, _| Fan::In);
        let y = mlp.forward(&Tensor::zeros([5, 6], (Kind::Float, Device::Cpu)));
        assert_eq!(y.size(), vec![5, 2]);
        let vars = vs.variables();
        assert_eq!(vars.len(), 8);
        for (name, t) in &vars {
            if name.ends_with("bias") {
                assert_eq!(t.abs().max().double_value(&[]), 0.0, "{name}");
            } else {
                let fan_in = t.size()[1] as f64;
                let std = t.std(true).double_value(&[]);
                let want = (2.0 / fan_in).sqrt();
                assert!(
                    (std / want - 1.0).abs() < 0.1,
                    "{name}: std {std}, want {want}"
                );
                assert!(t.mean(Kind::Float).double_value(&[]).abs() < 0.1 * want);
            }
        }
        assert_eq!(vars["0.weight"].size(), vec![512, 6]);
        assert_eq!(vars["3.weight"].size(), vec![2, 512]);
    }
}
