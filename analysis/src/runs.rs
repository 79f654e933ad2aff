//! A finished (or running) run folder as the analysis reads it back: its configuration, `metrics.csv`, `evals.csv`
//! and `summary.json`, as one [`RunRecord`].

use crate::stats::median;
use cabc_proto::config::RunConfig;
use cabc_runfolder::Table;
use std::path::{Path, PathBuf};

/// A run folder that cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("{path}: {why}")]
    Run { path: PathBuf, why: String },
    #[error("drawing {path}: {why}")]
    Draw { path: PathBuf, why: String },
    #[error("--versus {pair}: {why}")]
    Versus { pair: String, why: String },
}

/// One evaluation as `evals.csv` holds it.
#[derive(Clone, Debug, PartialEq)]
pub struct Eval {
    pub version: u64,
    pub laps: u32,
    pub lap_mean: Option<f64>,
    pub lap_std: Option<f64>,
    /// The steps the evaluation lasted (until its laps, a failure or its step cap).
    pub steps: Option<u64>,
}

/// The late evaluations of [`RunRecord::late_steps`]: those of a run's last `LATE_VERSIONS` versions.
pub const LATE_VERSIONS: u64 = 50;

/// What the comparison needs of one run.
#[derive(Clone, Debug)]
pub struct RunRecord {
    pub name: String,
    pub lambda: f64,
    /// None for a folder without config.toml (read from summary.json).
    pub seed: Option<u64>,
    pub eval_laps: u32,
    pub evals: Vec<Eval>,
    /// (epoch, imitation loss) where the policy trained.
    pub imitation: Vec<(u64, f64)>,
    pub epochs: u64,
    pub wall_s: f64,
    pub incomplete_share: Option<f64>,
    pub early_stop: Option<u64>,
    pub expert_lap_time: Option<(f64, f64)>,
    pub ended: Option<String>,
    /// The learner's peak resident memory (MB), when the summary has it.
    pub peak_mb: Option<f64>,
    /// Per epoch in order, (steps of collected episodes that left the track or otherwise failed, steps collected):
    /// empty for older folders without D?'s provenance columns.
    pub collection: Vec<(f64, f64)>,
}

fn number<T: std::str::FromStr>(text: &str) -> Option<T> {
    text.parse().ok()
}

/// What names a run: from its config.toml, or (a folder of results without one: older copies) its summary.json.
struct Identity {
    name: String,
    lambda: f64,
    seed: Option<u64>,
    eval_laps: u32,
}

impl Identity {
    fn read(dir: &Path, summary: Option<&serde_json::Value>) -> Result<Identity, String> {
        let config_path = dir.join(cabc_runfolder::CONFIG);
        if config_path.exists() {
            let config =
                RunConfig::load(&config_path.display().to_string()).map_err(|e| e.to_string())?;
            return Ok(Identity {
                name: config.run.name.clone(),
                lambda: config.algorithm.lambda,
                seed: Some(config.run.seed),
                eval_laps: config.collection.eval_laps,
            });
        }
        let s = summary.ok_or("neither config.toml nor summary.json")?;
        Ok(Identity {
            name: s["run"].as_str().unwrap_or("?").to_string(),
            lambda: s["lambda"].as_f64().unwrap_or(f64::NAN),
            seed: None,
            eval_laps: cabc_proto::config::CollectionSection::default().eval_laps,
        })
    }
}

/// What the comparison reads of metrics.csv.
struct Metrics {
    epochs: u64,
    imitation: Vec<(u64, f64)>,
    wall_s: f64,
    /// Per epoch; empty for older folders.
    incomplete: Vec<f64>,
    collection: Vec<(f64, f64)>,
}

impl Metrics {
    fn read(dir: &Path) -> Result<Metrics, String> {
        let metrics = Table::read(&dir.join(cabc_runfolder::METRICS))
            .map_err(|e| format!("metrics.csv: {e}"))?;
        let column = |name| {
            metrics
                .column(name)
                .map_err(|e| format!("metrics.csv: {e}"))
        };
        let epochs: Vec<u64> = column("epoch")?.iter().filter_map(|v| number(v)).collect();
        let imitation = epochs
            .iter()
            .zip(column("imitation_loss")?)
            .filter_map(|(&e, v)| number::<f64>(v).filter(|v| *v > 0.0).map(|v| (e, v)))
            .collect();
        let wall_s = column("epoch_s")?
            .iter()
            .filter_map(|v| number::<f64>(v))
            .sum();
        // Older run folders have no incomplete share.
        let incomplete: Vec<f64> = metrics
            .column("incomplete_share")
            .map(|c| c.iter().filter_map(|v| number(v)).collect())
            .unwrap_or_default();
        // The steps of D_new's failed episodes (not the expert's failures, nor an off-track spawn's single step).
        let collection = match (
            metrics.column("uncertain_failed_lap"),
            metrics.column("uncertain_truncating"),
            metrics.column("steps_collected"),
        ) {
            (Ok(failed_lap), Ok(truncating), Ok(collected)) => failed_lap
                .iter()
                .zip(truncating)
                .zip(collected)
                .filter_map(|((f, t), c)| {
                    Some((number::<f64>(f)? + number::<f64>(t)?, number::<f64>(c)?))
                })
                .collect(),
            _ => Vec::new(),
        };
        Ok(Metrics {
            epochs: epochs.len() as u64,
            imitation,
            wall_s,
            incomplete,
            collection,
        })
    }
}

/// The evaluations of evals.csv in version order, one per version.
fn read_evals(dir: &Path) -> Result<Vec<Eval>, String> {
    let table =
        Table::read(&dir.join(cabc_runfolder::EVALS)).map_err(|e| format!("evals.csv: {e}"))?;
    let column = |name| table.column(name).map_err(|e| format!("evals.csv: {e}"));
    let versions = column("version")?;
    // Older folders may lack the steps.
    let steps = table
        .column("steps")
        .unwrap_or_else(|_| vec![""; versions.len()]);
    let mut evals: Vec<Eval> = versions
        .iter()
        .zip(column("laps")?)
        .zip(column("lap_mean")?)
        .zip(column("lap_std")?)
        .zip(steps)
        .filter_map(|((((v, l), m), s), steps)| {
            Some(Eval {
                version: number(v)?,
                laps: number(l)?,
                lap_mean: number(m),
                lap_std: number(s),
                steps: number(steps),
            })
        })
        .collect();
    evals.sort_by_key(|e| e.version);
    evals.dedup_by_key(|e| e.version);
    Ok(evals)
}

impl RunRecord {
    pub fn read(dir: &Path) -> Result<RunRecord, CompareError> {
        let fail = |why: String| CompareError::Run {
            path: dir.to_path_buf(),
            why,
        };
        let summary: Option<serde_json::Value> =
            std::fs::read_to_string(dir.join(cabc_runfolder::SUMMARY))
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok());
        let identity = Identity::read(dir, summary.as_ref()).map_err(fail)?;
        let metrics = Metrics::read(dir).map_err(fail)?;
        let evals = read_evals(dir).map_err(fail)?;
        let summary = summary.as_ref();
        let expert_lap_time = summary.and_then(|s| {
            let e = &s["expert_lap_time"];
            Some((e["mean"].as_f64()?, e["std"].as_f64()?))
        });
        Ok(RunRecord {
            name: identity.name,
            lambda: identity.lambda,
            seed: identity.seed,
            eval_laps: identity.eval_laps,
            evals,
            imitation: metrics.imitation,
            epochs: metrics.epochs,
            wall_s: metrics.wall_s,
            incomplete_share: cabc_proto::stats::mean(&metrics.incomplete),
            early_stop: summary.and_then(|s| s["early_stop_version"].as_u64()),
            expert_lap_time,
            ended: summary.and_then(|s| s["ended"].as_str().map(str::to_string)),
            peak_mb: summary.and_then(|s| s["learner_peak_rss_mb"].as_f64()),
            collection: metrics.collection,
        })
    }

    /// The evaluations that completed `eval_laps` laps, in version order.
    pub fn full(&self) -> impl Iterator<Item = &Eval> {
        self.evals.iter().filter(|e| e.laps >= self.eval_laps)
    }

    /// The laps completed over all its evaluations: a run that never reaches `eval_laps` may still complete some.
    pub fn laps_completed(&self) -> u64 {
        self.evals.iter().map(|e| u64::from(e.laps)).sum()
    }

    /// The median steps of the evaluations of the run's last [`LATE_VERSIONS`] versions: how long its late policies
    /// stay on the track, a figure that tells apart runs that never complete a lap. None without evaluations.
    pub fn late_steps(&self) -> Option<f64> {
        let last = self.evals.last()?.version;
        let late: Vec<f64> = self
            .evals
            .iter()
            .filter(|e| e.version + LATE_VERSIONS > last)
            .filter_map(|e| e.steps.map(|s| s as f64))
            .collect();
        median(&late)
    }

    /// The share of the steps collected in the first `epochs` epochs that belonged to an episode that failed (left
    /// the track, stalled or spun): how much of the training-time driving ended in a violation. None when the run
    /// has fewer epochs with these columns, or collected nothing.
    pub fn crashed_share(&self, epochs: u64) -> Option<f64> {
        self.crashed_share_over(0..usize::try_from(epochs).ok()?)
    }

    /// [`RunRecord::crashed_share`] over the epochs `epochs` (indices of `collection`); None when the run lacks
    /// some of them or collected nothing there.
    pub fn crashed_share_over(&self, epochs: std::ops::Range<usize>) -> Option<f64> {
        let (failed, collected) = self
            .collection
            .get(epochs)?
            .iter()
            .fold((0.0, 0.0), |(f, c), &(ef, ec)| (f + ef, c + ec));
        (collected > 0.0).then(|| failed / collected)
    }

    /// A baseline run: named so by `--baseline` (its name ends in `-baseline`, whatever lambda it has: the Fig. 6
    /// caption's V-C baseline keeps lambda = 1), or trained with lambda = 0.
    pub fn is_baseline(&self) -> bool {
        self.name.ends_with("-baseline") || self.lambda == 0.0
    }
}
