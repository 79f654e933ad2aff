//! The track as the MPC sees it: splines of the centreline and of the tightened boundaries, the contouring and
//! lag errors with their Gauss–Newton Jacobians, and the linearised track slab (expert.md §1, §4, §5).

use cabc_sim::track::Track;

use crate::spline::{CubicSpline, SplineError};

/// Cubic not-a-knot splines of the centreline and of the inside (left, e_y = +w) and outside (right, e_y = −w)
/// tightened boundaries, w = half_width − tightening, over S_i = i·L/(n−1).
#[derive(Debug, Clone)]
pub struct TrackSplines {
    length: f64,
    center: [CubicSpline; 2],
    inside: [CubicSpline; 2],
    outside: [CubicSpline; 2],
}

/// The contouring and lag errors at one (X, Y, s) and their gradients with respect to (X, Y, s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContourErrors {
    /// Contouring (lateral) error e_c.
    pub e_c: f64,
    /// Lag error e_l (minus the along-track offset).
    pub e_l: f64,
    /// ∂e_c/∂(X, Y, s).
    pub grad_c: [f64; 3],
    /// ∂e_l/∂(X, Y, s).
    pub grad_l: [f64; 3],
}

/// The soft track constraint at one stage: `lo − σ ≤ normal·(X, Y) ≤ hi + σ`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    /// c = p_in − p_out (not normalised, |c| ≈ 0.9 m).
    pub normal: [f64; 2],
    /// c·p_out.
    pub lo: f64,
    /// c·p_in.
    pub hi: f64,
}

impl TrackSplines {
    /// Sample the track at `n` equally spaced progress values (both ends included) and interpolate.
    pub fn new(track: &Track, n: usize, tightening: f64) -> Result<Self, SplineError> {
        let length = track.length();
        let w = track.half_width() - tightening;
        let s: Vec<f64> = (0..n)
            .map(|i| i as f64 * length / (n - 1).max(1) as f64)
            .collect();
        let curve = |e_y: f64| -> Result<[CubicSpline; 2], SplineError> {
            let pts: Vec<_> = s
                .iter()
                .map(|&si| track.local_to_global(si, e_y, 0.0))
                .collect();
            let xs: Vec<f64> = pts.iter().map(|p| p.x).collect();
            let ys: Vec<f64> = pts.iter().map(|p| p.y).collect();
            Ok([
                CubicSpline::not_a_knot(&s, &xs)?,
                CubicSpline::not_a_knot(&s, &ys)?,
            ])
        };
        Ok(Self {
            length,
            center: curve(0.0)?,
            inside: curve(w)?,
            outside: curve(-w)?,
        })
    }

    /// Track length L.
    pub fn length(&self) -> f64 {
        self.length
    }

    /// Every lookup uses C `fmod(s, L)`, like the reference (not periodic: s < 0 stays negative).
    fn wrap(&self, s: f64) -> f64 {
        s % self.length
    }

    /// Centreline point at progress s.
    pub fn center(&self, s: f64) -> [f64; 2] {
        let s = self.wrap(s);
        [self.center[0].value(s), self.center[1].value(s)]
    }

    /// e_c, e_l and their gradients at global position (x, y) and progress s (reference point z = 0: the midpoint
    /// m(s) of the two tightened boundaries; tangent angle θ(s) from the centreline).
    pub fn errors(&self, x: f64, y: f64, s: f64) -> ContourErrors {
        let s = self.wrap(s);
        let [_, xc1, xc2] = self.center[0].eval(s);
        let [_, yc1, yc2] = self.center[1].eval(s);
        let [xi, xi1, _] = self.inside[0].eval(s);
        let [yi, yi1, _] = self.inside[1].eval(s);
        let [xo, xo1, _] = self.outside[0].eval(s);
        let [yo, yo1, _] = self.outside[1].eval(s);
        let (mx, my, mx1, my1) = (
            (xi + xo) / 2.0,
            (yi + yo) / 2.0,
            (xi1 + xo1) / 2.0,
            (yi1 + yo1) / 2.0,
        );
        let theta = yc1.atan2(xc1);
        let dtheta = (xc1 * yc2 - yc1 * xc2) / (xc1 * xc1 + yc1 * yc1);
        let (sn, cs) = theta.sin_cos();
        let (dx, dy) = (x - mx, y - my);
        let e_c = sn * dx - cs * dy;
        let e_l = -cs * dx - sn * dy;
        ContourErrors {
            e_c,
            e_l,
            grad_c: [sn, -cs, -dtheta * e_l - sn * mx1 + cs * my1],
            grad_l: [-cs, -sn, dtheta * e_c + cs * mx1 + sn * my1],
        }
    }

    /// The track slab linearised at progress s.
    pub fn slab(&self, s: f64) -> Slab {
        let s = self.wrap(s);
        let p_in = [self.inside[0].value(s), self.inside[1].value(s)];
        let p_out = [self.outside[0].value(s), self.outside[1].value(s)];
        let c = [p_in[0] - p_out[0], p_in[1] - p_out[1]];
        let dot = |p: [f64; 2]| c[0] * p[0] + c[1] * p[1];
        Slab {
            normal: c,
            lo: dot(p_out),
            hi: dot(p_in),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn splines() -> (Track, TrackSplines) {
        let t = Track::l_track_barc();
        let sp = TrackSplines::new(&t, 100, 0.1).unwrap();
        (t, sp)
    }

    #[test]
    fn splines_reproduce_the_samples_and_the_straight() {
        let (t, sp) = splines();
        assert!((sp.length() - 17.461412207630154).abs() < 1e-12);
        for i in 0..100 {
            let s = i as f64 * sp.length() / 99.0;
            let p = t.local_to_global(s, 0.0, 0.0);
            let c = sp.center(s);
            // s = L wraps to 0 (fmod), where the track point is (0, 0) as well.
            assert!(
                (c[0] - p.x).abs() < 1e-9 && (c[1] - p.y).abs() < 1e-9,
                "s={s}: {c:?} vs {p:?}"
            );
        }
        let c = sp.center(1.0);
        assert!((c[0] - 1.0).abs() < 1e-3 && c[1].abs() < 1e-3, "{c:?}");
        let e = sp.errors(1.0, 0.0, 1.0);
        assert!(e.e_c.abs() < 1e-3 && e.e_l.abs() < 1e-3, "{e:?}");
    }

    #[test]
    fn error_signs_and_gradients() {
        let (_, sp) = splines();
        // On the first straight (θ = 0): left of the centreline ⇒ e_c < 0; ahead of s ⇒ e_l < 0.
        let e = sp.errors(1.2, 0.3, 1.0);
        assert!(
            (e.e_c + 0.3).abs() < 1e-3 && (e.e_l + 0.2).abs() < 1e-3,
            "{e:?}"
        );
        // Gradients against central differences, on an arc.
        let (x, y, s) = (2.9, 1.4, 3.9);
        let e = sp.errors(x, y, s);
        let h = 1e-6;
        let fd = |f: &dyn Fn(f64) -> ContourErrors| {
            let (p, m) = (f(h), f(-h));
            [(p.e_c - m.e_c) / (2.0 * h), (p.e_l - m.e_l) / (2.0 * h)]
        };
        let d = [
            fd(&|d| sp.errors(x + d, y, s)),
            fd(&|d| sp.errors(x, y + d, s)),
            fd(&|d| sp.errors(x, y, s + d)),
        ];
        for (j, [dc, dl]) in d.into_iter().enumerate() {
            assert!(
                (e.grad_c[j] - dc).abs() < 1e-6,
                "c {j}: {} vs {dc}",
                e.grad_c[j]
            );
            assert!(
                (e.grad_l[j] - dl).abs() < 1e-6,
                "l {j}: {} vs {dl}",
                e.grad_l[j]
            );
        }
    }

    #[test]
    fn slab_brackets_the_tightened_track() {
        let (t, sp) = splines();
        for s in [0.5, 3.0, 7.5, 10.0, 15.5] {
            let sl = sp.slab(s);
            let dot = |p: cabc_sim::track::Pose| sl.normal[0] * p.x + sl.normal[1] * p.y;
            let mid = dot(t.local_to_global(s, 0.0, 0.0));
            assert!(sl.lo < mid && mid < sl.hi);
            assert!((dot(t.local_to_global(s, 0.45, 0.0)) - sl.hi).abs() < 1e-3);
            assert!((dot(t.local_to_global(s, -0.45, 0.0)) - sl.lo).abs() < 1e-3);
            let n = (sl.normal[0].hypot(sl.normal[1]) - 0.9).abs();
            assert!(n < 1e-3, "|c| − 0.9 = {n}");
        }
    }
}
