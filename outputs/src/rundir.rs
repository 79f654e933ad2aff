//! The run folder `runs/<run>/`: configuration, checkpoints, `metrics.csv`, `evals.csv`, plots, `summary.json`, the
//! policies it keeps and their videos.
//!
//! The names of its files are [`RunDir`]'s ([`RunDir::CONFIG`], [`RunDir::policy_file`], ...): the learner writes them
//! through a `RunDir`, and every reader of a run folder (a finished run, or one that another process holds) joins
//! them to the folder's path.
//!
//! The checkpoint (`checkpoint/`) is the learner's ([`cabc_learning::state::LearnerState::save`]), written by the one writer,
//! [`cabc_learning::checkpoint`], which also says how a crash mid-write leaves the previous checkpoint intact.
//!
//! One run at a time in a folder: a [`RunDir`] holds an exclusive lock on `<run>/lock` (the process's id written
//! in it) for as long as it lives, so a second launch of the same run (a second lane of a one-lane campaign, a
//! second `deploy/run-local.sh`) stops at once with [`RunDirError::InUse`], before it rewrites `config.toml`,
//! discards the checkpoint or starts an actor whose trajectories would go to the first run's learner. The lock is
//! the operating system's (`flock` on Unix, opened close-on-exec so that no child keeps it), so it goes with the
//! process that held it, a crash included.

use cabc_learning::checkpoint::{Checkpoint, CheckpointError};
use cabc_learning::evaluations::EvalSummary;
use cabc_learning::record::{Record, TableError};
use cabc_learning::state::CHECKPOINT;
use cabc_learning::summary::Summary;
use cabc_models::Policy;
use cabc_proto::config::RunConfig;
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

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
    #[error("{path}: {source}")]
    Policy {
        path: PathBuf,
        source: cabc_models::ModelError,
    },
    #[error(
        "{path} is in use by another run (process {holder} holds {path}/lock): one run at a time in a run folder"
    )]
    InUse { path: PathBuf, holder: String },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RunDirError + '_ {
    move |source| RunDirError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The two policies a run keeps: the best evaluated version's (most laps, then the lowest mean lap time) and the
/// last one's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeptPolicy {
    Best,
    Final,
}

impl KeptPolicy {
    pub const ALL: [KeptPolicy; 2] = [KeptPolicy::Best, KeptPolicy::Final];

    /// `best` or `final`: how the command line names it, and the start of its files' names.
    pub fn as_str(self) -> &'static str {
        match self {
            KeptPolicy::Best => "best",
            KeptPolicy::Final => "final",
        }
    }

    /// The kept policy named `name` ([`KeptPolicy::as_str`]), if any.
    pub fn named(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|kept| kept.as_str() == name)
    }
}

/// A run folder, locked for this process while the value (or a clone of it) lives.
#[derive(Clone, Debug)]
pub struct RunDir {
    root: PathBuf,
    /// `<run>/lock`, locked exclusively; the lock goes when the last clone is dropped.
    _lock: Arc<File>,
}

/// The run folder's files, by name (relative to the folder).
impl RunDir {
    /// The run's configuration, written when it starts ([`RunDir::prepare`]).
    pub const CONFIG: &'static str = cabc_runfolder::CONFIG;
    pub const TRACK: &'static str = cabc_runfolder::TRACK;
    /// A row per epoch ([`RunDir::write_tables`]).
    pub const METRICS: &'static str = cabc_runfolder::METRICS;
    /// A row per evaluation ([`EVALS_HEADER`], [`parse_evals`]).
    pub const EVALS: &'static str = cabc_runfolder::EVALS;
    /// The run's [`Summary`], written when it ends (or is interrupted).
    pub const SUMMARY: &'static str = cabc_runfolder::SUMMARY;
    /// The plots and the evaluations' videos.
    pub const PLOTS: &'static str = cabc_runfolder::PLOTS;

    /// `best-policy.safetensors` or `final-policy.safetensors`: the kept policy's weights.
    pub fn policy_file(which: KeptPolicy) -> String {
        format!("{}-policy.safetensors", which.as_str())
    }

    /// `best-policy.gif` or `final-policy.gif`: the kept policy's video (the learner draws the best one's, `cabc
    /// video` either).
    pub fn policy_video(which: KeptPolicy) -> String {
        format!("{}-policy.gif", which.as_str())
    }

    /// `plots/eval-v<version>.gif`: the video of an evaluation that completed its laps.
    pub fn eval_video(version: u64) -> PathBuf {
        Path::new(Self::PLOTS).join(format!("eval-v{version}.gif"))
    }

    /// The versions of the evaluations' videos in run folder `run` ([`RunDir::eval_video`]), in order.
    pub fn eval_videos(run: &Path) -> Vec<u64> {
        let mut versions: Vec<u64> = std::fs::read_dir(run.join(Self::PLOTS))
            .into_iter()
            .flatten()
            .filter_map(|entry| {
                let name = entry.ok()?.file_name().into_string().ok()?;
                name.strip_prefix("eval-v")?
                    .strip_suffix(".gif")?
                    .parse()
                    .ok()
            })
            .collect();
        versions.sort_unstable();
        versions
    }

    /// `runs_dir/<name>`, created with `logs/` and `plots/`, and locked: [`RunDirError::InUse`] when another
    /// [`RunDir`] of the same folder lives, in this process or another.
    pub fn create(root: impl Into<PathBuf>) -> Result<Self, RunDirError> {
        let root = root.into();
        for sub in ["logs", Self::PLOTS] {
            let p = root.join(sub);
            std::fs::create_dir_all(&p).map_err(io(&p))?;
        }
        let lock = lock(&root)?;
        Ok(RunDir {
            root,
            _lock: Arc::new(lock),
        })
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
        self.root.join(Self::CONFIG)
    }

    pub fn checkpoint(&self) -> PathBuf {
        self.root.join(CHECKPOINT)
    }

    pub fn plots(&self) -> PathBuf {
        self.root.join(Self::PLOTS)
    }

    /// `<run>/best-policy.safetensors` or `<run>/final-policy.safetensors`.
    pub fn policy_path(&self, which: KeptPolicy) -> PathBuf {
        self.root.join(Self::policy_file(which))
    }

    /// Writes `config.toml`; a track from a file (`sim.track`) is copied beside it as `track.csv` or `track.toml`
    /// and named so, so that the folder holds all that its run drives on (on every machine that reads it).
    pub fn write_config(&self, config: &RunConfig) -> Result<(), RunDirError> {
        let mut config = config.clone();
        if config.sim.track_is_file() {
            let from = PathBuf::from(&config.sim.track);
            let ext = if config.sim.track.ends_with(".csv") {
                "csv"
            } else {
                "toml"
            };
            let name = format!("{}.{ext}", Self::TRACK);
            let to = self.root.join(&name);
            let same = match (std::fs::canonicalize(&from), std::fs::canonicalize(&to)) {
                (Ok(a), Ok(b)) => a == b,
                _ => false,
            };
            if !same {
                std::fs::copy(&from, &to).map_err(io(&from))?;
            }
            config.sim.track = name;
        }
        let path = self.config_path();
        std::fs::write(&path, config.to_toml()).map_err(io(&path))
    }

    /// Whether the run has a checkpoint (`checkpoint/`, or `checkpoint.old/` after a crash mid-commit).
    pub fn has_checkpoint(&self) -> bool {
        Checkpoint::exists(&self.checkpoint())
    }

    /// Removes the checkpoint and what a commit leaves beside it (`--fresh`).
    pub fn remove_checkpoint(&self) -> Result<(), RunDirError> {
        Ok(Checkpoint::remove(&self.checkpoint())?)
    }

    /// Rewrites `metrics.csv` and `evals.csv` from every record and evaluation (so a resumed run's files stay
    /// consistent).
    pub fn write_tables(&self, rows: &[Record], evals: &[EvalSummary]) -> Result<(), RunDirError> {
        let path = self.root.join(Self::METRICS);
        write_atomic(&path, cabc_learning::record::table(rows).as_bytes())?;
        let path = self.root.join(Self::EVALS);
        // The early stop's episodes from random spawns get their columns once an evaluation drove some: a run
        // without `collection.early_stop_spawns` writes the table it always wrote.
        let spawns = evals.iter().any(|e| e.spawn_episodes > 0);
        let mut text = match spawns {
            true => format!("{EVALS_HEADER},{EVALS_SPAWN_COLUMNS}\n"),
            false => format!("{EVALS_HEADER}\n"),
        };
        let opt = |v: Option<f64>| v.map(|v| format!("{v:.3}")).unwrap_or_default();
        for e in evals {
            text.push_str(&format!(
                "{},{},{},{},{},{},{},{}",
                e.version,
                e.laps,
                opt(e.lap_mean),
                opt(e.lap_std),
                opt(e.lap_min),
                opt(e.lap_max),
                e.end_reason,
                e.steps,
            ));
            if spawns {
                text.push_str(&format!(",{},{}", e.spawn_episodes, e.spawn_crashes));
            }
            text.push('\n');
        }
        write_atomic(&path, text.as_bytes())
    }

    pub fn write_summary(&self, summary: &Summary) -> Result<(), RunDirError> {
        let path = self.root.join(Self::SUMMARY);
        let text = serde_json::to_string_pretty(summary).map_err(|e| RunDirError::Format {
            path: path.clone(),
            message: e.to_string(),
        })?;
        write_atomic(&path, text.as_bytes())
    }

    /// Writes a kept policy's weights ([`RunDir::policy_file`]) beside the checkpoint.
    pub fn write_policy(&self, which: KeptPolicy, bytes: &[u8]) -> Result<(), RunDirError> {
        write_atomic(&self.policy_path(which), bytes)
    }
}

/// A policy's weights from a safetensors file (a run's [`RunDir::policy_file`], or any of the run's architecture), on
/// the CPU.
pub fn load_policy(path: &Path) -> Result<Policy, RunDirError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    Policy::from_bytes(&bytes, tch::Device::Cpu).map_err(|source| RunDirError::Policy {
        path: path.to_path_buf(),
        source,
    })
}

/// `evals.csv`'s header: a row per evaluation ([`RunDir::write_tables`]), the fixed spawn's laps, lap times (3
/// decimals), end and steps.
pub const EVALS_HEADER: &str = "version,laps,lap_mean,lap_std,lap_min,lap_max,end_reason,steps";
/// `evals.csv`'s columns after [`EVALS_HEADER`] once an evaluation drove the early stop's episodes from random
/// spawns (`collection.early_stop_spawns`): how many, and how many of them did not complete their laps.
pub const EVALS_SPAWN_COLUMNS: &str = "spawn_episodes,spawn_crashes";

/// `evals.csv`'s text read back (the inverse of [`RunDir::write_tables`]'s, its lap times to 3 decimals): columns
/// by name, `version` and `laps` needed, an empty cell or a missing column of the others None (`steps`,
/// `spawn_episodes` and `spawn_crashes` 0, `end_reason` empty). Blank lines are skipped; a row of the wrong length or with a cell that is not a number is
/// refused with its line.
pub fn parse_evals(text: &str) -> Result<Vec<EvalSummary>, TableError> {
    let (header, rows) = cabc_learning::record::csv_rows(text)?;
    let column = |name: &str| header.iter().position(|h| *h == name);
    let needed = |name: &str| {
        column(name).ok_or_else(|| TableError {
            line: 1,
            message: format!("no {name} column in the header {:?}", header.join(",")),
        })
    };
    let (version, laps) = (needed("version")?, needed("laps")?);
    let mut evals = vec![];
    for (line, cells) in rows {
        let fail = |message: String| TableError { line, message };
        let cell = |name: &str| column(name).map_or("", |c| cells[c]);
        fn parsed<T: std::str::FromStr>(name: &str, text: &str) -> Result<Option<T>, String> {
            match text {
                "" => Ok(None),
                t => t
                    .parse()
                    .map(Some)
                    .map_err(|_| format!("{name}: {t:?} is not a number")),
            }
        }
        let real = |name: &str| parsed::<f64>(name, cell(name)).map_err(fail);
        let missing = |name: &str| fail(format!("no {name}"));
        evals.push(EvalSummary {
            version: parsed("version", cells[version])
                .map_err(fail)?
                .ok_or_else(|| missing("version"))?,
            laps: parsed("laps", cells[laps])
                .map_err(fail)?
                .ok_or_else(|| missing("laps"))?,
            lap_mean: real("lap_mean")?,
            lap_std: real("lap_std")?,
            lap_min: real("lap_min")?,
            lap_max: real("lap_max")?,
            end_reason: cell("end_reason").to_string(),
            steps: parsed("steps", cell("steps")).map_err(fail)?.unwrap_or(0),
            spawn_episodes: parsed("spawn_episodes", cell("spawn_episodes"))
                .map_err(fail)?
                .unwrap_or(0),
            spawn_crashes: parsed("spawn_crashes", cell("spawn_crashes"))
                .map_err(fail)?
                .unwrap_or(0),
        });
    }
    Ok(evals)
}

/// Takes `<root>/lock` exclusively and writes this process's id into it.
fn lock(root: &Path) -> Result<File, RunDirError> {
    let path = root.join("lock");
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(io(&path))?;
    if !try_lock_exclusive(&file).map_err(io(&path))? {
        // The holder's id, for the message: at most 32 bytes of it (a file on disk, so believed no further).
        let mut holder = String::new();
        let _ = (&file).take(32).read_to_string(&mut holder);
        let holder = holder.trim();
        return Err(RunDirError::InUse {
            path: root.to_path_buf(),
            holder: if holder.is_empty() {
                "unknown".into()
            } else {
                holder.into()
            },
        });
    }
    file.set_len(0).map_err(io(&path))?;
    file.rewind().map_err(io(&path))?;
    writeln!(file, "{}", std::process::id()).map_err(io(&path))?;
    Ok(file)
}

/// `flock(LOCK_EX | LOCK_NB)`: whether the lock was taken (false: another open file holds it). The workspace's
/// Rust (1.85) predates `File::try_lock`.
#[cfg(unix)]
fn try_lock_exclusive(file: &File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock takes a descriptor that `file` owns and keeps open for the call; no memory crosses.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

/// Elsewhere a run folder is not locked.
#[cfg(not(unix))]
fn try_lock_exclusive(_file: &File) -> std::io::Result<bool> {
    Ok(true)
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
    use cabc_proto::messages::{EndReason, EvalReport};

    #[test]
    fn a_track_from_a_file_is_copied_into_the_run_folder_and_read_from_there() {
        let dir = tempfile::tempdir().unwrap();
        let user = dir.path().join("mine.toml");
        let oval = include_str!("../../tracks/oval.toml");
        std::fs::write(&user, oval).unwrap();
        let config = RunConfig::default()
            .with_overrides(&[format!("sim.track={}", user.display())])
            .unwrap();
        let run = RunDir::create(dir.path().join("run")).unwrap();
        run.write_config(&config).unwrap();
        let copy = dir.path().join("run").join("track.toml");
        assert_eq!(std::fs::read_to_string(&copy).unwrap(), oval);
        // The folder's configuration names its own copy, read from the folder whatever the working directory.
        std::fs::remove_file(&user).unwrap();
        let read = RunConfig::load(&run.config_path().display().to_string()).unwrap();
        let copy = std::fs::canonicalize(copy).unwrap();
        assert_eq!(read.sim.track, copy.display().to_string());
        // Written again (a resumed run), the copy stays.
        run.write_config(&read).unwrap();
        assert_eq!(std::fs::read_to_string(&copy).unwrap(), oval);
        assert!(std::fs::read_to_string(run.config_path())
            .unwrap()
            .contains("track = \"track.toml\""));
        // A track file that is not there is an error naming it.
        let missing = RunConfig::default()
            .with_overrides(&["sim.track=/nonexistent/t.csv".into()])
            .unwrap();
        let e = run.write_config(&missing).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/t.csv"), "{e}");
    }

    #[test]
    fn a_run_folder_holds_one_run_at_a_time() {
        let dir = tempfile::tempdir().unwrap();
        let first = RunDir::create(dir.path()).unwrap();
        let held = std::fs::read_to_string(dir.path().join("lock")).unwrap();
        assert_eq!(held.trim(), std::process::id().to_string());
        // A second launch of the run stops before it touches the folder: no config written, no checkpoint removed.
        let config = RunConfig::load("smoke").unwrap();
        for second in [
            RunDir::create(dir.path()),
            RunDir::prepare(&config, Some(dir.path().to_path_buf()), true),
        ] {
            match second {
                Err(RunDirError::InUse { path, holder }) => {
                    assert_eq!(path, dir.path());
                    assert_eq!(holder, std::process::id().to_string());
                }
                other => panic!("a second run in the folder: {other:?}"),
            }
        }
        assert!(!dir.path().join("config.toml").exists());
        // A clone shares the lock; the folder is free once the last one is dropped.
        let clone = first.clone();
        drop(first);
        assert!(matches!(
            RunDir::create(dir.path()),
            Err(RunDirError::InUse { .. })
        ));
        drop(clone);
        let again = RunDir::create(dir.path()).unwrap();
        assert_eq!(again.path(), dir.path());
        // Another folder is another lock.
        let other = tempfile::tempdir().unwrap();
        RunDir::create(other.path()).unwrap();
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
            spawn_episodes: 0,
            spawn_crashes: 0,
        };
        run.write_tables(&[Record::new(0)], &[EvalSummary::of(&report)])
            .unwrap();
        let metrics = std::fs::read_to_string(dir.path().join("metrics.csv")).unwrap();
        assert_eq!(metrics.lines().count(), 2);
        let header_cols = metrics.lines().next().unwrap().split(',').count();
        assert_eq!(
            metrics.lines().nth(1).unwrap().split(',').count(),
            header_cols
        );
        let evals = std::fs::read_to_string(dir.path().join("evals.csv")).unwrap();
        assert!(
            evals.contains("2,2,5.500,0.500,5.000,6.000,spin,130\n"),
            "{evals}"
        );
    }

    /// evals.csv reads back into the summaries that wrote it (lap times to 3 decimals); a malformed one is refused
    /// with its line.
    #[test]
    fn evals_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path()).unwrap();
        let report = |version, lap_times: Vec<f64>, spawns: [u32; 2]| EvalReport {
            actor: "e".into(),
            version,
            laps: lap_times.len() as u32,
            lap_times,
            end_reason: EndReason::Spin,
            steps: 130,
            line: vec![],
            spawn_episodes: spawns[0],
            spawn_crashes: spawns[1],
        };
        // Without the early stop's episodes from random spawns, and with them (their columns at the end).
        for spawns in [[0, 0], [5, 2]] {
            let evals = [
                EvalSummary::of(&report(0, vec![], [0, 0])),
                EvalSummary::of(&report(3, vec![5.0, 6.0], spawns)),
            ];
            run.write_tables(&[Record::new(0)], &evals).unwrap();
            let text = std::fs::read_to_string(dir.path().join("evals.csv")).unwrap();
            let header = text.lines().next().unwrap();
            assert_eq!(
                header == format!("{EVALS_HEADER},{EVALS_SPAWN_COLUMNS}"),
                spawns[0] > 0,
                "{text}"
            );
            let back = parse_evals(&text).unwrap();
            assert_eq!(back.len(), 2);
            for (a, b) in back.iter().zip(&evals) {
                assert_eq!(
                    serde_json::to_value(a).unwrap(),
                    serde_json::to_value(b).unwrap()
                );
            }
        }
        // An older table without steps, lap extremes or random spawns.
        let old = parse_evals("version,laps,lap_mean\n4,1,5.2\n").unwrap();
        assert_eq!(
            (old[0].version, old[0].lap_mean, old[0].steps),
            (4, Some(5.2), 0)
        );
        assert_eq!((old[0].spawn_episodes, old[0].spawn_crashes), (0, 0));
        for (bad, line, what) in [
            ("", 1, "no header"),
            ("laps\n1\n", 1, "no version column"),
            ("version,laps\n1,2\n3\n", 3, "1 cells"),
            (
                "version,laps,lap_mean\n1,2,fast\n",
                2,
                "lap_mean: \"fast\" is not a number",
            ),
            ("version,laps\n1,\n", 2, "no laps"),
        ] {
            let e = parse_evals(bad).unwrap_err();
            assert_eq!(e.line, line, "{bad:?}: {e}");
            assert!(e.to_string().contains(what), "{bad:?}: {e}");
        }
    }
}
