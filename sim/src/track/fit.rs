//! A closed centre line given as points (an F1TENTH CSV) made into pieces: a periodic cubic spline through the
//! points, its tangent's heading sampled along its arc length, and that heading's change over each piece of about
//! [`PIECE_LENGTH`] taken as the piece's constant curvature. The pieces' curvature is the spline's averaged over
//! 5 cm: continuous to within that step, and the heading after the last piece is the first one's plus the curve's
//! total turning exactly. The position the pieces end at is then closed onto the start by the least change of the
//! pieces' curvatures (three constraints: heading, x, y; Gauss-Newton, a few iterations).

use super::TrackPiece;
use std::f64::consts::PI;

/// The length of a fitted piece (m): the step of the fitted curvature.
pub const PIECE_LENGTH: f64 = 0.05;

/// One point of a centre line: its position (m) and where it came from (the file's line).
#[derive(Clone, Copy, Debug)]
pub struct CentrePoint {
    pub x: f64,
    pub y: f64,
    pub line: usize,
}

/// Why a centre line could not be fitted; `line` is the file's line nearest the fault.
#[derive(Debug, Clone, PartialEq)]
pub struct FitError {
    pub line: Option<usize>,
    pub why: String,
}

/// A fitted centre line: pieces from the pose (0, 0, 0) (the first point, heading along the curve), the arc
/// length at each input point, and the curvature's largest magnitude with the line nearest it.
#[derive(Debug, Clone)]
pub struct Fitted {
    pub pieces: Vec<TrackPiece>,
    /// Arc length at each input point (the first is 0).
    pub s_of_point: Vec<f64>,
    pub lines: Vec<usize>,
}

impl Fitted {
    /// The input line nearest arc length `s`.
    pub fn line_at(&self, s: f64) -> usize {
        let i = self.s_of_point.partition_point(|&p| p <= s).max(1) - 1;
        self.lines[i]
    }
}

fn fail(line: Option<usize>, why: String) -> FitError {
    FitError { line, why }
}

/// A periodic cubic spline through (t_i, v_i), period `period` (t_0 = 0 < t_1 < ... < t_{n-1} < period).
struct Periodic {
    t: Vec<f64>,
    v: Vec<f64>,
    m: Vec<f64>,
    period: f64,
}

impl Periodic {
    fn new(t: &[f64], v: &[f64], period: f64) -> Periodic {
        let n = t.len();
        let h = |i: usize| {
            if i + 1 < n {
                t[i + 1] - t[i]
            } else {
                period - t[n - 1]
            }
        };
        let val = |i: usize| v[i % n];
        // h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1} = 6 (slope_i - slope_{i-1}), cyclic.
        let (mut sub, mut diag, mut sup, mut rhs) =
            (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for i in 0..n {
            let (hp, hi) = (h((i + n - 1) % n), h(i));
            sub[i] = hp;
            diag[i] = 2.0 * (hp + hi);
            sup[i] = hi;
            rhs[i] = 6.0 * ((val(i + 1) - v[i]) / hi - (v[i] - val(i + n - 1)) / hp);
        }
        let m = cyclic_tridiagonal(&sub, &diag, &sup, &rhs);
        Periodic {
            t: t.to_vec(),
            v: v.to_vec(),
            m,
            period,
        }
    }

    /// Value, first and second derivative on interval `i` at offset `u` from its start.
    fn eval(&self, i: usize, u: f64) -> (f64, f64) {
        let n = self.t.len();
        let j = (i + 1) % n;
        let h = if i + 1 < n {
            self.t[i + 1] - self.t[i]
        } else {
            self.period - self.t[n - 1]
        };
        let (mi, mj, vi, vj) = (self.m[i], self.m[j], self.v[i], self.v[j]);
        let w = h - u;
        let d1 =
            -mi * w * w / (2.0 * h) + mj * u * u / (2.0 * h) + (vj - vi) / h - (mj - mi) * h / 6.0;
        let d2 = (mi * w + mj * u) / h;
        (d1, d2)
    }
}

/// Solves a cyclic tridiagonal system (row i: sub[i] x_{i-1} + diag[i] x_i + sup[i] x_{i+1} = rhs[i], indices mod
/// n) by Sherman-Morrison over the Thomas algorithm. The spline's system is strictly diagonally dominant.
fn cyclic_tridiagonal(sub: &[f64], diag: &[f64], sup: &[f64], rhs: &[f64]) -> Vec<f64> {
    let n = diag.len();
    let (alpha, beta) = (sup[n - 1], sub[0]); // A[n-1][0] and A[0][n-1]
    let gamma = -diag[0];
    let mut b = diag.to_vec();
    b[0] -= gamma;
    b[n - 1] -= alpha * beta / gamma;
    let thomas = |r: &[f64]| -> Vec<f64> {
        let (mut c, mut d) = (vec![0.0; n], vec![0.0; n]);
        c[0] = sup[0] / b[0];
        d[0] = r[0] / b[0];
        for i in 1..n {
            let den = b[i] - sub[i] * c[i - 1];
            c[i] = if i + 1 < n { sup[i] / den } else { 0.0 };
            d[i] = (r[i] - sub[i] * d[i - 1]) / den;
        }
        let mut x = vec![0.0; n];
        x[n - 1] = d[n - 1];
        for i in (0..n - 1).rev() {
            x[i] = d[i] - c[i] * x[i + 1];
        }
        x
    };
    let x = thomas(rhs);
    let mut u = vec![0.0; n];
    u[0] = gamma;
    u[n - 1] = alpha;
    let z = thomas(&u);
    let factor = (x[0] + beta * x[n - 1] / gamma) / (1.0 + z[0] + beta * z[n - 1] / gamma);
    x.iter().zip(&z).map(|(xi, zi)| xi - factor * zi).collect()
}

/// The centre line through `points` (closed: the last joins the first), as pieces of about [`PIECE_LENGTH`].
pub fn fit(points: &[CentrePoint]) -> Result<Fitted, FitError> {
    let mut points = points.to_vec();
    if points.len() >= 2 {
        let (a, b) = (points[0], points[points.len() - 1]);
        if (a.x - b.x).hypot(a.y - b.y) < 1e-9 {
            points.pop(); // a file that repeats its first point at the end
        }
    }
    let n = points.len();
    if n < 4 {
        return Err(fail(
            points.last().map(|p| p.line),
            format!("too few points: {n}, a closed centre line needs at least 4"),
        ));
    }
    // Chord lengths: t_i, and the closing chord.
    let mut t = vec![0.0; n];
    for i in 1..n {
        let d = (points[i].x - points[i - 1].x).hypot(points[i].y - points[i - 1].y);
        if d.is_nan() || d <= 1e-9 {
            return Err(fail(
                Some(points[i].line),
                "this point repeats the one before it".into(),
            ));
        }
        t[i] = t[i - 1] + d;
    }
    let gap = (points[0].x - points[n - 1].x).hypot(points[0].y - points[n - 1].y);
    let mut spacing: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    spacing.sort_by(f64::total_cmp);
    let median = spacing[spacing.len() / 2];
    if gap > 4.0 * median {
        return Err(fail(
            Some(points[n - 1].line),
            format!(
                "not closed: the last point is {gap:.3} m from the first, and the points are {median:.3} m apart \
                 (a centre line is closed: its last point comes back near its first)"
            ),
        ));
    }
    let period = t[n - 1] + gap;
    let xs: Vec<f64> = points.iter().map(|p| p.x).collect();
    let ys: Vec<f64> = points.iter().map(|p| p.y).collect();
    let (sx, sy) = (
        Periodic::new(&t, &xs, period),
        Periodic::new(&t, &ys, period),
    );

    // The tangent's heading along the arc length, sampled finely (Simpson's rule for the arc length).
    let mut s_samples = vec![0.0];
    let mut heading = Vec::new();
    let mut s_of_point = Vec::with_capacity(n);
    let tangent = |i: usize, u: f64| {
        let (dx, _) = sx.eval(i, u);
        let (dy, _) = sy.eval(i, u);
        (dx, dy)
    };
    let (dx0, dy0) = tangent(0, 0.0);
    heading.push(dy0.atan2(dx0));
    for i in 0..n {
        s_of_point.push(*s_samples.last().unwrap_or(&0.0));
        let h = if i + 1 < n { t[i + 1] - t[i] } else { gap };
        let k = ((h / (PIECE_LENGTH / 5.0)).ceil() as usize).clamp(2, 100_000);
        let du = h / k as f64;
        for j in 0..k {
            let (u0, um, u1) = (j as f64 * du, (j as f64 + 0.5) * du, (j + 1) as f64 * du);
            let speed = |u: f64| {
                let (a, b) = tangent(i, u);
                a.hypot(b)
            };
            let ds = du / 6.0 * (speed(u0) + 4.0 * speed(um) + speed(u1));
            let (a, b) = tangent(i, u1);
            if a.hypot(b).is_nan() || a.hypot(b) <= 1e-12 {
                return Err(fail(
                    Some(points[i].line),
                    "the centre line has a cusp here (its direction is undefined)".into(),
                ));
            }
            let prev = *heading.last().unwrap_or(&0.0);
            let mut th = b.atan2(a);
            th += 2.0 * PI * ((prev - th) / (2.0 * PI)).round();
            if (th - prev).abs() > PI / 2.0 {
                return Err(fail(
                    Some(points[i].line),
                    "the centre line turns back on itself here".into(),
                ));
            }
            heading.push(th);
            s_samples.push(s_samples.last().unwrap_or(&0.0) + ds);
        }
    }
    let length = *s_samples.last().unwrap_or(&0.0);
    let turning = heading.last().unwrap_or(&0.0) - heading[0];
    if ((turning.abs() - 2.0 * PI) / (2.0 * PI)).abs() > 0.05 {
        return Err(fail(
            None,
            format!(
                "the centre line turns {:.0} degrees in all, not 360: it crosses itself",
                turning.to_degrees()
            ),
        ));
    }
    let heading_at = |s: f64| {
        let k = s_samples
            .partition_point(|&x| x <= s)
            .clamp(1, s_samples.len() - 1);
        let (s0, s1) = (s_samples[k - 1], s_samples[k]);
        let f = if s1 > s0 { (s - s0) / (s1 - s0) } else { 0.0 };
        heading[k - 1] + f * (heading[k] - heading[k - 1])
    };
    let count = ((length / PIECE_LENGTH).round() as usize).max(8);
    let ds = length / count as f64;
    let mut curvature: Vec<f64> = (0..count)
        .map(|j| {
            let (a, b) = (
                j as f64 * ds,
                if j + 1 == count {
                    length
                } else {
                    (j + 1) as f64 * ds
                },
            );
            (heading_at(b) - heading_at(a)) / ds
        })
        .collect();
    // The whole turning is ±2π exactly, so the heading closes; close the position by the least change of
    // curvature that keeps the turning.
    let total = 2.0 * PI * turning.signum();
    let sum: f64 = curvature.iter().sum::<f64>() * ds;
    let shift = (total - sum) / (count as f64 * ds);
    curvature.iter_mut().for_each(|k| *k += shift);
    for _ in 0..8 {
        let (ex, ey, mids) = integrate(&curvature, ds);
        if ex.hypot(ey) < 1e-10 {
            break;
        }
        // Rows: heading (Σ δ ds = 0), x, y; d end / d κ_j = ds · rot90(end − m_j).
        let rows: Vec<[f64; 3]> = mids
            .iter()
            .map(|&(mx, my)| [ds, -(ey - my) * ds, (ex - mx) * ds])
            .collect();
        let mut a = [[0.0; 3]; 3];
        for r in &rows {
            for p in 0..3 {
                for q in 0..3 {
                    a[p][q] += r[p] * r[q];
                }
            }
        }
        let Some(lambda) = solve3(a, [0.0, -ex, -ey]) else {
            break;
        };
        for (k, r) in curvature.iter_mut().zip(&rows) {
            *k += r[0] * lambda[0] + r[1] * lambda[1] + r[2] * lambda[2];
        }
    }
    let pieces = curvature
        .iter()
        .map(|&k| TrackPiece {
            length: ds,
            radius: if k.abs() < 1e-9 { 0.0 } else { 1.0 / k },
        })
        .collect();
    Ok(Fitted {
        pieces,
        s_of_point,
        lines: points.iter().map(|p| p.line).collect(),
    })
}

/// The end of the pieces of constant curvature `curvature`, each `ds` long, from the pose (0, 0, 0), and the
/// middle of each piece.
fn integrate(curvature: &[f64], ds: f64) -> (f64, f64, Vec<(f64, f64)>) {
    let (mut x, mut y, mut psi) = (0.0, 0.0, 0.0f64);
    let mut mids = Vec::with_capacity(curvature.len());
    let advance = |x: f64, y: f64, psi: f64, k: f64, l: f64| {
        if k.abs() < 1e-9 {
            (x + l * psi.cos(), y + l * psi.sin(), psi)
        } else {
            let a = psi + k * l;
            (
                x + (a.sin() - psi.sin()) / k,
                y - (a.cos() - psi.cos()) / k,
                a,
            )
        }
    };
    for &k in curvature {
        let (mx, my, _) = advance(x, y, psi, k, 0.5 * ds);
        mids.push((mx, my));
        (x, y, psi) = advance(x, y, psi, k, ds);
    }
    (x, y, mids)
}

/// Solves the 3x3 system `a z = b` (Cramer's rule); None when it is singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.is_nan() || d.abs() <= 1e-300 {
        return None;
    }
    let mut z = [0.0; 3];
    for (c, zc) in z.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][c] = b[r];
        }
        *zc = det(m) / d;
    }
    Some(z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(r: f64, n: usize) -> Vec<CentrePoint> {
        (0..n)
            .map(|i| {
                let a = 2.0 * PI * i as f64 / n as f64;
                CentrePoint {
                    x: r * a.cos(),
                    y: r * a.sin(),
                    line: i + 2,
                }
            })
            .collect()
    }

    #[test]
    fn a_circles_pieces_turn_with_its_radius_and_close() {
        let f = fit(&circle(3.0, 60)).unwrap();
        let length: f64 = f.pieces.iter().map(|p| p.length).sum();
        assert!((length - 2.0 * PI * 3.0).abs() < 1e-3, "{length}");
        for p in &f.pieces {
            assert!((p.radius / 3.0 - 1.0).abs() < 2e-3, "{p:?}");
        }
        let k: Vec<f64> = f.pieces.iter().map(|p| 1.0 / p.radius).collect();
        let (ex, ey, _) = integrate(&k, f.pieces[0].length);
        assert!(ex.hypot(ey) < 1e-9);
    }

    #[test]
    fn an_open_line_and_a_figure_eight_are_refused() {
        let mut open = circle(3.0, 60);
        open.truncate(40);
        let e = fit(&open).unwrap_err();
        assert!(e.why.contains("not closed"), "{e:?}");
        assert_eq!(e.line, Some(41));
        let eight: Vec<CentrePoint> = (0..80)
            .map(|i| {
                let a = 2.0 * PI * i as f64 / 80.0;
                CentrePoint {
                    x: 5.0 * a.sin(),
                    y: 3.0 * (2.0 * a).sin(),
                    line: i + 1,
                }
            })
            .collect();
        let e = fit(&eight).unwrap_err();
        assert!(e.why.contains("crosses itself"), "{e:?}");
        let e = fit(&circle(3.0, 3)).unwrap_err();
        assert!(e.why.contains("too few points"), "{e:?}");
    }
}
