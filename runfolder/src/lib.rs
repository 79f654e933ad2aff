//! A run folder's layout, in one place and without libtorch: the names of its files, whether it holds a checkpoint,
//! its CSV tables read back ([`Table`]), the supervisor's record ([`status::Status`]) and the learner's exit codes
//! ([`exit`]). The learner writes the folder (`cabc_outputs::RunDir`, whose names are these); `cabc supervise`,
//! `cabc chaos`, `cabc campaign` and the analysis read it through this crate, so none of them links libtorch for it.

pub mod audit;
pub mod journal;
pub mod status;
mod table;

pub use status::Status;
pub use table::Table;

use std::path::Path;

/// The run's resolved configuration.
pub const CONFIG: &str = "config.toml";
/// A run's track from a file, copied beside its configuration: `track.csv` or `track.toml`.
pub const TRACK: &str = "track";
/// One row per epoch (the learner's metrics).
pub const METRICS: &str = "metrics.csv";
/// One row per evaluated policy version.
pub const EVALS: &str = "evals.csv";
/// The run's summary, written when it ends (or is interrupted).
pub const SUMMARY: &str = "summary.json";
/// The plots' folder.
pub const PLOTS: &str = "plots";
/// The checkpoint that `--resume` continues.
pub const CHECKPOINT: &str = "checkpoint";
/// The previous checkpoint, while a new one is swapped in (a crash between the renames leaves only this one).
pub const CHECKPOINT_OLD: &str = "checkpoint.old";

/// Whether a run folder holds a checkpoint that `--resume` continues (`checkpoint/`, or `checkpoint.old/` while a
/// new one was being swapped in).
pub fn has_checkpoint(run_dir: &Path) -> bool {
    run_dir.join(CHECKPOINT).exists() || run_dir.join(CHECKPOINT_OLD).exists()
}

/// The learner's exit statuses that mean something to its supervisor.
pub mod exit {
    /// No actor was alive for `bus.no_actor_timeout_s`: the learner ended with its checkpoint, and its supervisor
    /// ends the run (a restart would wait for actors again).
    pub const NO_ACTORS: i32 = 3;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_checkpoint_is_either_folder() {
        let dir = tempfile::tempdir().unwrap();
        assert!(!has_checkpoint(dir.path()));
        std::fs::create_dir(dir.path().join(CHECKPOINT_OLD)).unwrap();
        assert!(has_checkpoint(dir.path()));
        std::fs::remove_dir(dir.path().join(CHECKPOINT_OLD)).unwrap();
        std::fs::create_dir(dir.path().join(CHECKPOINT)).unwrap();
        assert!(has_checkpoint(dir.path()));
    }
}
