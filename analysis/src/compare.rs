//! `cabc compare RUN...`: the paper's figures for any set of run folders, both methods on one plot.
//!
//! * `<out>-laps.png`: completed evaluation laps per policy version (the paper's V-A, V-B and V-C figures);
//! * `<out>-imitation.png`: the imitation loss per epoch, each run's early stop marked;
//! * `<out>-lap-times.png`: lap-time mean and spread of the evaluations that completed `eval_laps` laps, against
//!   the expert's;
//! * `<out>-steps.png`: how long each evaluation stayed on the track (its steps, a running median), which tells
//!   runs apart that never complete a lap;
//! * `<out>-crashed.png`: per epoch, the share of the collected steps in episodes that failed (over 9 epochs), the
//!   training-time safety that the paper's claim is about;
//! * a Markdown table on stdout: per run, the versions of the first and second full evaluation, the early stop,
//!   lap times, the laps completed over all evaluations, the late evaluations' steps ([`RunRecord::late_steps`]),
//!   the incomplete share and the wall clock; then per method, the median and range over its runs
//!   ([`crate::seeds`]).
//!
//! A run folder is read from its `config.toml`, `metrics.csv`, `evals.csv` and (when the run ended) `summary.json`;
//! it may still be running. Proposed runs are drawn in blues, baselines (named `-baseline`, or lambda = 0) in oranges, a
//! shade per seed.

use std::path::PathBuf;

mod figures;
pub use crate::runs::{CompareError, Eval, RunRecord, LATE_VERSIONS};
pub use figures::draw;

/// `cabc compare`'s command-line arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct CompareOptions {
    /// Run folders (runs/<run>, or copies holding config.toml, metrics.csv, evals.csv, summary.json).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Figures go to <OUT>-laps.png, <OUT>-imitation.png, <OUT>-lap-times.png, <OUT>-steps.png, <OUT>-crashed.png
    /// (with --by-group: <OUT>-groups.png and <OUT>-first50.png).
    #[arg(long, default_value = "compare")]
    pub out: PathBuf,
    /// The ablation view: the runs grouped by name less `-s<k>`, a row per group and a column per seed
    /// ([`crate::groups`]), the late evaluations' steps per group in <OUT>-groups.png and the first 50-lap version
    /// per group in <OUT>-first50.png.
    #[arg(long)]
    pub by_group: bool,
    /// With --by-group, one more comparison `A=B` of two groups' labels (as the table names them, e.g.
    /// `v-c-ref-ten=v-c-ref-bc-ten (baseline)`): P(A reaches its first 50-lap version before B), beside each group
    /// against its own baseline. Repeatable.
    #[arg(long, value_name = "A=B", requires = "by_group")]
    pub versus: Vec<String>,
}

/// Reads the runs, draws the figures (logging their paths) and returns the Markdown table.
pub fn run(options: &CompareOptions) -> Result<String, CompareError> {
    let records = options
        .runs
        .iter()
        .map(|dir| RunRecord::read(dir))
        .collect::<Result<Vec<_>, _>>()?;
    if options.by_group {
        let figures =
            crate::groups::draw(&records, &options.out).map_err(|e| CompareError::Draw {
                path: options.out.clone(),
                why: e.to_string(),
            })?;
        for figure in figures {
            tracing::info!("wrote {}", figure.display());
        }
        let versus = options
            .versus
            .iter()
            .map(|pair| {
                pair.split_once('=')
                    .map(|(a, b)| (a.trim().to_string(), b.trim().to_string()))
                    .ok_or_else(|| CompareError::Versus {
                        pair: pair.clone(),
                        why: "not of the form A=B".into(),
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        return crate::groups::table(&records, &versus);
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
    use cabc_proto::config::RunConfig;
    use std::path::Path;

    /// A run folder with the files `compare` reads.
    fn run(dir: &Path, name: &str, lambda: f64, evals: &[(u64, u32, f64)]) -> PathBuf {
        let folder = dir.join(name);
        let mut config = RunConfig::load("smoke").unwrap();
        config.run.name = name.into();
        config.algorithm.lambda = lambda;
        config.collection.eval_laps = 3;
        cabc_fixtures::run_folder(&folder, &config);
        let mut metrics = String::from(
            "epoch,imitation_loss,epoch_s,incomplete_share,steps_collected,uncertain_failed_lap,uncertain_truncating\n",
        );
        for e in 0..evals.len() {
            // Epoch e collects 100 steps, 10 e of them in failed laps and e truncating ones.
            metrics.push_str(&format!(
                "{e},{},{},0.02,100,{},{e}\n",
                0.1 / (e + 1) as f64,
                30.0,
                10 * e
            ));
        }
        std::fs::write(folder.join("metrics.csv"), metrics).unwrap();
        let mut text = format!("{}\n", cabc_outputs::rundir::EVALS_HEADER);
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
        // Epochs 0-2 of p: (0 + 11 + 22) of 300 steps; b has 2 epochs only.
        assert_eq!(runs[0].crashed_share(3), Some(0.11));
        assert_eq!(runs[1].crashed_share(2), Some(0.055));
        assert_eq!(runs[1].crashed_share(3), None);
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
        assert_eq!(figures.len(), 5);
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
