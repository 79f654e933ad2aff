//! Statistics over seeds a reviewer accepts (Agarwal et al., "Deep RL at the edge of the statistical precipice",
//! NeurIPS 2021, and its library rliable): the interquartile mean (IQM) of a figure over a group's runs, with a 95 %
//! percentile interval from a bootstrap that resamples runs within each group (rliable's stratified bootstrap, one
//! stratum per group and method), and the share of runs that reach the early stop with its Wilson score interval (a
//! bootstrap of a share of 10 of 10 would be the point [1, 1]).
//!
//! Between two methods over the same seeds, rliable's probability of improvement of the first 50-lap version, with
//! the same bootstrap (each method one stratum).
//!
//! The figures: the first version whose evaluation completes `eval_laps` laps (a run that never gets there counts at
//! its budget, the epochs it ran), and the late evaluations' steps ([`RunRecord::late_steps`]).

use crate::runs::{RunRecord, LATE_VERSIONS};
use crate::stats::{bootstrap_95, bootstrap_95_lower, iqm, probability_lower, wilson_95};

/// The first version with `eval_laps` laps, or the run's budget (the epochs it ran) when it never got there.
pub fn first_full_or_budget(r: &RunRecord) -> f64 {
    r.full()
        .next()
        .map_or(r.epochs as f64, |e| e.version as f64)
}

/// Whether the run reached the early stop (its summary's, or two full evaluations where it has no summary).
pub fn reached_early_stop(r: &RunRecord) -> bool {
    r.early_stop.is_some() || r.full().nth(1).is_some()
}

/// "IQM [lo, hi]" with `digits` decimals; "-" when empty.
fn iqm_interval(values: &[f64], digits: usize) -> String {
    match (iqm(values), bootstrap_95(values, iqm)) {
        (Some(m), Some((lo, hi))) => format!("{m:.digits$} [{lo:.digits$}, {hi:.digits$}]"),
        _ => "-".into(),
    }
}

/// The header of [`interval_row`]'s table, after a first column named `first`.
pub fn interval_header(first: &str) -> String {
    format!(
        "| {first} | runs | early stop, share [Wilson 95 %] | 1st 50-lap version, IQM [95 % CI] (never: the budget) | eval steps, last {LATE_VERSIONS}, IQM [95 % CI] |\n|---|---|---|---|---|\n"
    )
}

/// One row of the interval table for the runs `of` (one group and method), first column `label`.
pub fn interval_row(label: &str, of: &[&RunRecord]) -> String {
    let stopped = of.iter().filter(|r| reached_early_stop(r)).count();
    let share = wilson_95(stopped, of.len()).map_or("-".into(), |(lo, hi)| {
        format!("{stopped} of {} [{lo:.2}, {hi:.2}]", of.len())
    });
    let first: Vec<f64> = of.iter().map(|r| first_full_or_budget(r)).collect();
    let late: Vec<f64> = of.iter().filter_map(|r| r.late_steps()).collect();
    format!(
        "| {label} | {} | {share} | {} | {} |\n",
        of.len(),
        iqm_interval(&first, 1),
        iqm_interval(&late, 1),
    )
}

/// The sentence that compares `a` (named `a_name`) with `b` on the first 50-lap version (never: the budget):
/// rliable's probability of improvement, P(a's version < b's) with ties half, and its 95 % interval; then, over the
/// seeds both have, on how many `a` got there sooner, later and as soon ([`by_seed`]).
pub fn improvement_line(a_name: &str, a: &[&RunRecord], b_name: &str, b: &[&RunRecord]) -> String {
    let first = |of: &[&RunRecord]| {
        of.iter()
            .map(|r| first_full_or_budget(r))
            .collect::<Vec<_>>()
    };
    let paired = by_seed(a, b).map_or(String::new(), |(sooner, later, same)| {
        format!(
            "; by seed ({} in common): sooner on {sooner}, later on {later}, as soon on {same}",
            sooner + later + same
        )
    });
    let (a, b) = (first(a), first(b));
    match (probability_lower(&a, &b), bootstrap_95_lower(&a, &b)) {
        (Some(p), Some((lo, hi))) => format!(
            "P({a_name} reaches its first 50-lap version before {b_name}), rliable's probability of improvement over every pair of runs: {p:.2} [{lo:.2}, {hi:.2}] (95 % CI){paired}\n"
        ),
        _ => String::new(),
    }
}

/// Over the seeds that `a` and `b` both ran, once each: on how many `a`'s first 50-lap version (never: the budget)
/// came before `b`'s, after it, and at the same version. None when no seed pairs up, or when a seed appears twice on
/// one side (then which run to pair is not defined).
pub fn by_seed(a: &[&RunRecord], b: &[&RunRecord]) -> Option<(usize, usize, usize)> {
    let once = |of: &[&RunRecord]| {
        let mut seeds = std::collections::BTreeMap::new();
        for r in of {
            if seeds.insert(r.seed?, first_full_or_budget(r)).is_some() {
                return None;
            }
        }
        Some(seeds)
    };
    let (a, b) = (once(a)?, once(b)?);
    let mut counts = (0, 0, 0);
    for (seed, x) in &a {
        match b.get(seed).map(|y| x.total_cmp(y)) {
            Some(std::cmp::Ordering::Less) => counts.0 += 1,
            Some(std::cmp::Ordering::Greater) => counts.1 += 1,
            Some(std::cmp::Ordering::Equal) => counts.2 += 1,
            None => {}
        }
    }
    (counts.0 + counts.1 + counts.2 > 0).then_some(counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_interquartile_mean_cuts_a_quarter_from_each_end() {
        // scipy.stats.trim_mean([1..10], 0.25) = mean(3..8) = 5.5; n = 5 cuts one each side; n = 3 none.
        let ten: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(iqm(&ten), Some(5.5));
        assert_eq!(iqm(&[100.0, 1.0, 2.0, 3.0, -50.0]), Some(2.0));
        assert_eq!(iqm(&[1.0, 2.0, 6.0]), Some(3.0));
        assert_eq!(iqm(&[]), None);
    }

    #[test]
    fn the_bootstrap_interval_holds_the_statistic_and_shrinks_with_agreement() {
        let spread: Vec<f64> = (0..10).map(|i| 50.0 + 15.0 * i as f64).collect();
        let (lo, hi) = bootstrap_95(&spread, iqm).unwrap();
        let m = iqm(&spread).unwrap();
        assert!(lo < m && m < hi, "{lo} {m} {hi}");
        assert!(lo >= 50.0 && hi <= 185.0);
        assert_eq!(bootstrap_95(&spread, iqm), Some((lo, hi)), "seeded");
        assert_eq!(bootstrap_95(&[7.0; 6], iqm), Some((7.0, 7.0)));
        assert_eq!(bootstrap_95(&[], iqm), None);
    }

    #[test]
    fn the_probability_of_improvement_counts_pairs_and_half_ties() {
        // Pairs (1,2) (1,3) (2,2) (2,3): three wins and a tie of four.
        assert_eq!(probability_lower(&[1.0, 2.0], &[2.0, 3.0]), Some(0.875));
        assert_eq!(probability_lower(&[5.0], &[1.0, 2.0]), Some(0.0));
        assert_eq!(probability_lower(&[], &[1.0]), None);
        assert_eq!(
            bootstrap_95_lower(&[1.0, 1.0, 1.0], &[2.0, 3.0]),
            Some((1.0, 1.0)),
            "no resample can reverse a clean separation"
        );
        let a: Vec<f64> = (0..10).map(|i| 40.0 + 10.0 * i as f64).collect();
        let b: Vec<f64> = (0..10).map(|i| 60.0 + 10.0 * i as f64).collect();
        let p = probability_lower(&a, &b).unwrap();
        let (lo, hi) = bootstrap_95_lower(&a, &b).unwrap();
        assert!(lo < p && p < hi && lo > 0.3 && hi <= 1.0, "{lo} {p} {hi}");
        assert_eq!(
            bootstrap_95_lower(&b, &a).map(|(lo, _)| lo < 1.0 - p),
            Some(true)
        );
    }

    #[test]
    fn wilson_intervals_match_the_textbook() {
        // 9 of 10: [0.596, 0.982]; 10 of 10: [0.722, 1]; 1 of 5: [0.036, 0.624].
        let close =
            |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-3 && (a.1 - b.1).abs() < 1e-3;
        assert!(close(wilson_95(9, 10).unwrap(), (0.596, 0.982)));
        assert!(close(wilson_95(10, 10).unwrap(), (0.722, 1.0)));
        assert!(close(wilson_95(1, 5).unwrap(), (0.036, 0.624)));
        assert_eq!(wilson_95(0, 0), None);
    }
}
