//! What the trainer hands the checkpoint writer, and reads back: the three networks (safetensors), their Adam
//! states (moments and step counts, `<network>.adam.safetensors`, [`Adam::to_bytes`](super::adam::Adam::to_bytes))
//! and `trainer.json` (learning-rate schedules, epoch counter, RNG). A resumed run continues bit for bit as the
//! uninterrupted one would have on the same device. A checkpoint without the Adam states (written before they were
//! kept) still loads, with fresh moments and a warning.

use super::fit::Opt;
use super::{Standardiser, TrainError, Trainer};
use crate::checkpoint::{CheckpointError, Parts};
use cabc_models::{Network, Policy};
use cabc_proto::config::RunConfig;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

const POLICY: &str = "policy.safetensors";
const DYNAMICS: &str = "dynamics.safetensors";
const CRITIC: &str = "critic.safetensors";
const STATE: &str = "trainer.json";
const POLICY_ADAM: &str = "policy.adam.safetensors";
const DYNAMICS_ADAM: &str = "dynamics.adam.safetensors";
const CRITIC_ADAM: &str = "critic.adam.safetensors";
/// The policy's moving average (`training.policy_ema`), once it exists.
const POLICY_EMA: &str = "policy.ema.safetensors";

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
    /// The state's standardisation (`training.standardise`); absent in checkpoints from before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    standardiser: Option<Standardiser>,
    /// The critic's last held-out balanced accuracy (`training.safety_gate`); absent before its first measure.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    heldout_balanced: Option<f64>,
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
            standardiser: self.standardiser.clone(),
            heldout_balanced: self.heldout_balanced,
        };
        let ema = self.ema.as_ref().map(|ema| (POLICY_EMA, ema.to_bytes()));
        let mut files = vec![
            (POLICY, self.policy.to_bytes()),
            (DYNAMICS, self.dynamics.to_bytes()),
            (CRITIC, self.critic.to_bytes()),
            (POLICY_ADAM, self.policy_opt.adam.to_bytes()),
            (DYNAMICS_ADAM, self.dynamics_opt.adam.to_bytes()),
            (CRITIC_ADAM, self.critic_opt.adam.to_bytes()),
            (
                STATE,
                serde_json::to_vec_pretty(&state).expect("serialises"),
            ),
        ];
        files.extend(ema);
        files
    }

    /// Restores what [`Trainer::to_checkpoint`] wrote into this trainer (built from the same configuration; weights
    /// of another architecture are refused).
    pub fn load(&mut self, checkpoint: &dyn Parts) -> Result<(), TrainError> {
        let state: TrainerState =
            serde_json::from_slice(&checkpoint.read(STATE)?).map_err(|e| TrainError::State {
                path: checkpoint.path().join(STATE).display().to_string(),
                message: e.to_string(),
            })?;
        self.policy.load_bytes(&checkpoint.read(POLICY)?)?;
        self.dynamics.load_bytes(&checkpoint.read(DYNAMICS)?)?;
        self.critic.load_bytes(&checkpoint.read(CRITIC)?)?;
        load_adam(&mut self.policy_opt, checkpoint, POLICY_ADAM)?;
        load_adam(&mut self.dynamics_opt, checkpoint, DYNAMICS_ADAM)?;
        load_adam(&mut self.critic_opt, checkpoint, CRITIC_ADAM)?;
        self.ema = match checkpoint.read(POLICY_EMA) {
            Ok(bytes) => {
                let mut ema = Policy::new(self.policy.arch(), self.device, 0);
                ema.load_bytes(&bytes)?;
                Some(ema)
            }
            Err(CheckpointError::Io { source, .. })
                if source.kind() == std::io::ErrorKind::NotFound =>
            {
                None
            }
            Err(e) => return Err(e.into()),
        };
        self.standardiser = state.standardiser;
        self.heldout_balanced = state.heldout_balanced;
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
    pub fn resume(config: &RunConfig, checkpoint: &dyn Parts) -> Result<Self, TrainError> {
        let mut t = Trainer::new(config)?;
        t.load(checkpoint)?;
        Ok(t)
    }
}

/// Restores one optimiser's Adam state from `name`; without that file (an older checkpoint) the moments restart.
fn load_adam(opt: &mut Opt, checkpoint: &dyn Parts, name: &str) -> Result<(), TrainError> {
    match checkpoint.read(name) {
        Ok(bytes) => opt
            .adam
            .load_bytes(&bytes)
            .map_err(|message| TrainError::State {
                path: checkpoint.path().join(name).display().to_string(),
                message,
            }),
        Err(CheckpointError::Io { source, .. })
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            tracing::warn!(
                "{}: no {name} (a checkpoint from before the optimiser states were kept): Adam's moments restart",
                checkpoint.path().display()
            );
            opt.adam.reset();
            Ok(())
        }
        Err(e) => Err(e.into()),
    }
}
