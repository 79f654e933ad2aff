//! The state's standardisation (`training.standardise`): x_n = (x - mean) / std per dimension, with D+'s mean and
//! standard deviation taken once, at the first policy fit, and kept in the checkpoint. The three networks train on
//! x_n (the policy's input, f_hat's state in and out, p_hat's input); the published policy takes raw states, the
//! standardisation folded into its first layer ([`cabc_models::Policy::fold_input_standardisation`]), so actors,
//! exports and old readers of policy weights see a plain MLP.
//!
//! Why: the reference feeds the raw state, where s runs over the whole track length while the velocities and
//! errors stay near 1, so the first layer's inputs differ in scale by an order of magnitude (robomimic, LeRobot and
//! Diffusion Policy all standardise inputs from the data's own statistics).

use cabc_proto::messages::STATE_DIM;
use serde::{Deserialize, Serialize};
use tch::{Device, Tensor};

/// A dimension whose standard deviation is below this is divided by it instead (a constant dimension stays
/// finite).
pub const MIN_STD: f32 = 1e-3;

/// Per-dimension mean and standard deviation of the state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Standardiser {
    pub mean: [f32; STATE_DIM],
    pub std: [f32; STATE_DIM],
}

impl Standardiser {
    /// The statistics of `states` (in f64, population standard deviation, floored at [`MIN_STD`]); None when
    /// there are none.
    pub fn of(states: &[[f32; STATE_DIM]]) -> Option<Self> {
        if states.is_empty() {
            return None;
        }
        let n = states.len() as f64;
        let mut mean = [0.0f64; STATE_DIM];
        for x in states {
            for (m, v) in mean.iter_mut().zip(x) {
                *m += *v as f64;
            }
        }
        mean.iter_mut().for_each(|m| *m /= n);
        let mut var = [0.0f64; STATE_DIM];
        for x in states {
            for k in 0..STATE_DIM {
                var[k] += (x[k] as f64 - mean[k]).powi(2);
            }
        }
        Some(Standardiser {
            mean: mean.map(|m| m as f32),
            std: std::array::from_fn(|k| ((var[k] / n).sqrt() as f32).max(MIN_STD)),
        })
    }

    /// (x - mean) / std for x [N, 6] on any device.
    pub fn apply(&self, x: &Tensor) -> Tensor {
        let device: Device = x.device();
        let mean = Tensor::from_slice(&self.mean).to_device(device);
        let std = Tensor::from_slice(&self.std).to_device(device);
        (x - mean) / std
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standardised_states_have_zero_mean_and_unit_deviation() {
        let states: Vec<[f32; 6]> = (0..100)
            .map(|i| {
                let t = i as f32;
                [1.0 + 0.01 * t, 0.0, -t, 10.0 * t, 0.5, 2.0]
            })
            .collect();
        let s = Standardiser::of(&states).unwrap();
        assert_eq!(s.std[1], MIN_STD, "a constant dimension is floored");
        let flat: Vec<f32> = states.iter().flatten().copied().collect();
        let x = s.apply(&Tensor::from_slice(&flat).view([-1, 6]));
        let mean = Vec::<f64>::try_from(x.mean_dim(0, false, tch::Kind::Double)).unwrap();
        let std = Vec::<f64>::try_from(x.std_dim(0, false, false)).unwrap();
        for k in [0, 2, 3] {
            assert!(
                mean[k].abs() < 1e-4 && (std[k] - 1.0).abs() < 1e-4,
                "{k}: {mean:?} {std:?}"
            );
        }
        assert_eq!(Standardiser::of(&[]), None);
    }
}
