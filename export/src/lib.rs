//! cabc-export: a run's data as a LeRobot v3 dataset, for Python (pyarrow, pandas, LeRobot); its command line is
//! `cabc export RUN --out DIR` (cabc-cli). It reads the run folder through cabc-learning's checkpoint and replay readers
//! and writes parquet (arrow) and PNG, so that the learning core depends on neither.
//!
//! ```text
//! DIR/data/chunk-000/file-000.parquet        one row per step the replay holds (a new file past 100 MB)
//! DIR/meta/info.json                          features (dtype, shape, names), fps = 10, counts, cabc's notes
//! DIR/meta/stats.json                         per feature: min, max, mean, std, count
//! DIR/meta/episodes/chunk-000/file-000.parquet   per episode: length, its rows, its data file, store, versions
//! DIR/meta/tasks.parquet                      the one task
//! ```
//!
//! A row: `observation.state` (the true state [v_long, v_tran, omega, s, x_tran, e_psi], f32, as the replay keeps
//! it), `observation.velocity` (its first three), `observation.image` (PNG, in D+ rows of a camera run: the replay
//! keeps no other images), `action` (the expert's label; in D? a failed expert's placeholder [0, 0] cannot be told
//! apart, the replay keeps no flag), `applied_action` (what the environment was given), `next.observation.state`,
//! `episode_index`, `frame_index`, `timestamp` (frame_index / fps), `index`, `task_index`, `policy_version` and
//! `store` (D+, D?, D- or dynamics-only). Episodes and policy versions are derived ([`lineage`]).
//!
//! Streaming: `replay.bin`'s arrays (64 bytes a step) are decoded whole, the images are read from the run's image
//! log one at a time, and rows go out in batches of at most 4,096 rows or 32 MB of PNG. Nothing in the run folder is
//! written, so a live run can be exported (its last committed checkpoint). The dataset is built in `DIR.partial` and
//! renamed to `DIR` when complete.

pub mod lineage;
mod meta;
mod rows;
mod table;

use cabc_learning::checkpoint::{Checkpoint, CheckpointError};
use cabc_learning::replay::{ReplayError, ReplaySnapshot};
use cabc_outputs::RunDir;
use cabc_proto::config::{ObservationKind, RunConfig};
use lineage::{EpochSizes, Versions};
use meta::Info;
use serde::Serialize;
use std::path::{Path, PathBuf};
use table::DataFiles;

/// Why a run could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{path}: not a run folder ({reason})")]
    NotARun { path: PathBuf, reason: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("the run's checkpoint: {0}")]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: {source}")]
    Replay { path: PathBuf, source: ReplayError },
    /// The run's config.toml does not parse (the message names the file).
    #[error("{message}")]
    Config { path: PathBuf, message: String },
    #[error("{path}, line {line}: {message}")]
    Metrics {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path} exists and is not empty: export into a new folder")]
    OutExists { path: PathBuf },
    #[error("writing parquet: {0}")]
    Parquet(#[from] parquet::errors::ParquetError),
    #[error("building arrow arrays: {0}")]
    Arrow(#[from] arrow_schema::ArrowError),
    #[error("encoding an image as PNG: {0}")]
    Png(String),
}

impl ExportError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        ExportError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// What an export wrote.
#[derive(Clone, Debug, Serialize)]
pub struct ExportReport {
    pub out: PathBuf,
    pub frames: u64,
    pub episodes: u64,
    pub data_files: u64,
    /// Rows per store label (D+, D?, D-, dynamics-only).
    pub rows: std::collections::BTreeMap<&'static str, u64>,
    /// D- states whose step D? no longer holds (evicted since the labelling): not exported.
    pub d_minus_without_step: u64,
    /// Per store (D+, D?, dynamics-only): whether the policy versions could be derived.
    pub versions_known: [bool; 3],
}

/// Largest config.toml read.
const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// The run's configuration (for its name and images).
fn read_config(run: &Path) -> Result<RunConfig, ExportError> {
    let path = run.join(RunDir::CONFIG);
    let not_run = |reason: String| ExportError::NotARun {
        path: run.to_path_buf(),
        reason,
    };
    let len = std::fs::metadata(&path)
        .map_err(|e| not_run(format!("{}: {e}", path.display())))?
        .len();
    if len > MAX_CONFIG_BYTES {
        return Err(not_run(format!("{} holds {len} bytes", path.display())));
    }
    let text = std::fs::read_to_string(&path).map_err(|e| ExportError::io(&path, e))?;
    RunConfig::from_toml(&text, &path.display().to_string()).map_err(|e| ExportError::Config {
        path,
        message: e.to_string(),
    })
}

/// Exports the run folder `run` into the new folder `out` (see the module's documentation).
pub fn export(run: &Path, out: &Path) -> Result<ExportReport, ExportError> {
    if !run.is_dir() {
        return Err(ExportError::NotARun {
            path: run.to_path_buf(),
            reason: "no such folder".into(),
        });
    }
    let config = read_config(run)?;
    let checkpoint = Checkpoint::open(&run.join("checkpoint"))?;
    let replay_bin = checkpoint.path().join("replay.bin");
    let bytes = checkpoint.read("replay.bin")?;
    let replay_err = |source| ExportError::Replay {
        path: replay_bin.clone(),
        source,
    };
    let snapshot = ReplaySnapshot::read(&bytes, run).map_err(replay_err)?;
    drop(bytes);
    let image = match (config.observation.kind, snapshot.image_size()) {
        (ObservationKind::Camera, Some(size))
            if size == (config.observation.width, config.observation.height) =>
        {
            Some(size)
        }
        (ObservationKind::Camera, None) => {
            Some((config.observation.width, config.observation.height))
        }
        (ObservationKind::State, None) => None,
        (kind, held) => {
            return Err(replay_err(ReplayError::Decode(format!(
                "D+ holds images of {held:?} (width, height) in a run observing {kind:?} of {}x{}",
                config.observation.width, config.observation.height
            ))))
        }
    };

    let metrics = run.join(RunDir::METRICS);
    let sizes = EpochSizes::read(&metrics).unwrap_or_else(|e| {
        tracing::warn!("policy versions unknown: {e}");
        None
    });
    let added = &snapshot.added;
    let versions = [
        (snapshot.plus.len(), added.plus),
        (snapshot.uncertain.len(), added.uncertain),
        (snapshot.dynamics_only.len(), added.dynamics_only),
    ];
    let versions: [Versions; 3] = std::array::from_fn(|i| {
        let (len, added) = versions[i];
        Versions::of(sizes.as_ref(), i, len, added)
    });

    if out.exists()
        && std::fs::read_dir(out)
            .map_err(|e| ExportError::io(out, e))?
            .next()
            .is_some()
    {
        return Err(ExportError::OutExists {
            path: out.to_path_buf(),
        });
    }
    let mut partial = out.as_os_str().to_owned();
    partial.push(".partial");
    let root = PathBuf::from(partial);
    if root.exists() {
        std::fs::remove_dir_all(&root).map_err(|e| ExportError::io(&root, e))?;
    }
    std::fs::create_dir_all(&root).map_err(|e| ExportError::io(&root, e))?;

    let fps = (1.0 / cabc_sim::env::DT).round() as u32;
    let track = cabc_sim::Track::of(&config.sim).map_err(|e| ExportError::NotARun {
        path: run.to_path_buf(),
        reason: format!("its track (sim.track): {e}"),
    })?;
    let task = format!(
        "drive laps of {} ({:.2} m) without leaving it (|x_tran| <= {} m)",
        track.describe(),
        track.length(),
        track.half_width()
    );
    let files = DataFiles::new(&root, image.is_some());
    let written = rows::write(&snapshot, image, &versions, fps, files, &replay_err)?;
    table::write_episodes(
        &root.join("meta/episodes/chunk-000/file-000.parquet"),
        &written.episodes,
        &task,
    )?;
    table::write_tasks(&root.join("meta/tasks.parquet"), &task)?;

    let report = ExportReport {
        out: out.to_path_buf(),
        frames: written.frames,
        episodes: written.episodes.len() as u64,
        data_files: written.data_files,
        rows: written.rows,
        d_minus_without_step: (snapshot.minus.len() as u64).saturating_sub(written.minus_rows),
        versions_known: [
            versions[0].known(),
            versions[1].known(),
            versions[2].known(),
        ],
    };
    let info = Info {
        fps,
        episodes: report.episodes,
        frames: report.frames,
        image: image.map(|(w, h)| (h, w)),
        task: &task,
        cabc: serde_json::json!({
            "run": config.run.name,
            "source": run.display().to_string(),
            "checkpoint": checkpoint.path().display().to_string(),
            "rows": report.rows,
            "d_minus_without_step": report.d_minus_without_step,
            "policy_version_known": {
                "D+": report.versions_known[0],
                "D?": report.versions_known[1],
                "dynamics-only": report.versions_known[2],
            },
            "episodes": "maximal runs of consecutive steps of one store in which each state is the previous step's next state, bit for bit",
            "policy_version": "the epoch in which the store grew past the slot (metrics.csv), while the store only grew; -1 when unknown",
            "observation.state": "the true state (the learner's x); a camera run's policy saw the image, with noise when the run adds it",
        }),
    };
    let write_json = |name: &str, value: &serde_json::Value| -> Result<(), ExportError> {
        let path = root.join("meta").join(name);
        let text = serde_json::to_vec_pretty(value).expect("JSON values serialise");
        std::fs::write(&path, text).map_err(|e| ExportError::io(&path, e))
    };
    write_json("info.json", &info.to_json())?;
    write_json("stats.json", &written.stats.to_json())?;
    if out.exists() {
        std::fs::remove_dir(out).map_err(|e| ExportError::io(out, e))?;
    }
    std::fs::rename(&root, out).map_err(|e| ExportError::io(out, e))?;
    Ok(report)
}
