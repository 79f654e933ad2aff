//! Summary statistics of samples (lap times, solve times): the one mean / standard deviation and percentile of
//! the workspace, so that every report computes them the same way.
//!
//! Percentiles are nearest-rank on the sorted sample: the q-quantile of n values is `sorted[round((n − 1)·q)]`, an
//! element of the sample (no interpolation), so the median of an even count is the upper of the two middles.
//! Sorting uses `f64::total_cmp`, so NaN sorts last instead of panicking.

/// The arithmetic mean; `None` for an empty sample.
pub fn mean(xs: &[f64]) -> Option<f64> {
    (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64)
}

/// Mean and population standard deviation (divided by n, not n − 1); `None` for an empty sample.
pub fn mean_std(xs: &[f64]) -> Option<(f64, f64)> {
    let m = mean(xs)?;
    let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / xs.len() as f64;
    Some((m, var.sqrt()))
}

/// The nearest-rank q-quantile (q in [0, 1], clamped) of an already sorted sample; `None` when it is empty.
pub fn percentile_sorted(sorted: &[f64], q: f64) -> Option<f64> {
    let last = sorted.len().checked_sub(1)?;
    let q = if q.is_nan() { 0.5 } else { q.clamp(0.0, 1.0) };
    Some(sorted[(last as f64 * q).round() as usize])
}

/// Sorts `xs` in place and returns its nearest-rank q-quantile; `None` when it is empty.
pub fn percentile(xs: &mut [f64], q: f64) -> Option<f64> {
    xs.sort_unstable_by(f64::total_cmp);
    percentile_sorted(xs, q)
}

/// Sorts `xs` in place and returns its nearest-rank median (`percentile(xs, 0.5)`).
pub fn median(xs: &mut [f64]) -> Option<f64> {
    percentile(xs, 0.5)
}

/// The median of `values` with the mean of the two middles for an even count (see
/// [`median_of_middles_sorted`]); `None` when it is empty.
pub fn median_of_middles(values: &[f64]) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    median_of_middles_sorted(&sorted)
}

/// The median of an already sorted sample with the mean of the two middles for an even count (not nearest-rank: a
/// median over two seeds' versions or run times lies between them); `None` when it is empty.
pub fn median_of_middles_sorted(sorted: &[f64]) -> Option<f64> {
    let n = sorted.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(sorted[n / 2]),
        _ => Some((sorted[n / 2 - 1] + sorted[n / 2]) / 2.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_samples_have_no_statistics() {
        assert_eq!(mean(&[]), None);
        assert_eq!(mean_std(&[]), None);
        assert_eq!(percentile(&mut [], 0.5), None);
        assert_eq!(median(&mut []), None);
    }

    #[test]
    fn mean_and_population_std() {
        assert_eq!(mean_std(&[3.0]), Some((3.0, 0.0)));
        let (m, s) = mean_std(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
        assert_eq!((m, s), (5.0, 2.0));
    }

    #[test]
    fn nearest_rank_percentiles() {
        let mut xs: Vec<f64> = (1..=101).rev().map(f64::from).collect();
        assert_eq!(median(&mut xs), Some(51.0));
        assert_eq!(xs[0], 1.0, "sorted in place");
        assert_eq!(percentile_sorted(&xs, 0.99), Some(100.0));
        assert_eq!(percentile_sorted(&xs, 0.0), Some(1.0));
        assert_eq!(percentile_sorted(&xs, 1.0), Some(101.0));
        assert_eq!(percentile_sorted(&xs, 7.0), Some(101.0), "q is clamped");
        // Even count: round(1.5) = 2, the upper middle.
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
    }

    #[test]
    fn nan_sorts_last() {
        let mut xs = [f64::NAN, 1.0, 2.0];
        assert_eq!(percentile(&mut xs, 0.0), Some(1.0));
        assert!(percentile_sorted(&xs, 1.0).unwrap().is_nan());
    }
}
