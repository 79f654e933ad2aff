//! The reproduction report's figures over seeds: per method (proposed, lambda > 0; baseline, lambda = 0), how many
//! runs reached `eval_laps` laps and the median and range of the versions of their first and second full
//! evaluations, of the best full evaluation's mean lap time, of the laps completed over all evaluations, of the late
//! evaluations' steps ([`RunRecord::late_steps`]), of the imitation loss at the end (the early stop or the epoch cap)
//! and of the wall clock; and of the share of collected steps in failed episodes over the epochs every run has
//! ([`RunRecord::crashed_share`]: training-time safety, which the paper's claim is about). `cabc compare` prints it
//! under the per-run table.

use crate::runs::{RunRecord, LATE_VERSIONS};
use crate::stats::median_range;

/// The Markdown table of the methods over their runs (seeds).
pub fn methods_table(runs: &[RunRecord]) -> String {
    // The window every run has, so that a run that stopped early is not compared with another's later epochs.
    let window = runs
        .iter()
        .map(|r| r.collection.len() as u64)
        .min()
        .unwrap_or(0);
    let mut out = format!(
        "| method | runs | reached the laps | 1st full eval | 2nd full eval | best lap time (s) | laps, all evals | eval steps, last {LATE_VERSIONS} | imitation loss at the end | wall clock (min) | collected steps in failed episodes, epochs 0–{} (%) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
        window.saturating_sub(1),
    );
    for (method, baseline) in [("proposed", false), ("baseline", true)] {
        let of: Vec<&RunRecord> = runs
            .iter()
            .filter(|r| r.is_baseline() == baseline)
            .collect();
        if of.is_empty() {
            continue;
        }
        let fulls: Vec<Vec<u64>> = of
            .iter()
            .map(|r| r.full().map(|e| e.version).collect())
            .collect();
        let nth = |k: usize| -> Vec<f64> {
            fulls
                .iter()
                .filter_map(|f| f.get(k).map(|&v| v as f64))
                .collect()
        };
        let reached = fulls.iter().filter(|f| !f.is_empty()).count();
        let cap = of.iter().map(|r| r.epochs).max().unwrap_or(0);
        let versions = |k: usize| match nth(k) {
            v if v.is_empty() => format!("none by {cap}"),
            v => format!("{} (of {})", median_range(&v, 0), v.len()),
        };
        let best: Vec<f64> = of
            .iter()
            .filter_map(|r| r.full().filter_map(|e| e.lap_mean).min_by(f64::total_cmp))
            .collect();
        let imitation: Vec<f64> = of
            .iter()
            .filter_map(|r| r.imitation.last().map(|&(_, l)| l))
            .collect();
        let wall: Vec<f64> = of.iter().map(|r| r.wall_s / 60.0).collect();
        let laps: Vec<f64> = of.iter().map(|r| r.laps_completed() as f64).collect();
        let late: Vec<f64> = of.iter().filter_map(|r| r.late_steps()).collect();
        let crashed: Vec<f64> = of
            .iter()
            .filter_map(|r| Some(100.0 * r.crashed_share(window)?))
            .collect();
        out.push_str(&format!(
            "| {method} | {} | {reached} of {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            of.len(),
            of.len(),
            versions(0),
            versions(1),
            median_range(&best, 2),
            median_range(&laps, 0),
            median_range(&late, 0),
            median_range(&imitation, 3),
            median_range(&wall, 1),
            median_range(&crashed, 1),
        ));
    }
    out.push('\n');
    out.push_str(&crate::intervals::interval_header("method"));
    let [proposed, baseline]: [Vec<&RunRecord>; 2] =
        [false, true].map(|b| runs.iter().filter(|r| r.is_baseline() == b).collect());
    for (method, of) in [("proposed", &proposed), ("baseline", &baseline)] {
        if !of.is_empty() {
            out.push_str(&crate::intervals::interval_row(method, of));
        }
    }
    let line = crate::intervals::improvement_line("proposed", &proposed, "baseline", &baseline);
    if !line.is_empty() {
        out.push('\n');
        out.push_str(&line);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runs::Eval;

    /// A run whose epochs each collect 100 steps, `crashed` of them in failed episodes.
    fn record(
        name: &str,
        lambda: f64,
        full_at: &[u64],
        imitation: f64,
        wall_s: f64,
        crashed: f64,
    ) -> RunRecord {
        RunRecord {
            name: name.into(),
            lambda,
            seed: Some(1),
            eval_laps: 50,
            evals: full_at
                .iter()
                .map(|&version| Eval {
                    version,
                    laps: 50,
                    lap_mean: Some(5.0 + version as f64 / 100.0),
                    lap_std: Some(0.1),
                    steps: Some(2600),
                })
                .collect(),
            imitation: vec![(0, 1.0), (9, imitation)],
            epochs: 200,
            wall_s,
            incomplete_share: None,
            early_stop: None,
            expert_lap_time: None,
            ended: None,
            peak_mb: None,
            collection: vec![(crashed, 100.0); 3],
        }
    }

    #[test]
    fn medians_and_ranges_per_method() {
        assert_eq!(median_range(&[3.0, 1.0, 2.0], 0), "2 [1–3]");
        assert_eq!(median_range(&[1.0, 4.0], 1), "2.5 [1.0–4.0]");
        assert_eq!(median_range(&[7.0], 2), "7.00");
        assert_eq!(median_range(&[], 2), "-");
        let mut runs = [
            record("p1", 10.0, &[100, 110], 0.2, 600.0, 20.0),
            record("p2", 10.0, &[], 0.3, 720.0, 40.0),
            record("p3", 10.0, &[150], 0.25, 660.0, 30.0),
            record("b1", 0.0, &[], 0.1, 700.0, 60.0),
        ];
        // p2's fourth epoch lies outside the window the others have: counted, its share would be 55 %.
        runs[1].collection.push((100.0, 100.0));
        let table = methods_table(&runs);
        assert!(
            table.contains("| collected steps in failed episodes, epochs 0–2 (%) |"),
            "{table}"
        );
        assert!(
            table.contains(
                "| proposed | 3 | 2 of 3 | 125 [100–150] (of 2) | 110 (of 1) | 6.25 [6.00–6.50] | 50 [0–100] | 2600 [2600–2600] | 0.250 [0.200–0.300] | 11.0 [10.0–12.0] | 30.0 [20.0–40.0] |"
            ),
            "{table}"
        );
        assert!(
            table.contains(
                "| baseline | 1 | 0 of 1 | none by 200 | none by 200 | - | 0 | - | 0.100 | 11.7 | 60.0 |"
            ),
            "{table}"
        );
        // The baseline's one run never got there (200): the proposed runs' 100 and 150 beat it, 200 ties.
        assert!(
            table.contains("P(proposed reaches its first 50-lap version before baseline), rliable's probability of improvement over every pair of runs: 0.83 [0.50, 1.00] (95 % CI)"),
            "{table}"
        );
        // Over seeds: p1 stopped (two full evaluations); first 50-lap versions 100, 200 (never: its budget), 150.
        assert!(
            table.contains(
                "| proposed | 3 | 1 of 3 [0.06, 0.79] | 150.0 [100.0, 200.0] | 2600.0 [2600.0, 2600.0] |"
            ),
            "{table}"
        );
    }
}
