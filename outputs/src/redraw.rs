//! `cabc plots RUN`: a run folder's plots redrawn from its small files alone, the ones a kept run folder holds
//! (`docs/reproduction/<run>/`: `config.toml`, `metrics.csv`, `evals.csv`, `summary.json`; no plots or videos, issue
//! 47). The drawing is the live run's ([`plots::draw_tables`]); the tables are read back into the records and
//! evaluations the run wrote them from ([`cabc_learning::record::parse_table`], [`crate::rundir::parse_evals`]), and
//! the expert's lap time comes from `summary.json`.
//!
//! What the small files cannot give is left out, with the command that makes it from a full run folder
//! (`runs/<run>/`): [`LEFT_OUT`].

use crate::plots::{self, ExpertLaps, TABLE_PLOTS};
use crate::rundir::{parse_evals, RunDir};
use cabc_learning::evaluations::EvalSummary;
use cabc_learning::record::{parse_table, Record, TableError};
use std::path::{Path, PathBuf};

/// Why a run folder's plots could not be redrawn.
#[derive(Debug, thiserror::Error)]
pub enum RedrawError {
    #[error(
        "{path} is not a run folder ({why}): a run folder, or its kept copy in docs/reproduction/<run>/, holds \
         config.toml, metrics.csv, evals.csv and summary.json"
    )]
    NotARunFolder { path: PathBuf, why: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Table { path: PathBuf, source: TableError },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("drawing {path}: {message}")]
    Draw { path: PathBuf, message: String },
}

/// A run's plot that its small files cannot give, and how to get it from a full run folder.
#[derive(Clone, Copy, Debug)]
pub struct LeftOut {
    pub what: &'static str,
    pub why: &'static str,
}

impl std::fmt::Display for LeftOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.what, self.why)
    }
}

/// The live run's plots that [`redraw`] leaves out.
pub const LEFT_OUT: [LeftOut; 2] = [
    LeftOut {
        what: "line.png (the last evaluated line on the track)",
        why: "drawn from the evaluation's trajectory, which no kept file holds; a full run folder (runs/<run>/) has \
              the run's own plots/line.png, and `cabc video RUN` drives its best policy anew and shows the line",
    },
    LeftOut {
        what: "eval-v<N>.gif, best-policy.gif (the evaluations' videos)",
        why: "made from the policy's weights (best-policy.safetensors, final-policy.safetensors) of a full run \
              folder: `cabc video RUN [--final]` or `cabc show RUN --gif [best|final|VERSION]`",
    },
];

/// What a run folder's plots are drawn from, read back from its small files.
#[derive(Clone, Debug)]
pub struct Kept {
    /// `metrics.csv`'s rows.
    pub rows: Vec<Record>,
    /// `evals.csv`'s rows.
    pub evals: Vec<EvalSummary>,
    /// `summary.json`'s `expert_lap_time` (None: no summary, or no expert lap in it).
    pub expert: Option<ExpertLaps>,
    /// `config.toml`'s `collection.eval_laps` (the early stop's line on the laps plot).
    pub eval_laps: u32,
    /// What was missing and how the plots do without it.
    pub notes: Vec<String>,
}

impl Kept {
    /// Reads `run`'s `metrics.csv` and `evals.csv` (both needed), `config.toml` and `summary.json` (each optional:
    /// without config.toml the default `eval_laps`, without a summary no expert band, each said in
    /// [`Kept::notes`]; a malformed one is an error).
    pub fn read(run: &Path) -> Result<Kept, RedrawError> {
        let not_a_run = |why: String| RedrawError::NotARunFolder {
            path: run.to_path_buf(),
            why,
        };
        if !run.is_dir() {
            return Err(not_a_run(match run.exists() {
                true => "not a folder".into(),
                false => "no such folder".into(),
            }));
        }
        let mut notes = vec![];
        let text = |name: &str| -> Result<Option<String>, RedrawError> {
            let path = run.join(name);
            match std::fs::read_to_string(&path) {
                Ok(text) => Ok(Some(text)),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                Err(source) => Err(RedrawError::Io { path, source }),
            }
        };
        let needed = |name: &str| text(name)?.ok_or_else(|| not_a_run(format!("no {name}")));
        let (metrics, evals) = (needed(RunDir::METRICS)?, needed(RunDir::EVALS)?);
        let table = |name: &'static str| {
            move |source| RedrawError::Table {
                path: run.join(name),
                source,
            }
        };
        let rows = parse_table(&metrics).map_err(table(RunDir::METRICS))?;
        let evals = parse_evals(&evals).map_err(table(RunDir::EVALS))?;
        let default_laps = cabc_proto::config::CollectionSection::default().eval_laps;
        let eval_laps = match text(RunDir::CONFIG)? {
            Some(config) => eval_laps(&config).map_err(|message| RedrawError::Format {
                path: run.join(RunDir::CONFIG),
                message,
            })?,
            None => None,
        };
        let eval_laps = eval_laps.unwrap_or_else(|| {
            notes.push(format!(
                "no collection.eval_laps (no config.toml, or not in it): the laps plot's early-stop line at the \
                 default, {default_laps}"
            ));
            default_laps
        });
        let expert = match text(RunDir::SUMMARY)? {
            Some(summary) => {
                let expert = expert_lap_time(&summary).map_err(|message| RedrawError::Format {
                    path: run.join(RunDir::SUMMARY),
                    message,
                })?;
                if expert.is_none() {
                    notes.push(
                        "no expert lap time in summary.json: no expert band on the lap-time plot"
                            .into(),
                    );
                }
                expert
            }
            None => {
                notes.push(
                    "no summary.json (a run in progress, or a copy without it): no expert band on the lap-time plot \
                     (the run's summary gives it when the run ends)"
                        .into(),
                );
                None
            }
        };
        Ok(Kept {
            rows,
            evals,
            expert,
            eval_laps,
            notes,
        })
    }
}

/// `collection.eval_laps` of a `config.toml`'s text (None when it has no such key).
fn eval_laps(config: &str) -> Result<Option<u32>, String> {
    let value: toml::Table = config.parse().map_err(|e| format!("not TOML: {e}"))?;
    match value.get("collection").and_then(|c| c.get("eval_laps")) {
        None => Ok(None),
        Some(laps) => laps
            .as_integer()
            .and_then(|n| u32::try_from(n).ok())
            .map(Some)
            .ok_or_else(|| format!("collection.eval_laps = {laps} is not a number of laps")),
    }
}

/// `expert_lap_time` of a `summary.json`'s text (`{"laps", "mean", "std"}`; None when absent or null).
fn expert_lap_time(summary: &str) -> Result<Option<ExpertLaps>, String> {
    let summary: serde_json::Value =
        serde_json::from_str(summary).map_err(|e| format!("not JSON: {e}"))?;
    let expert = &summary["expert_lap_time"];
    if expert.is_null() {
        return Ok(None);
    }
    let number = |key: &str| {
        expert[key]
            .as_f64()
            .ok_or_else(|| format!("expert_lap_time.{key} is not a number: {expert}"))
    };
    Ok(Some(ExpertLaps {
        mean: number("mean")?,
        std: number("std")?,
        laps: number("laps")? as usize,
    }))
}

/// What [`redraw`] did.
#[derive(Clone, Debug)]
pub struct Redrawn {
    /// The plots written, in [`TABLE_PLOTS`]' order.
    pub drawn: Vec<PathBuf>,
    /// What was missing and how the plots do without it ([`Kept::notes`]).
    pub notes: Vec<String>,
    /// The live run's plots that the small files cannot give ([`LEFT_OUT`]).
    pub left_out: &'static [LeftOut],
}

/// Redraws `run`'s plots of [`TABLE_PLOTS`] from its small files ([`Kept::read`]) into `out` (default
/// `run/plots/`, created), overwriting what is there; the rest of the live run's plots are [`LEFT_OUT`].
pub fn redraw(run: &Path, out: Option<&Path>) -> Result<Redrawn, RedrawError> {
    let kept = Kept::read(run)?;
    let dir = out.map_or_else(|| run.join(RunDir::PLOTS), Path::to_path_buf);
    std::fs::create_dir_all(&dir).map_err(|source| RedrawError::Io {
        path: dir.clone(),
        source,
    })?;
    plots::draw_tables(&dir, &kept.rows, &kept.evals, kept.expert, kept.eval_laps).map_err(
        |e| RedrawError::Draw {
            path: dir.clone(),
            message: e.to_string(),
        },
    )?;
    Ok(Redrawn {
        drawn: TABLE_PLOTS.iter().map(|name| dir.join(name)).collect(),
        notes: kept.notes,
        left_out: &LEFT_OUT,
    })
}
