//! `learner compare RUN...`: the paper's figures for any set of run folders, both methods on one plot.
//!
//! * `<out>-laps.png`: completed evaluation laps per policy version (the paper's V-A, V-B and V-C figures);
//! * `<out>-imitation.png`: the imitation loss per epoch, each run's early stop marked;
//! * `<out>-lap-times.png`: lap-time mean and spread of the evaluations that completed `eval_laps` laps, against
//!   the expert's;
//! * `<out>-steps.png`: how long each evaluation stayed on the track (its steps, a running median), which tells
//!   runs apart that never complete a lap;
//! * a Markdown table on stdout: per run, the versions of the first and second full evaluation, the early stop,
//!   lap times, the laps completed over all evaluations, the late evaluations' steps ([`RunRecord::late_steps`]),
//!   the incomplete share and the wall clock; then per method, the median and range over its runs
//!   ([`crate::seeds`]).
//!
//! A run folder is read from its `config.toml`, `metrics.csv`, `evals.csv` and (when the run ended) `summary.json`;
//! it may still be running. Proposed runs are drawn in blues, baselines (named `-baseline`, or lambda = 0) in oranges, a
//! shade per seed.

use cabc_proto::config::RunConfig;
use std::path::{Path, PathBuf};

mod figures;
pub use figures::draw;

/// A run folder that cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("{path}: {why}")]
    Run { path: PathBuf, why: String },
    #[error("drawing {path}: {why}")]
    Draw { path: PathBuf, why: String },
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
}

/// A CSV with a header, as the learner writes it (no quoting).
struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    fn read(path: &Path) -> Result<Table, String> {
        let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
        let mut lines = text
            .lines()
            .map(|l| l.split(',').map(str::to_string).collect());
        let header = lines.next().ok_or("empty")?;
        Ok(Table {
            header,
            rows: lines.collect(),
        })
    }

    fn column(&self, name: &str) -> Result<Vec<&str>, String> {
        let i = self
            .header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| format!("no column {name}"))?;
        Ok(self
            .rows
            .iter()
            .map(|r| r.get(i).map_or("", String::as_str))
            .collect())
    }
}

fn number<T: std::str::FromStr>(text: &str) -> Option<T> {
    text.parse().ok()
}

impl RunRecord {
    pub fn read(dir: &Path) -> Result<RunRecord, CompareError> {
        let fail = |why: String| CompareError::Run {
            path: dir.to_path_buf(),
            why,
        };
        let summary: Option<serde_json::Value> = std::fs::read_to_string(dir.join("summary.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
        // A folder of results without config.toml (older copies): the name and lambda from summary.json.
        let config_path = dir.join("config.toml");
        let (name, lambda, seed, eval_laps) = if config_path.exists() {
            let config = RunConfig::load(&config_path.display().to_string())
                .map_err(|e| fail(e.to_string()))?;
            (
                config.run.name.clone(),
                config.algorithm.lambda,
                Some(config.run.seed),
                config.collection.eval_laps,
            )
        } else {
            let s = summary
                .as_ref()
                .ok_or_else(|| fail("neither config.toml nor summary.json".into()))?;
            (
                s["run"].as_str().unwrap_or("?").to_string(),
                s["lambda"].as_f64().unwrap_or(f64::NAN),
                None,
                cabc_proto::config::CollectionSection::default().eval_laps,
            )
        };
        let metrics =
            Table::read(&dir.join("metrics.csv")).map_err(|e| fail(format!("metrics.csv: {e}")))?;
        let column = |name| {
            metrics
                .column(name)
                .map_err(|e| fail(format!("metrics.csv: {e}")))
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
        let evals_table =
            Table::read(&dir.join("evals.csv")).map_err(|e| fail(format!("evals.csv: {e}")))?;
        let evals_column = |name| {
            evals_table
                .column(name)
                .map_err(|e| fail(format!("evals.csv: {e}")))
        };
        let versions = evals_column("version")?;
        // Older folders may lack the steps.
        let steps = evals_table
            .column("steps")
            .unwrap_or_else(|_| vec![""; versions.len()]);
        let mut evals: Vec<Eval> = versions
            .iter()
            .zip(evals_column("laps")?)
            .zip(evals_column("lap_mean")?)
            .zip(evals_column("lap_std")?)
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
        let expert_lap_time = summary.as_ref().and_then(|s| {
            let e = &s["expert_lap_time"];
            Some((e["mean"].as_f64()?, e["std"].as_f64()?))
        });
        Ok(RunRecord {
            name,
            lambda,
            seed,
            eval_laps,
            evals,
            imitation,
            epochs: epochs.len() as u64,
            wall_s,
            incomplete_share: cabc_proto::stats::mean(&incomplete),
            early_stop: summary
                .as_ref()
                .and_then(|s| s["early_stop_version"].as_u64()),
            expert_lap_time,
            ended: summary
                .as_ref()
                .and_then(|s| s["ended"].as_str().map(str::to_string)),
            peak_mb: summary
                .as_ref()
                .and_then(|s| s["learner_peak_rss_mb"].as_f64()),
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
        crate::seeds::median(&late)
    }

    /// A baseline run: named so by `--baseline` (its name ends in `-baseline`, whatever lambda it has: the Fig. 6
    /// caption's V-C baseline keeps lambda = 1), or trained with lambda = 0.
    pub fn is_baseline(&self) -> bool {
        self.name.ends_with("-baseline") || self.lambda == 0.0
    }
}

/// `learner compare`'s command-line arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct CompareOptions {
    /// Run folders (runs/<run>, or copies holding config.toml, metrics.csv, evals.csv, summary.json).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Figures go to <OUT>-laps.png, <OUT>-imitation.png, <OUT>-lap-times.png, <OUT>-steps.png (with --by-group:
    /// <OUT>-groups.png).
    #[arg(long, default_value = "compare")]
    pub out: PathBuf,
    /// The ablation view: the runs grouped by name less `-s<k>`, a row per group and a column per seed
    /// ([`crate::groups`]), and the late evaluations' steps per group in <OUT>-groups.png.
    #[arg(long)]
    pub by_group: bool,
}

/// Reads the runs, draws the figures (logging their paths) and returns the Markdown table.
pub fn run(options: &CompareOptions) -> Result<String, CompareError> {
    let records = options
        .runs
        .iter()
        .map(|dir| RunRecord::read(dir))
        .collect::<Result<Vec<_>, _>>()?;
    if options.by_group {
        let figure =
            crate::groups::draw(&records, &options.out).map_err(|e| CompareError::Draw {
                path: options.out.clone(),
                why: e.to_string(),
            })?;
        tracing::info!("wrote {}", figure.display());
        return Ok(crate::groups::table(&records));
    }
    for figure in draw(&records, &options.out)? {
        tracing::info!("wrote {}", figure.display());
    }
    Ok(format!(
        "{}\n{}",
        table(&records),
        crate::seeds::methods_table(&records)
    ))
}

/// The Markdown table of the runs.
pub fn table(runs: &[RunRecord]) -> String {
    let mut out = format!(
        "| run | lambda | seed | epochs | 1st full eval | 2nd full eval | early stop | best lap time (s) | expert (s) | laps, all evals | eval steps, last {LATE_VERSIONS} | incomplete | wall clock (min) | learner peak (MB) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let opt = |v: Option<u64>| v.map_or("none".to_string(), |v| v.to_string());
    for r in runs {
        let full: Vec<&Eval> = r.full().collect();
        let best = full
            .iter()
            .filter_map(|e| Some((e.lap_mean?, e.lap_std.unwrap_or(0.0))))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.1} | {} |\n",
            r.name,
            r.lambda,
            r.seed.map_or("?".into(), |s| s.to_string()),
            r.epochs,
            full.first()
                .map_or(format!("none by {}", r.epochs), |e| e.version.to_string()),
            full.get(1).map_or("none".into(), |e| e.version.to_string()),
            opt(r.early_stop),
            best.map_or("-".into(), |(m, s)| format!("{m:.2} ± {s:.2}")),
            r.expert_lap_time
                .map_or("-".into(), |(m, s)| format!("{m:.2} ± {s:.2}")),
            r.laps_completed(),
            r.late_steps().map_or("-".into(), |s| format!("{s:.0}")),
            r.incomplete_share
                .map_or("-".into(), |s| format!("{:.1} %", 100.0 * s)),
            r.wall_s / 60.0,
            r.peak_mb.map_or("-".into(), |m| format!("{m:.0}")),
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run folder with the files `compare` reads.
    fn run(dir: &Path, name: &str, lambda: f64, evals: &[(u64, u32, f64)]) -> PathBuf {
        let folder = dir.join(name);
        std::fs::create_dir_all(&folder).unwrap();
        let mut config = RunConfig::load("smoke").unwrap();
        config.run.name = name.into();
        config.algorithm.lambda = lambda;
        config.collection.eval_laps = 3;
        std::fs::write(folder.join("config.toml"), config.to_toml()).unwrap();
        let mut metrics = String::from("epoch,imitation_loss,epoch_s,incomplete_share\n");
        for e in 0..evals.len() {
            metrics.push_str(&format!("{e},{},{},0.02\n", 0.1 / (e + 1) as f64, 30.0));
        }
        std::fs::write(folder.join("metrics.csv"), metrics).unwrap();
        let mut text =
            String::from("version,laps,lap_mean,lap_std,lap_min,lap_max,end_reason,steps\n");
        for &(v, laps, mean) in evals {
            let (m, s) = if laps > 0 {
                (format!("{mean}"), "0.1".to_string())
            } else {
                (String::new(), String::new())
            };
            let steps = 10 + 30 * laps;
            text.push_str(&format!("{v},{laps},{m},{s},,,max-laps,{steps}\n"));
        }
        std::fs::write(folder.join("evals.csv"), text).unwrap();
        folder
    }

    #[test]
    fn runs_are_read_tabulated_and_drawn() {
        let tmp = tempfile::tempdir().unwrap();
        let proposed = run(
            tmp.path(),
            "p",
            10.0,
            &[(0, 0, 0.0), (1, 3, 5.2), (2, 1, 6.0), (3, 3, 5.0)],
        );
        let baseline = run(tmp.path(), "b", 0.0, &[(0, 0, 0.0), (1, 1, 7.0)]);
        let runs: Vec<RunRecord> = [proposed, baseline]
            .iter()
            .map(|d| RunRecord::read(d).unwrap())
            .collect();
        assert_eq!(
            runs[0].full().map(|e| e.version).collect::<Vec<_>>(),
            [1, 3]
        );
        assert!(runs[1].is_baseline());
        let table = table(&runs);
        assert!(
            table.contains(
                "| p | 10 | 7 | 4 | 1 | 3 | none | 5.00 ± 0.10 | - | 7 | 70 | 2.0 % | 2.0 | - |"
            ),
            "{table}"
        );
        assert!(
            table.contains("| b | 0 | 7 | 2 | none by 2 | none |"),
            "{table}"
        );
        // The late steps are those of the last LATE_VERSIONS versions only.
        let long = run(
            tmp.path(),
            "long",
            10.0,
            &(0..100)
                .map(|v| (v, (v / 10) as u32, 5.0))
                .collect::<Vec<_>>(),
        );
        let long = RunRecord::read(&long).unwrap();
        assert_eq!(long.laps_completed(), 450);
        // Versions 50-99: laps 5-9, steps 160-280, 10 versions each: the median is the middle group's 220 (all
        // 100 versions would give 145).
        assert_eq!(long.late_steps(), Some(220.0));
        let figures = draw(&runs, &tmp.path().join("cmp")).unwrap();
        assert_eq!(figures.len(), 4);
        for f in figures {
            assert!(
                std::fs::metadata(&f).unwrap().len() > 1000,
                "{}",
                f.display()
            );
        }
        let missing = RunRecord::read(&tmp.path().join("nothing"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("nothing"), "{missing}");
    }
}
