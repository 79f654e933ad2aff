//! p_hat as a shield in collection (`collection.shield`, issue 45): the way SafeDAgger, EnsembleDAgger and
//! ThriftyDAgger use a learned safety signal. Once the critic has trained, each policy update carries f_hat and p_hat
//! ([`ShieldNets`]); a step whose applied action u (the mixture's, with its noise, clipped as the plant gets it) has
//! p_hat(f_hat(x, u)) below the threshold is driven by the expert's action instead, when the expert answered. The
//! stored label is the expert's either way; the stored action is the one applied.

use cabc_models::{Critic, Dynamics, ModelError, Network};
use cabc_proto::config::{MlpSize, RunConfig};
use cabc_proto::messages::{ShieldNets, ACTION_DIM, STATE_DIM};
use tch::{Device, Kind, Tensor};

/// The shield's settings from the run's configuration: the threshold and the networks' sizes.
#[derive(Clone, Copy, Debug)]
pub struct ShieldConfig {
    /// `collection.shield`; 0: no shield.
    pub threshold: f64,
    dynamics: MlpSize,
    critic: MlpSize,
}

impl ShieldConfig {
    pub fn of(config: &RunConfig) -> Self {
        ShieldConfig {
            threshold: config.collection.shield,
            dynamics: config.networks.dynamics,
            critic: config.networks.critic,
        }
    }

    /// The shield of a policy update: None when the run has none, or the update carries no networks (before the
    /// critic's first fit); an error for networks of other sizes or malformed weights.
    pub fn shield(&self, nets: Option<&ShieldNets>) -> Result<Option<Shield>, ModelError> {
        let Some(nets) = nets.filter(|_| self.threshold > 0.0) else {
            return Ok(None);
        };
        let mut dynamics = Dynamics::new(self.dynamics, Device::Cpu, 0);
        dynamics.load_bytes(&nets.dynamics)?;
        let mut critic = Critic::new(STATE_DIM, self.critic, Device::Cpu, 0);
        critic.load_bytes(&nets.critic)?;
        Ok(Some(Shield {
            dynamics,
            critic,
            threshold: self.threshold,
        }))
    }
}

/// f_hat and p_hat of one policy version, and the threshold.
pub struct Shield {
    dynamics: Dynamics,
    critic: Critic,
    threshold: f64,
}

impl Shield {
    /// p_hat(f_hat(x, u)) for each state and action.
    pub fn safety(&self, states: &[[f32; STATE_DIM]], actions: &[[f64; ACTION_DIM]]) -> Vec<f32> {
        if states.is_empty() {
            return Vec::new();
        }
        let x = Tensor::from_slice(states.as_flattened()).view([-1, STATE_DIM as i64]);
        let u: Vec<f32> = actions.iter().flatten().map(|&v| v as f32).collect();
        let u = Tensor::from_slice(&u).view([-1, ACTION_DIM as i64]);
        let p = tch::no_grad(|| self.critic.probability(&self.dynamics.forward(&x, &u)));
        Vec::<f32>::try_from(p.to_kind(Kind::Float)).expect("p_hat: a [N] float tensor")
    }

    /// Whether each action is one the expert should take over: p_hat(f_hat(x, u)) below the threshold.
    pub fn overrules(
        &self,
        states: &[[f32; STATE_DIM]],
        actions: &[[f64; ACTION_DIM]],
    ) -> Vec<bool> {
        self.safety(states, actions)
            .into_iter()
            .map(|p| f64::from(p) < self.threshold)
            .collect()
    }
}
