//! Sensor noise: the paper's n_k in the output equation y_k = g(x_k) + n_k. What the policy sees, in collection and
//! in evaluation, is the true state plus Gaussian noise of `observation.state_noise_std` per dimension, and the
//! rendered image plus Gaussian noise of `observation.pixel_noise_std` per channel (clamped to 0..255). Off by
//! default (all zeros).
//!
//! A step stores the image the policy saw (the noisy one: the vision policy is cloned on what its camera gives it)
//! and the true state (the learner's x: the dynamics model, the critic and the auto-labelling's hulls are about the
//! car's state, Definition 1).

use cabc_proto::config::ObservationSection;
use cabc_proto::messages::Image;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// The noise of one observer, from its own random stream.
pub struct Sensor {
    state_std: [f32; 6],
    pixel_std: f32,
    rng: ChaCha8Rng,
}

impl Sensor {
    /// `rng` is the observer's own stream (so noise does not change the environments' draws).
    pub fn new(observation: &ObservationSection, rng: ChaCha8Rng) -> Self {
        Sensor {
            state_std: observation.state_noise_std.map(|s| s as f32),
            pixel_std: observation.pixel_noise_std as f32,
            rng,
        }
    }

    /// Whether any noise is added.
    pub fn is_noisy(&self) -> bool {
        self.pixel_std > 0.0 || self.state_std.iter().any(|&s| s > 0.0)
    }

    /// y = x + n for the state.
    pub fn state(&mut self, mut state: [f32; 6]) -> [f32; 6] {
        for (x, &std) in state.iter_mut().zip(&self.state_std) {
            if std > 0.0 {
                let n: f32 = self.rng.sample(StandardNormal);
                *x += std * n;
            }
        }
        state
    }

    /// The image with noise added to every channel of every pixel.
    pub fn image(&mut self, mut image: Image) -> Image {
        if self.pixel_std > 0.0 {
            for p in &mut image.rgb {
                let n: f32 = self.rng.sample(StandardNormal);
                *p = (*p as f32 + self.pixel_std * n).round().clamp(0.0, 255.0) as u8;
            }
        }
        image
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_sim::env::Env;

    fn sensor(state_std: [f64; 6], pixel_std: f64) -> Sensor {
        let observation = ObservationSection {
            state_noise_std: state_std,
            pixel_noise_std: pixel_std,
            ..Default::default()
        };
        Sensor::new(&observation, Env::rng(1, 2))
    }

    #[test]
    fn no_noise_by_default_changes_nothing() {
        let mut s = Sensor::new(&ObservationSection::default(), Env::rng(1, 2));
        assert!(!s.is_noisy());
        let x = [1.0, 0.1, 0.2, 3.0, 0.05, -0.1];
        assert_eq!(s.state(x), x);
        let image = Image {
            width: 2,
            height: 1,
            rgb: vec![0, 10, 20, 30, 40, 255],
        };
        assert_eq!(s.image(image.clone()), image);
    }

    #[test]
    fn state_noise_has_the_configured_spread_per_dimension() {
        let std = [0.5, 0.0, 0.1, 0.0, 0.02, 0.0];
        let mut s = sensor(std, 0.0);
        let n = 20_000;
        let mut sum = [0.0f64; 6];
        let mut sq = [0.0f64; 6];
        for _ in 0..n {
            let y = s.state([0.0; 6]);
            for d in 0..6 {
                sum[d] += y[d] as f64;
                sq[d] += (y[d] as f64).powi(2);
            }
        }
        for d in 0..6 {
            let mean = sum[d] / n as f64;
            let sd = (sq[d] / n as f64 - mean * mean).sqrt();
            assert!(mean.abs() < 0.02 + 0.05 * std[d], "dim {d}: mean {mean}");
            assert!(
                (sd - std[d]).abs() <= 0.05 * std[d] + 1e-9,
                "dim {d}: sd {sd} against {}",
                std[d]
            );
        }
    }

    #[test]
    fn pixel_noise_stays_in_range() {
        let mut s = sensor([0.0; 6], 40.0);
        let image = Image {
            width: 64,
            height: 64,
            rgb: vec![250; 64 * 64 * 3],
        };
        let noisy = s.image(image.clone());
        assert_ne!(noisy, image);
        let mean = noisy.rgb.iter().map(|&p| p as f64).sum::<f64>() / noisy.rgb.len() as f64;
        // Clamped at 255 from above, so the mean drops below 250 but stays near it.
        assert!((225.0..250.0).contains(&mean), "{mean}");
    }
}
