//! The numerics of the statistics over seeds, on plain numbers: the median (and "median [min–max]"), the
//! interquartile mean, the stratified bootstrap's 95 % interval, the Wilson score interval of a share and the
//! probability of improvement of one group over another.

use cabc_proto::stats::median_of_middles_sorted as median_of_sorted;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The median of `values` (the mean of the middle two for an even count, unlike `cabc_proto::stats::median`'s
/// nearest rank: a median of versions over two seeds lies between them); None when empty.
pub fn median(values: &[f64]) -> Option<f64> {
    cabc_proto::stats::median_of_middles(values)
}

fn sorted(values: &[f64]) -> Vec<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v
}

/// "median [min–max]" of `values` with `digits` decimals; "-" when empty.
pub fn median_range(values: &[f64], digits: usize) -> String {
    let v = sorted(values);
    let Some(median) = median_of_sorted(&v) else {
        return "-".into();
    };
    match v.as_slice() {
        [lo, _, ..] => format!(
            "{median:.digits$} [{lo:.digits$}–{:.digits$}]",
            v[v.len() - 1]
        ),
        _ => format!("{median:.digits$}"),
    }
}

/// Bootstrap resamples per interval.
pub const BOOTSTRAP_RESAMPLES: usize = 10_000;
/// The bootstrap's seed: the same runs give the same interval.
const BOOTSTRAP_SEED: u64 = 0x5eed;
/// The two-sided 95 % normal quantile of the Wilson interval.
const Z95: f64 = 1.959_963_984_540_054;

/// The interquartile mean: the mean of the values left when a quarter (rounded down) is cut from each end, as
/// `scipy.stats.trim_mean(values, 0.25)`, which rliable uses; None when empty.
pub fn iqm(values: &[f64]) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let cut = v.len() / 4;
    let middle = &v[cut..v.len() - cut];
    (!middle.is_empty()).then(|| middle.iter().sum::<f64>() / middle.len() as f64)
}

/// The 95 % percentile bootstrap interval of `statistic` over `values`: [`BOOTSTRAP_RESAMPLES`] resamples of the
/// values with replacement (the runs of one group: one stratum), seeded; None when empty.
pub fn bootstrap_95(values: &[f64], statistic: fn(&[f64]) -> Option<f64>) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(BOOTSTRAP_SEED);
    let mut resample = vec![0.0; values.len()];
    let stats: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .filter_map(|_| {
            for x in resample.iter_mut() {
                *x = values[rng.gen_range(0..values.len())];
            }
            statistic(&resample)
        })
        .collect();
    percentiles_95(stats)
}

/// The 2.5th and 97.5th percentiles of the bootstrap's statistics; None when there are none.
fn percentiles_95(mut stats: Vec<f64>) -> Option<(f64, f64)> {
    if stats.is_empty() {
        return None;
    }
    stats.sort_by(f64::total_cmp);
    let at = |q: f64| stats[((q * (stats.len() - 1) as f64).round() as usize).min(stats.len() - 1)];
    Some((at(0.025), at(0.975)))
}

/// rliable's probability of improvement where lower is better: over every pair (x of `a`, y of `b`), the share with
/// x < y, ties counted half (the Mann-Whitney U statistic over the pairs); None when either is empty.
pub fn probability_lower(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let wins: f64 = a
        .iter()
        .flat_map(|x| {
            b.iter().map(move |y| match x.total_cmp(y) {
                std::cmp::Ordering::Less => 1.0,
                std::cmp::Ordering::Equal => 0.5,
                std::cmp::Ordering::Greater => 0.0,
            })
        })
        .sum();
    Some(wins / (a.len() * b.len()) as f64)
}

/// The 95 % percentile bootstrap interval of [`probability_lower`]: each of `a` and `b` resampled with
/// replacement on its own (two strata), [`BOOTSTRAP_RESAMPLES`] times, seeded; None when either is empty.
pub fn bootstrap_95_lower(a: &[f64], b: &[f64]) -> Option<(f64, f64)> {
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(BOOTSTRAP_SEED);
    let (mut ra, mut rb) = (vec![0.0; a.len()], vec![0.0; b.len()]);
    let stats = (0..BOOTSTRAP_RESAMPLES)
        .filter_map(|_| {
            for (resample, values) in [(&mut ra, a), (&mut rb, b)] {
                for x in resample.iter_mut() {
                    *x = values[rng.gen_range(0..values.len())];
                }
            }
            probability_lower(&ra, &rb)
        })
        .collect();
    percentiles_95(stats)
}

/// The Wilson score 95 % interval of a share of `k` successes in `n` trials; None when n = 0.
pub fn wilson_95(k: usize, n: usize) -> Option<(f64, f64)> {
    if n == 0 {
        return None;
    }
    let (k, n) = (k as f64, n as f64);
    let p = k / n;
    let z2 = Z95 * Z95;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = Z95 * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / (1.0 + z2 / n);
    Some(((centre - half).max(0.0), (centre + half).min(1.0)))
}
