//! The run folder `runs/<run>/`: configuration, checkpoints, `metrics.csv`, `evals.csv`, plots, `summary.json`.
//!
//! The checkpoint (`checkpoint/`) is written by the one writer, [`crate::checkpoint`], which also says how a crash
//! mid-write leaves the previous checkpoint intact.

use crate::checkpoint::{Checkpoint, CheckpointError, CheckpointWriter};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::EvalReport;
use cabc_proto::stats::mean_std;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Errors of the run folder.
#[derive(Debug, thiserror::Error)]
pub enum RunDirError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RunDirError + '_ {
    move |source| RunDirError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// One row of `metrics.csv` (per epoch).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct EpochRow {
    pub epoch: u64,
    pub beta: f64,
    pub steps_collected: u64,
    /// Steps the actors said they published for this epoch (their markers).
    pub steps_published: u64,
    pub segments: u64,
    /// Steps the actors took in the epoch (their markers): the epoch's budget when every actor finished its share.
    pub steps_taken: u64,
    /// Steps the actors had taken but still staged at the end of the epoch (unfinished laps carried on).
    pub steps_staged: u64,
    /// Steps stored this epoch in incomplete segments (cut by the budget: dynamics only, never labelled).
    pub incomplete_steps: u64,
    pub d_plus: usize,
    pub d_uncertain: usize,
    /// D-: what the last auto-labelling left in D? (the critic's negatives), held until the next labelling.
    pub d_minus: usize,
    pub dynamics_only: usize,
    pub autolabel_removed: usize,
    pub rho: f64,
    pub imitation_loss: f64,
    pub safety_loss: f64,
    /// None in epochs where the network did not train.
    pub dynamics_loss: Option<f64>,
    pub critic_loss: Option<f64>,
    pub critic_accuracy: Option<f64>,
    /// The critic's training set, |D+| + |D-|, in epochs where it trained.
    pub critic_points: Option<usize>,
    /// Of these, the positives (D+) and the negatives (D-, or all of D? with `critic_negatives = "uncertain"`).
    pub critic_positives: Option<usize>,
    pub critic_negatives: Option<usize>,
    /// The steps that entered D? this epoch, by origin ([`crate::provenance::Provenance`]): truncating steps,
    /// off-track spawns, the staged steps of episodes the expert ended, the rest of failed laps, and the expert's
    /// failures.
    pub uncertain_truncating: u64,
    pub uncertain_spawn: u64,
    pub uncertain_patience: u64,
    pub uncertain_failed_lap: u64,
    pub expert_failures: u64,
    pub collect_s: f64,
    pub train_s: f64,
    pub epoch_s: f64,
    pub closed_by_timeout: bool,
    pub eval_version: Option<u64>,
    pub eval_laps: Option<u32>,
}

const METRICS_HEADER: &str = "epoch,beta,steps_collected,steps_published,segments,steps_taken,steps_staged,incomplete_steps,incomplete_share,d_plus,d_uncertain,d_minus,dynamics_only,autolabel_removed,rho,imitation_loss,safety_loss,dynamics_loss,critic_loss,critic_accuracy,critic_points,collect_s,train_s,epoch_s,closed_by_timeout,eval_version,eval_laps,critic_positives,critic_negatives,uncertain_truncating,uncertain_spawn,uncertain_patience,uncertain_failed_lap,expert_failures";

impl EpochRow {
    /// Every column of the row that holds a number, by its `metrics.csv` name (a flag as 0 or 1; an empty cell, a
    /// network that did not train, left out): what TensorBoard shows of an epoch.
    pub fn scalars(&self) -> Vec<(&'static str, f32)> {
        METRICS_HEADER
            .split(',')
            .zip(
                self.csv()
                    .split(',')
                    .map(str::to_string)
                    .collect::<Vec<_>>(),
            )
            .filter_map(|(name, cell)| {
                let value = match cell.as_str() {
                    "true" => 1.0,
                    "false" => 0.0,
                    cell => cell.parse::<f32>().ok()?,
                };
                Some((name, value))
            })
            .collect()
    }

    fn csv(&self) -> String {
        let opt = |v: Option<u64>| v.map(|v| v.to_string()).unwrap_or_default();
        let optf = |v: Option<f64>| v.map(|v| format!("{v:.6}")).unwrap_or_default();
        format!(
            "{},{:.6},{},{},{},{},{},{},{:.4},{},{},{},{},{},{},{:.6},{:.6},{},{},{},{},{:.3},{:.3},{:.3},{},{},{},{},{},{},{},{},{},{}",
            self.epoch,
            self.beta,
            self.steps_collected,
            self.steps_published,
            self.segments,
            self.steps_taken,
            self.steps_staged,
            self.incomplete_steps,
            self.incomplete_steps as f64 / self.steps_collected.max(1) as f64,
            self.d_plus,
            self.d_uncertain,
            self.d_minus,
            self.dynamics_only,
            self.autolabel_removed,
            self.rho,
            self.imitation_loss,
            self.safety_loss,
            optf(self.dynamics_loss),
            optf(self.critic_loss),
            optf(self.critic_accuracy),
            opt(self.critic_points.map(|n| n as u64)),
            self.collect_s,
            self.train_s,
            self.epoch_s,
            self.closed_by_timeout,
            opt(self.eval_version),
            opt(self.eval_laps.map(u64::from)),
            opt(self.critic_positives.map(|n| n as u64)),
            opt(self.critic_negatives.map(|n| n as u64)),
            self.uncertain_truncating,
            self.uncertain_spawn,
            self.uncertain_patience,
            self.uncertain_failed_lap,
            self.expert_failures,
        )
    }
}

/// The learner's bookkeeping besides networks and replay (saved with each checkpoint).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct LearnerState {
    /// The next epoch to run.
    pub next_epoch: u64,
    pub rows: Vec<EpochRow>,
    pub evals: Vec<EvalSummary>,
    /// Evaluations that completed the wanted laps.
    pub successes: u32,
    pub ledger: crate::ledger::Ledger,
    /// Lap times of the expert seen in the data (complete laps collected with beta = 1).
    pub expert_lap_times: Vec<f64>,
    pub stopped: Option<String>,
    /// What the policy's vision trunk started from ([`crate::train::Trainer::init_trunk`]).
    #[serde(default)]
    pub trunk_init: Option<String>,
}

/// An evaluation, without its line.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalSummary {
    pub version: u64,
    pub laps: u32,
    pub lap_mean: Option<f64>,
    pub lap_std: Option<f64>,
    pub lap_min: Option<f64>,
    pub lap_max: Option<f64>,
    pub end_reason: String,
    pub steps: u64,
}

impl EvalSummary {
    /// The better of two evaluations: more laps, then a lower mean lap time (ties: the earlier one stays best).
    pub fn better_than(&self, other: &EvalSummary) -> bool {
        match self.laps.cmp(&other.laps) {
            std::cmp::Ordering::Greater => true,
            std::cmp::Ordering::Less => false,
            std::cmp::Ordering::Equal => match (self.lap_mean, other.lap_mean) {
                (Some(a), Some(b)) => a < b,
                (Some(_), None) => true,
                _ => false,
            },
        }
    }

    pub fn of(report: &EvalReport) -> Self {
        let ms = mean_std(&report.lap_times);
        let fold = |f: fn(f64, f64) -> f64| report.lap_times.iter().copied().reduce(f);
        EvalSummary {
            version: report.version,
            laps: report.laps,
            lap_mean: ms.map(|m| m.0),
            lap_std: ms.map(|m| m.1),
            lap_min: fold(f64::min),
            lap_max: fold(f64::max),
            end_reason: report.end_reason.to_string(),
            steps: report.steps,
        }
    }
}

/// The learner state's file in the checkpoint.
const STATE: &str = "state.json";

/// A run folder.
#[derive(Clone, Debug)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// `runs_dir/<name>`, created with `logs/` and `plots/`.
    pub fn create(root: impl Into<PathBuf>) -> Result<Self, RunDirError> {
        let root = root.into();
        for sub in ["logs", "plots"] {
            let p = root.join(sub);
            std::fs::create_dir_all(&p).map_err(io(&p))?;
        }
        Ok(RunDir { root })
    }

    /// The run folder of `config` (`<runs_dir>/<run name>`, or `dir`), created, with `config.toml` written into it.
    /// With `fresh`, its checkpoint is discarded.
    pub fn prepare(
        config: &RunConfig,
        dir: Option<PathBuf>,
        fresh: bool,
    ) -> Result<Self, RunDirError> {
        let dir = dir.unwrap_or_else(|| PathBuf::from(&config.run.runs_dir).join(&config.run.name));
        let run_dir = RunDir::create(dir)?;
        if fresh {
            run_dir.remove_checkpoint()?;
        }
        run_dir.write_config(config)?;
        Ok(run_dir)
    }

    pub fn path(&self) -> &Path {
        &self.root
    }

    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.toml")
    }

    pub fn checkpoint(&self) -> PathBuf {
        self.root.join("checkpoint")
    }

    pub fn plots(&self) -> PathBuf {
        self.root.join("plots")
    }

    pub fn write_config(&self, config: &RunConfig) -> Result<(), RunDirError> {
        let path = self.config_path();
        std::fs::write(&path, config.to_toml()).map_err(io(&path))
    }

    /// Whether the run has a checkpoint (`checkpoint/`, or `checkpoint.old/` after a crash mid-commit).
    pub fn has_checkpoint(&self) -> bool {
        Checkpoint::exists(&self.checkpoint())
    }

    /// The checkpoint to resume from.
    pub fn open_checkpoint(&self) -> Result<Checkpoint, RunDirError> {
        Ok(Checkpoint::open(&self.checkpoint())?)
    }

    /// Removes the checkpoint and what a commit leaves beside it (`--fresh`).
    pub fn remove_checkpoint(&self) -> Result<(), RunDirError> {
        Ok(Checkpoint::remove(&self.checkpoint())?)
    }

    /// Writes a checkpoint atomically: `files` (the trainer's, the replay's) and the learner state as
    /// `state.json`.
    pub fn save_checkpoint<N: AsRef<str>>(
        &self,
        state: &LearnerState,
        files: impl IntoIterator<Item = (N, Vec<u8>)>,
    ) -> Result<(), RunDirError> {
        let json = serde_json::to_vec(state).map_err(|e| RunDirError::Format {
            path: self.checkpoint().join(STATE),
            message: e.to_string(),
        })?;
        CheckpointWriter::new(self.checkpoint())
            .files(files)
            .file(STATE, json)
            .commit()?;
        Ok(())
    }

    /// Reads the learner state of the checkpoint.
    pub fn load_state(&self) -> Result<LearnerState, RunDirError> {
        let checkpoint = self.open_checkpoint()?;
        let bytes = checkpoint.read(STATE)?;
        serde_json::from_slice(&bytes).map_err(|e| RunDirError::Format {
            path: checkpoint.path().join(STATE),
            message: e.to_string(),
        })
    }

    /// Rewrites `metrics.csv` and `evals.csv` from the state (so a resumed run's files stay consistent).
    pub fn write_tables(&self, state: &LearnerState) -> Result<(), RunDirError> {
        let path = self.root.join("metrics.csv");
        let mut text = String::from(METRICS_HEADER);
        text.push('\n');
        for row in &state.rows {
            text.push_str(&row.csv());
            text.push('\n');
        }
        write_atomic(&path, text.as_bytes())?;
        let path = self.root.join("evals.csv");
        let mut text =
            String::from("version,laps,lap_mean,lap_std,lap_min,lap_max,end_reason,steps\n");
        let opt = |v: Option<f64>| v.map(|v| format!("{v:.3}")).unwrap_or_default();
        for e in &state.evals {
            text.push_str(&format!(
                "{},{},{},{},{},{},{},{}\n",
                e.version,
                e.laps,
                opt(e.lap_mean),
                opt(e.lap_std),
                opt(e.lap_min),
                opt(e.lap_max),
                e.end_reason,
                e.steps
            ));
        }
        write_atomic(&path, text.as_bytes())
    }

    pub fn write_summary(&self, summary: &serde_json::Value) -> Result<(), RunDirError> {
        let path = self.root.join("summary.json");
        let text = serde_json::to_string_pretty(summary).unwrap_or_else(|_| summary.to_string());
        write_atomic(&path, text.as_bytes())
    }

    /// Writes policy weights beside the checkpoint (`best-policy.safetensors` on early stop).
    pub fn write_file(&self, name: &str, bytes: &[u8]) -> Result<(), RunDirError> {
        write_atomic(&self.root.join(name), bytes)
    }
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RunDirError> {
    let tmp = path.with_extension("tmp");
    let mut f = std::fs::File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(bytes).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::EndReason;

    #[test]
    fn checkpoint_round_trip_and_fresh_start() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path().join("r")).unwrap();
        assert!(!run.has_checkpoint());
        let mut state = LearnerState {
            next_epoch: 3,
            ..Default::default()
        };
        run.save_checkpoint(&state, [("x", b"1".to_vec())]).unwrap();
        state.next_epoch = 4;
        run.save_checkpoint(&state, [("x", b"2".to_vec())]).unwrap();
        assert_eq!(run.load_state().unwrap().next_epoch, 4);
        assert_eq!(run.open_checkpoint().unwrap().read("x").unwrap(), b"2");
        assert!(run.checkpoint().join("state.json").exists());
        // A failing commit leaves the last checkpoint untouched.
        assert!(run.save_checkpoint(&state, [("a/b", vec![])]).is_err());
        assert_eq!(std::fs::read(run.checkpoint().join("x")).unwrap(), b"2");
        run.remove_checkpoint().unwrap();
        assert!(!run.has_checkpoint());
    }

    #[test]
    fn tables_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path()).unwrap();
        let report = EvalReport {
            actor: "e".into(),
            version: 2,
            laps: 2,
            lap_times: vec![5.0, 6.0],
            end_reason: EndReason::Spin,
            steps: 130,
            line: vec![],
        };
        let state = LearnerState {
            rows: vec![EpochRow {
                epoch: 0,
                ..Default::default()
            }],
            evals: vec![EvalSummary::of(&report)],
            ..Default::default()
        };
        run.write_tables(&state).unwrap();
        let metrics = std::fs::read_to_string(dir.path().join("metrics.csv")).unwrap();
        assert_eq!(metrics.lines().count(), 2);
        let header_cols = metrics.lines().next().unwrap().split(',').count();
        assert_eq!(
            metrics.lines().nth(1).unwrap().split(',').count(),
            header_cols
        );
        let evals = std::fs::read_to_string(dir.path().join("evals.csv")).unwrap();
        assert!(
            evals.contains("2,2,5.500,0.500,5.000,6.000,spin,130"),
            "{evals}"
        );
    }
}
