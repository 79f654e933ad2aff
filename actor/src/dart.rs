//! DART (Laskey et al. 2017) in collection: Gaussian noise on the applied action (`collection.action_noise_std`),
//! the expert's label untouched, so that D+ holds the states the policy must recover from.

use cabc_sim::env::Env;
use cabc_sim::vehicle::Input;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Mixed into the run seed for the action noise's random streams.
const ACTION_NOISE_SEED: u64 = 0xda_4700;

/// DART's noise on the applied action (`collection.action_noise_std`): Gaussian per dimension, drawn from each
/// environment's own stream (so that it changes neither the environments' nor the sensor's draws, and the order in
/// which halves of the batch step does not matter), and nothing drawn where a dimension's deviation is 0.
pub(crate) struct ActionNoise {
    std: [f64; 2],
    /// One stream per environment of the collector.
    rngs: Vec<ChaCha8Rng>,
}

impl ActionNoise {
    /// Actor `index`'s environments use streams index*K .. index*K+K-1, as their environments do.
    pub(crate) fn new(std: [f64; 2], seed: u64, index: u64, k: usize) -> Self {
        let first = index * k as u64;
        ActionNoise {
            std,
            rngs: (0..k as u64)
                .map(|i| Env::rng(seed ^ ACTION_NOISE_SEED, first + i))
                .collect(),
        }
    }

    /// `action` plus environment `env`'s noise.
    pub(crate) fn add(&mut self, env: usize, mut action: Input) -> Input {
        for (u, &std) in action.iter_mut().zip(&self.std) {
            if std > 0.0 {
                let n: f64 = self.rngs[env].sample(StandardNormal);
                *u += std * n;
            }
        }
        action
    }
}
