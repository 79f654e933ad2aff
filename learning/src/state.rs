//! The learner's bookkeeping besides networks and replay, saved as `state.json` in each checkpoint (with the
//! trainer's and the replay's files, through the learner's checkpointer, [`crate::checkpointer`]).

use crate::checkpoint::{CheckpointError, CheckpointWriter, Parts};
use crate::evaluations::Evaluations;
use crate::record::Record;
use crate::sink::History;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The checkpoint's folder in the run folder.
pub const CHECKPOINT: &str = "checkpoint";
/// The learner state's file in the checkpoint.
const STATE: &str = "state.json";

/// A state that could not be saved or read.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

/// The learner's bookkeeping besides networks and replay (saved with each checkpoint).
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct LearnerState {
    /// The next epoch to run.
    pub next_epoch: u64,
    /// Every epoch's record (`metrics.csv`'s rows). Old checkpoints' rows (objects of named fields) load too
    /// ([`crate::record::rows`]).
    #[serde(deserialize_with = "crate::record::rows")]
    pub rows: Vec<Record>,
    /// The evaluations (saved as the fields `evals`, `successes` and `early_stop`).
    #[serde(flatten)]
    pub evaluations: Evaluations,
    pub ledger: crate::ledger::Ledger,
    /// Lap times of the expert seen in the data (complete laps collected with beta = 1).
    pub expert_lap_times: Vec<f64>,
    pub stopped: Option<String>,
    /// What the policy's vision trunk started from ([`crate::train::Trainer::init_trunk`]).
    #[serde(default)]
    pub trunk_init: Option<String>,
    /// Segments refused before the ledger saw them, since the run started (the `segments_not_stored` column).
    /// Checkpoints written before it was saved start it at 0.
    #[serde(default)]
    pub segments_not_stored: u64,
}

impl LearnerState {
    /// What the run wrote so far, as the sinks are opened with it.
    pub fn history(&self) -> History {
        History {
            rows: self.rows.clone(),
            evals: self.evaluations.evals.clone(),
            last_eval: self.evaluations.last().cloned(),
            expert_lap_times: self.expert_lap_times.clone(),
        }
    }

    /// This state as a checkpoint's part: `state.json`.
    pub fn part(&self) -> Result<(&'static str, Vec<u8>), StateError> {
        let json = serde_json::to_vec(self).map_err(|e| StateError::Format {
            path: PathBuf::from(STATE),
            message: e.to_string(),
        })?;
        Ok((STATE, json))
    }

    /// Writes a checkpoint into `dir` atomically: `files` (the trainer's, the replay's) and this state as
    /// `state.json`.
    pub fn save<N: AsRef<str>>(
        &self,
        dir: &Path,
        files: impl IntoIterator<Item = (N, Vec<u8>)>,
    ) -> Result<(), StateError> {
        let (name, json) = self.part()?;
        CheckpointWriter::new(dir)
            .files(files)
            .file(name, json)
            .commit()?;
        Ok(())
    }

    /// The state of a checkpoint.
    pub fn load(checkpoint: &dyn Parts) -> Result<Self, StateError> {
        let bytes = checkpoint.read(STATE)?;
        serde_json::from_slice(&bytes).map_err(|e| StateError::Format {
            path: checkpoint.path().join(STATE),
            message: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::Checkpoint;

    #[test]
    fn checkpoint_round_trip_and_fresh_start() {
        let dir = tempfile::tempdir().unwrap();
        let ck = dir.path().join(CHECKPOINT);
        assert!(!Checkpoint::exists(&ck));
        let mut state = LearnerState {
            next_epoch: 3,
            ..Default::default()
        };
        state.save(&ck, [("x", b"1".to_vec())]).unwrap();
        state.next_epoch = 4;
        state.rows.push(Record::new(3));
        state.save(&ck, [("x", b"2".to_vec())]).unwrap();
        let opened = Checkpoint::open(&ck).unwrap();
        let loaded = LearnerState::load(&opened).unwrap();
        assert_eq!((loaded.next_epoch, loaded.rows), (4, vec![Record::new(3)]));
        assert_eq!(opened.read("x").unwrap(), b"2");
        assert!(ck.join("state.json").exists());
        // A failing commit leaves the last checkpoint untouched.
        assert!(state.save(&ck, [("a/b", vec![])]).is_err());
        assert_eq!(std::fs::read(ck.join("x")).unwrap(), b"2");
        Checkpoint::remove(&ck).unwrap();
        assert!(!Checkpoint::exists(&ck));
    }

    /// The count of segments not stored goes with the checkpoint; a checkpoint written before it did loads with 0.
    #[test]
    fn segments_not_stored_is_saved_and_defaults_to_zero() {
        let dir = tempfile::tempdir().unwrap();
        let ck = dir.path().join(CHECKPOINT);
        let state = LearnerState {
            segments_not_stored: 3,
            ..Default::default()
        };
        state.save(&ck, [("x", vec![])]).unwrap();
        let loaded = LearnerState::load(&Checkpoint::open(&ck).unwrap()).unwrap();
        assert_eq!(loaded.segments_not_stored, 3);
        let mut json: serde_json::Value = serde_json::to_value(&state).unwrap();
        json.as_object_mut().unwrap().remove("segments_not_stored");
        let old: LearnerState = serde_json::from_value(json).unwrap();
        assert_eq!(old.segments_not_stored, 0);
    }
}
