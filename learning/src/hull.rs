//! Exact convex-hull membership: is x in conv(S)? (eq. (19), the test of Proposition 1.)
//!
//! It is the linear feasibility problem
//!
//! ```text
//!     find lambda >= 0 with  sum_i lambda_i (s_i - x) = 0,  sum_i lambda_i = 1,
//! ```
//!
//! solved by phase 1 of the revised simplex method in f64: d + 1 rows, one column per point, an artificial
//! variable per row; x is inside iff the artificials can be driven to zero. With d + 1 = 7 rows the basis inverse is
//! 7 x 7, so an iteration costs one pass over the points (pricing), which is what makes this fast. Points are
//! shifted to x and scaled by the neighbourhood radius, so the tolerances are relative to it.
//!
//! Termination: Dantzig's rule, switching to Bland's rule (which cannot cycle) after a run of degenerate pivots.
//! The verdict comes with a certificate that is checked: a convex combination (inside) or a separating direction w
//! with w . (s_i - x) <= tol for every point and the phase-1 objective > tol (outside).

/// Feasibility tolerance on the scaled problem.
const TOL: f64 = 1e-9;
/// Pivot element tolerance.
const PIVOT_TOL: f64 = 1e-11;
/// Degenerate pivots in a row before Bland's rule takes over.
const DEGENERATE_RUN: usize = 20;
/// Gilbert iterations tried before the simplex.
const GILBERT_STEPS: usize = 24;
/// Columns priced per block in partial pricing.
const PRICING_BLOCK: usize = 512;
/// Refactorise the basis inverse every this many pivots.
const REFACTOR_EVERY: usize = 50;

/// The verdict of [`HullTester::contains`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Membership {
    Inside,
    Outside,
    /// The simplex did not settle within its iteration limit (never seen in tests; treated as "stays in D?").
    Undecided,
}

/// Scratch space reused across queries (one per thread).
#[derive(Default)]
pub struct HullTester {
    /// Columns (s_i - x) / scale ++ [1], row-major by point: m x r.
    cols: Vec<f64>,
    binv: Vec<f64>,
    basis: Vec<usize>,
    xb: Vec<f64>,
    in_basis: Vec<bool>,
    y: Vec<f64>,
    u: Vec<f64>,
    /// Simplex iterations of the last query.
    pub iterations: usize,
}

impl HullTester {
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether `x` lies in the convex hull of `points` (each of `x.len()` coordinates), `scale` being a length of
    /// the neighbourhood (the radius): tolerances apply after dividing by it.
    pub fn contains<'a>(
        &mut self,
        x: &[f64],
        points: impl Iterator<Item = &'a [f64]>,
        scale: f64,
    ) -> Membership {
        let d = x.len();
        let r = d + 1;
        self.cols.clear();
        let inv = 1.0 / scale;
        // Cheap exits: x outside the bounding box of S is outside the hull; x equal to a point is inside.
        let mut lo = vec![f64::INFINITY; d];
        let mut hi = vec![f64::NEG_INFINITY; d];
        let mut equal = false;
        for p in points {
            let mut same = true;
            for k in 0..d {
                let v = (p[k] - x[k]) * inv;
                self.cols.push(v);
                lo[k] = lo[k].min(v);
                hi[k] = hi[k].max(v);
                same &= v.abs() <= TOL;
            }
            self.cols.push(1.0);
            equal |= same;
        }
        let m = self.cols.len() / r;
        self.iterations = 0;
        if m == 0 || (0..d).any(|k| lo[k] > TOL || hi[k] < -TOL) {
            return Membership::Outside;
        }
        if equal {
            return Membership::Inside;
        }
        // Cheap exit for most outside points: Gilbert's nearest-point iteration from the centroid. p is a point of
        // conv(S) (relative to x); when every point has p . (s_j - x) > 0, the plane through x normal to p
        // separates (an exact certificate). Inconclusive after GILBERT_STEPS: the simplex decides.
        let mut p = vec![0.0; d];
        for col in self.cols.chunks_exact(r) {
            for k in 0..d {
                p[k] += col[k] / m as f64;
            }
        }
        for _ in 0..GILBERT_STEPS {
            let (mut best, mut best_j) = (f64::INFINITY, 0);
            for (j, col) in self.cols.chunks_exact(r).enumerate() {
                let dot: f64 = (0..d).map(|k| p[k] * col[k]).sum();
                if dot < best {
                    best = dot;
                    best_j = j;
                }
            }
            if best > 0.0 {
                return Membership::Outside;
            }
            // Line search towards the support point s: p + t (s - p), minimising |.|.
            let sp = &self.cols[best_j * r..best_j * r + d];
            let diff: Vec<f64> = (0..d).map(|k| sp[k] - p[k]).collect();
            let dd: f64 = diff.iter().map(|v| v * v).sum();
            if dd <= 0.0 {
                break;
            }
            let t = (-(0..d).map(|k| p[k] * diff[k]).sum::<f64>() / dd).clamp(0.0, 1.0);
            for k in 0..d {
                p[k] += t * diff[k];
            }
        }
        self.phase_one(m, r)
    }

    /// Phase 1 of the revised simplex: pivots until the artificials are out of the basis (inside), no column
    /// improves (outside), or the iteration limit (undecided).
    fn phase_one(&mut self, m: usize, r: usize) -> Membership {
        self.start_basis(m, r);
        let max_iterations = 50 * (m + r) + 1000;
        let mut degenerate = 0usize;
        let mut since_refactor = 0usize;
        let mut cursor = 0usize;
        for it in 0..max_iterations {
            self.iterations = it;
            // Phase-1 objective: the artificials still in the basis.
            let objective: f64 = (0..r)
                .filter(|&i| self.basis[i] >= m)
                .map(|i| self.xb[i])
                .sum();
            if objective <= TOL {
                return self.verify_inside(m, r);
            }
            let Some(entering) = self.price(m, r, degenerate >= DEGENERATE_RUN, &mut cursor) else {
                // Optimal with a positive objective: outside, certified by y (w = y[..d]).
                return self.verify_outside(m, r);
            };
            let Some((leave, ratio)) = self.ratio_test(m, r, entering) else {
                // Unbounded cannot happen in phase 1 (the objective is >= 0); numerical trouble.
                return Membership::Undecided;
            };
            degenerate = if ratio <= TOL { degenerate + 1 } else { 0 };
            self.pivot(m, r, entering, leave, ratio);
            since_refactor += 1;
            if since_refactor >= REFACTOR_EVERY {
                since_refactor = 0;
                if !self.refactor(m, r) {
                    return Membership::Undecided;
                }
            }
        }
        Membership::Undecided
    }

    /// The starting basis: the r artificials (ids m..m+r), B = I, x_B = b = [0, ..., 0, 1].
    fn start_basis(&mut self, m: usize, r: usize) {
        self.basis.clear();
        self.basis.extend(m..m + r);
        self.binv.clear();
        self.binv.resize(r * r, 0.0);
        for i in 0..r {
            self.binv[i * r + i] = 1.0;
        }
        self.xb.clear();
        self.xb.resize(r, 0.0);
        self.xb[r - 1] = 1.0;
        self.in_basis.clear();
        self.in_basis.resize(m, false);
        self.y.resize(r, 0.0);
        self.u.resize(r, 0.0);
    }

    /// The entering point, none when no reduced cost improves. y = c_B^T B^-1 (c = 1 on artificials); the reduced
    /// cost of point j is -y . a_j (artificials never re-enter). Partial pricing: Dantzig within blocks of
    /// PRICING_BLOCK columns from a rotating start (`cursor`); with `bland`, Bland's rule scans from column 0 and
    /// takes the first improving one.
    fn price(&mut self, m: usize, r: usize, bland: bool, cursor: &mut usize) -> Option<usize> {
        for k in 0..r {
            self.y[k] = (0..r)
                .filter(|&i| self.basis[i] >= m)
                .map(|i| self.binv[i * r + k])
                .sum();
        }
        let mut entering = usize::MAX;
        let mut best = -TOL;
        let begin = if bland { 0 } else { *cursor };
        for step in 0..m {
            let j = (begin + step) % m;
            if !self.in_basis[j] {
                let a = &self.cols[j * r..(j + 1) * r];
                let dot: f64 = self.y.iter().zip(a).map(|(y, a)| y * a).sum();
                let reduced = -dot;
                if reduced < best {
                    entering = j;
                    best = reduced;
                    if bland {
                        break;
                    }
                }
            }
            if !bland && entering != usize::MAX && (step + 1) % PRICING_BLOCK == 0 {
                *cursor = (j + 1) % m;
                break;
            }
        }
        (entering != usize::MAX).then_some(entering)
    }

    /// u = B^-1 a_entering, and the row that leaves with its ratio, none when no row bounds the step. Ties go to
    /// artificials first (drives them out), then to the smallest variable id (Bland).
    fn ratio_test(&mut self, m: usize, r: usize, entering: usize) -> Option<(usize, f64)> {
        let a = &self.cols[entering * r..(entering + 1) * r];
        for i in 0..r {
            self.u[i] = (0..r).map(|k| self.binv[i * r + k] * a[k]).sum();
        }
        let mut leave = usize::MAX;
        let mut ratio = f64::INFINITY;
        for i in 0..r {
            if self.u[i] > PIVOT_TOL {
                let t = self.xb[i].max(0.0) / self.u[i];
                let better = t < ratio - 1e-15
                    || (t <= ratio + 1e-15
                        && leave != usize::MAX
                        && tie_break(self.basis[i], self.basis[leave], m));
                if better {
                    ratio = t;
                    leave = i;
                }
            }
        }
        (leave != usize::MAX).then_some((leave, ratio))
    }

    /// The pivot: `entering` takes row `leave`'s place in the basis, x_B and B^-1 updated by u.
    fn pivot(&mut self, m: usize, r: usize, entering: usize, leave: usize, ratio: f64) {
        let pivot = self.u[leave];
        for i in 0..r {
            if i != leave {
                self.xb[i] -= ratio * self.u[i];
            }
        }
        self.xb[leave] = ratio;
        for k in 0..r {
            self.binv[leave * r + k] /= pivot;
        }
        for i in 0..r {
            if i != leave && self.u[i] != 0.0 {
                let f = self.u[i];
                for k in 0..r {
                    self.binv[i * r + k] -= f * self.binv[leave * r + k];
                }
            }
        }
        if self.basis[leave] < m {
            self.in_basis[self.basis[leave]] = false;
        }
        self.basis[leave] = entering;
        self.in_basis[entering] = true;
    }

    /// Recomputes B^-1 and x_B = B^-1 b from the basis (Gauss-Jordan with partial pivoting).
    fn refactor(&mut self, m: usize, r: usize) -> bool {
        let mut a = vec![0.0; r * 2 * r];
        for (c, &j) in self.basis.iter().enumerate() {
            for i in 0..r {
                a[i * 2 * r + c] = if j < m {
                    self.cols[j * r + i]
                } else if j - m == i {
                    1.0
                } else {
                    0.0
                };
            }
        }
        for i in 0..r {
            a[i * 2 * r + r + i] = 1.0;
        }
        for c in 0..r {
            let p = (c..r)
                .max_by(|&x, &y| a[x * 2 * r + c].abs().total_cmp(&a[y * 2 * r + c].abs()))
                .expect("rows");
            if a[p * 2 * r + c].abs() < 1e-14 {
                return false;
            }
            if p != c {
                for k in 0..2 * r {
                    a.swap(p * 2 * r + k, c * 2 * r + k);
                }
            }
            let piv = a[c * 2 * r + c];
            for k in 0..2 * r {
                a[c * 2 * r + k] /= piv;
            }
            for i in 0..r {
                if i != c {
                    let f = a[i * 2 * r + c];
                    if f != 0.0 {
                        for k in 0..2 * r {
                            a[i * 2 * r + k] -= f * a[c * 2 * r + k];
                        }
                    }
                }
            }
        }
        for i in 0..r {
            for k in 0..r {
                self.binv[i * r + k] = a[i * 2 * r + r + k];
            }
            // b = e_{r-1}
            self.xb[i] = self.binv[i * r + r - 1];
        }
        true
    }

    /// The basic solution is a convex combination reproducing x (to tolerance): inside.
    fn verify_inside(&self, m: usize, r: usize) -> Membership {
        let mut residual = vec![0.0; r];
        residual[r - 1] = -1.0;
        for i in 0..r {
            let j = self.basis[i];
            if j < m {
                if self.xb[i] < -1e-7 {
                    return Membership::Undecided;
                }
                for (res, c) in residual.iter_mut().zip(&self.cols[j * r..(j + 1) * r]) {
                    *res += self.xb[i] * c;
                }
            }
        }
        if residual.iter().all(|v| v.abs() <= 1e-7) {
            Membership::Inside
        } else {
            Membership::Undecided
        }
    }

    /// Farkas: with w = y[..d], y . a_j < y_r (= y . b) for every point separates x from the points.
    fn verify_outside(&self, m: usize, r: usize) -> Membership {
        if self.y[r - 1] <= TOL {
            return Membership::Undecided;
        }
        let worst = (0..m)
            .map(|j| {
                (0..r)
                    .map(|k| self.y[k] * self.cols[j * r + k])
                    .sum::<f64>()
            })
            .fold(f64::NEG_INFINITY, f64::max);
        // w . (s_j - x) = scale * (y . a_j - y_r) < 0 for every point: a strict separating hyperplane.
        if worst < self.y[r - 1] {
            Membership::Outside
        } else {
            Membership::Undecided
        }
    }
}

/// Whether basic variable `a` should leave before `b` on a tie.
fn tie_break(a: usize, b: usize, m: usize) -> bool {
    match (a >= m, b >= m) {
        (true, false) => true,
        (false, true) => false,
        _ => a < b,
    }
}

/// One-shot form of [`HullTester::contains`] for points stored row-major.
pub fn in_convex_hull(x: &[f64], points: &[f64], scale: f64) -> Membership {
    let d = x.len();
    HullTester::new().contains(x, points.chunks_exact(d), scale)
}
