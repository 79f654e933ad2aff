//! Cubic not-a-knot interpolating splines (expert.md §1).
//!
//! The reference builds its track curves with CasADi `interpolant('bspline')`, whose default is the cubic
//! not-a-knot interpolant (the same curve as MATLAB `spline` and scipy `CubicSpline(bc_type='not-a-knot')`).
//! Not-a-knot makes the third derivative continuous across the second and the second-to-last knot, so the
//! spline reproduces every cubic polynomial exactly. Outside the knot range the end pieces are extended.

use nalgebra::{DMatrix, DVector};

/// A cubic spline through `(x_i, y_i)`, stored piecewise as `y_i + b_i d + c_i d² + d_i d³` with `d = x − x_i`.
#[derive(Debug, Clone)]
pub struct CubicSpline {
    knots: Vec<f64>,
    coef: Vec<[f64; 4]>,
}

/// Why a spline cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SplineError {
    #[error("a not-a-knot spline needs at least 4 points, got {0}")]
    TooFewPoints(usize),
    #[error("x and y have different lengths ({0} and {1})")]
    LengthMismatch(usize, usize),
    #[error("knots must be finite and strictly increasing")]
    BadKnots,
}

impl CubicSpline {
    /// The not-a-knot interpolant of `ys` at the strictly increasing `xs` (at least 4 points).
    pub fn not_a_knot(xs: &[f64], ys: &[f64]) -> Result<Self, SplineError> {
        let n = xs.len();
        if n != ys.len() {
            return Err(SplineError::LengthMismatch(n, ys.len()));
        }
        if n < 4 {
            return Err(SplineError::TooFewPoints(n));
        }
        if xs.iter().any(|x| !x.is_finite()) || xs.windows(2).any(|w| w[1] <= w[0]) {
            return Err(SplineError::BadKnots);
        }
        let h: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
        let slope: Vec<f64> = (0..n - 1).map(|i| (ys[i + 1] - ys[i]) / h[i]).collect();

        // Unknowns: second derivatives M_0..M_{n−1}. Built once per track, so a dense solve is fine.
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut rhs = DVector::<f64>::zeros(n);
        // Not-a-knot at x_1: the third derivative (M_{i+1} − M_i)/h_i agrees on both sides.
        a[(0, 0)] = h[1];
        a[(0, 1)] = -(h[0] + h[1]);
        a[(0, 2)] = h[0];
        for i in 1..n - 1 {
            a[(i, i - 1)] = h[i - 1];
            a[(i, i)] = 2.0 * (h[i - 1] + h[i]);
            a[(i, i + 1)] = h[i];
            rhs[i] = 6.0 * (slope[i] - slope[i - 1]);
        }
        // Not-a-knot at x_{n−2}.
        a[(n - 1, n - 3)] = h[n - 2];
        a[(n - 1, n - 2)] = -(h[n - 3] + h[n - 2]);
        a[(n - 1, n - 1)] = h[n - 3];
        let m = a.lu().solve(&rhs).ok_or(SplineError::BadKnots)?;

        let coef = (0..n - 1)
            .map(|i| {
                let (hi, mi, mj) = (h[i], m[i], m[i + 1]);
                [
                    ys[i],
                    slope[i] - hi * (2.0 * mi + mj) / 6.0,
                    mi / 2.0,
                    (mj - mi) / (6.0 * hi),
                ]
            })
            .collect();
        Ok(Self {
            knots: xs.to_vec(),
            coef,
        })
    }

    /// The piece that holds `x` (end pieces extend past the knot range) and the offset into it.
    fn piece(&self, x: f64) -> (&[f64; 4], f64) {
        let i = self
            .knots
            .partition_point(|&k| k <= x)
            .saturating_sub(1)
            .min(self.coef.len() - 1);
        (&self.coef[i], x - self.knots[i])
    }

    /// Value, first and second derivative at `x`.
    pub fn eval(&self, x: f64) -> [f64; 3] {
        let ([y, b, c, d], t) = self.piece(x);
        [
            y + t * (b + t * (c + t * d)),
            b + t * (2.0 * c + 3.0 * d * t),
            2.0 * c + 6.0 * d * t,
        ]
    }

    /// Value at `x`.
    pub fn value(&self, x: f64) -> f64 {
        self.eval(x)[0]
    }

    /// The knots.
    pub fn knots(&self) -> &[f64] {
        &self.knots
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cubic(x: f64) -> [f64; 3] {
        // 0.7 − 1.3x + 0.4x² − 0.25x³
        [
            0.7 - 1.3 * x + 0.4 * x * x - 0.25 * x * x * x,
            -1.3 + 0.8 * x - 0.75 * x * x,
            0.8 - 1.5 * x,
        ]
    }

    #[test]
    fn reproduces_any_cubic_exactly() {
        // Non-uniform knots, to exercise the general system.
        let xs: Vec<f64> = (0..12)
            .map(|i| i as f64 * 0.37 + 0.05 * (i as f64).sin())
            .collect();
        let ys: Vec<f64> = xs.iter().map(|&x| cubic(x)[0]).collect();
        let sp = CubicSpline::not_a_knot(&xs, &ys).unwrap();
        for j in 0..200 {
            let x = -0.3 + j as f64 * 0.025; // includes extrapolation on both ends
            let got = sp.eval(x);
            let want = cubic(x);
            for d in 0..3 {
                assert!(
                    (got[d] - want[d]).abs() < 1e-9,
                    "x={x} d={d}: {} vs {}",
                    got[d],
                    want[d]
                );
            }
        }
    }

    #[test]
    fn four_points_is_the_interpolating_cubic() {
        let xs = [0.0, 1.0, 2.5, 3.0];
        let ys: Vec<f64> = xs.iter().map(|&x| cubic(x)[0]).collect();
        let sp = CubicSpline::not_a_knot(&xs, &ys).unwrap();
        assert!((sp.value(1.7) - cubic(1.7)[0]).abs() < 1e-12);
    }

    #[test]
    fn interpolates_and_is_c2_on_a_non_polynomial() {
        let xs: Vec<f64> = (0..30).map(|i| i as f64 * 0.2).collect();
        let ys: Vec<f64> = xs.iter().map(|&x| x.sin()).collect();
        let sp = CubicSpline::not_a_knot(&xs, &ys).unwrap();
        for (x, y) in xs.iter().zip(&ys) {
            assert!((sp.value(*x) - y).abs() < 1e-13);
        }
        for &x in &xs[1..29] {
            let (l, r) = (sp.eval(x - 1e-9), sp.eval(x + 1e-9));
            assert!((l[1] - r[1]).abs() < 1e-7 && (l[2] - r[2]).abs() < 1e-6);
        }
        // Accuracy of the interpolant for a smooth function (O(h⁴)).
        assert!((sp.value(2.05) - 2.05f64.sin()).abs() < 1e-4);
        assert!((sp.eval(2.05)[1] - 2.05f64.cos()).abs() < 1e-3);
    }

    #[test]
    fn rejects_bad_input() {
        assert_eq!(
            CubicSpline::not_a_knot(&[0.0, 1.0, 2.0], &[0.0; 3]).unwrap_err(),
            SplineError::TooFewPoints(3)
        );
        assert!(CubicSpline::not_a_knot(&[0.0, 1.0, 1.0, 2.0], &[0.0; 4]).is_err());
    }
}
