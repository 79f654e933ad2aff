//! What the trainer hands the checkpoint writer, and reads back: the three networks (safetensors) and
//! `trainer.json` (learning-rate schedules, epoch counter, RNG). Adam's moments are not kept (tch does not expose
//! them), so they restart on resume.

use super::{TrainError, Trainer};
use crate::checkpoint::Checkpoint;
use cabc_models::Network;
use cabc_proto::config::RunConfig;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

const POLICY: &str = "policy.safetensors";
const DYNAMICS: &str = "dynamics.safetensors";
const CRITIC: &str = "critic.safetensors";
const STATE: &str = "trainer.json";

/// `trainer.json`.
#[derive(Serialize, Deserialize)]
struct TrainerState {
    epochs_trained: u64,
    critic_trained: bool,
    /// Fit calls of the policy, dynamics and critic optimisers, in that order.
    fits: [u64; 3],
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    architectures: [String; 3],
}

impl Trainer {
    /// The trainer's files of a checkpoint, for [`CheckpointWriter::files`](crate::checkpoint::CheckpointWriter::files).
    pub fn to_checkpoint(&self) -> Vec<(&'static str, Vec<u8>)> {
        let state = TrainerState {
            epochs_trained: self.epochs_trained,
            critic_trained: self.critic_trained,
            fits: [
                self.policy_opt.fits,
                self.dynamics_opt.fits,
                self.critic_opt.fits,
            ],
            rng_seed: self.rng.get_seed(),
            rng_stream: self.rng.get_stream(),
            rng_word_pos: self.rng.get_word_pos(),
            architectures: [
                self.policy.architecture(),
                self.dynamics.architecture(),
                self.critic.architecture(),
            ],
        };
        vec![
            (POLICY, self.policy.to_bytes()),
            (DYNAMICS, self.dynamics.to_bytes()),
            (CRITIC, self.critic.to_bytes()),
            (
                STATE,
                serde_json::to_vec_pretty(&state).expect("serialises"),
            ),
        ]
    }

    /// Restores what [`Trainer::to_checkpoint`] wrote into this trainer (built from the same configuration; weights
    /// of another architecture are refused).
    pub fn load(&mut self, checkpoint: &Checkpoint) -> Result<(), TrainError> {
        let state: TrainerState =
            serde_json::from_slice(&checkpoint.read(STATE)?).map_err(|e| TrainError::State {
                path: checkpoint.path().join(STATE).display().to_string(),
                message: e.to_string(),
            })?;
        self.policy.load_bytes(&checkpoint.read(POLICY)?)?;
        self.dynamics.load_bytes(&checkpoint.read(DYNAMICS)?)?;
        self.critic.load_bytes(&checkpoint.read(CRITIC)?)?;
        self.epochs_trained = state.epochs_trained;
        self.critic_trained = state.critic_trained;
        [
            self.policy_opt.fits,
            self.dynamics_opt.fits,
            self.critic_opt.fits,
        ] = state.fits;
        let mut rng = ChaCha8Rng::from_seed(state.rng_seed);
        rng.set_stream(state.rng_stream);
        rng.set_word_pos(state.rng_word_pos);
        self.rng = rng;
        Ok(())
    }

    /// A trainer from `config` on `training.device`, restored from `checkpoint`.
    pub fn resume(config: &RunConfig, checkpoint: &Checkpoint) -> Result<Self, TrainError> {
        let mut t = Trainer::new(config)?;
        t.load(checkpoint)?;
        Ok(t)
    }
}
