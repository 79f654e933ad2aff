//! Deterministic weight initialisation from a seed.
//!
//! libtorch's global generator is shared by every thread of the process, so two networks built concurrently (tests,
//! the learner beside an evaluation) would not be reproducible from `tch::manual_seed`. Instead every weight is drawn
//! here from a ChaCha stream owned by the network being built: the same seed gives the same network, always.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::{nn, Tensor};

/// Which fan the Kaiming normal scales by: fan-in for linear layers (the reference's `init_weights`), fan-out for
/// convolutions (torchvision's ResNet).
#[derive(Clone, Copy, Debug)]
pub enum Fan {
    In,
    Out,
}

/// Fills every weight of `vs` with at least two dimensions: Kaiming normal with ReLU gain, std = sqrt(2 / fan).
/// Biases and batch-norm parameters keep the constants the layers were built with (zero bias, unit scale).
/// Variables are visited in name order, so the result depends on the seed only.
pub fn kaiming_normal(vs: &nn::VarStore, seed: u64, fan_of: impl Fn(&str, usize) -> Fan) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    tch::no_grad(|| {
        for (name, mut var) in vars {
            let dims = var.size();
            if dims.len() < 2 {
                continue;
            }
            let receptive: i64 = dims.iter().skip(2).product();
            let fan = match fan_of(&name, dims.len()) {
                Fan::In => dims[1] * receptive,
                Fan::Out => dims[0] * receptive,
            };
            let std = (2.0 / fan as f64).sqrt();
            let n: i64 = dims.iter().product();
            let values: Vec<f32> = (0..n).map(|_| (std * normal(&mut rng)) as f32).collect();
            let t = Tensor::from_slice(&values)
                .reshape(dims.as_slice())
                .to_kind(var.kind())
                .to_device(var.device());
            var.copy_(&t);
        }
    });
}

/// A standard normal sample (Box-Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.gen::<f64>(); // (0, 1]
    let u2: f64 = rng.gen::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}
