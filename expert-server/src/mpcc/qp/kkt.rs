//! How fast the KKT system that Clarabel factors at every interior-point iteration can be factored (issue 75,
//! `expert-server bench --kkt`): QDLDL as Clarabel runs it (AMD ordering, up-looking), the same factors by a
//! left-looking loop over a precomputed schedule (no elimination-tree walks), and QDLDL on the smaller system left
//! when every inequality row is eliminated into the variables' block (P + Aᵢᵀ H⁻¹ Aᵢ, what an HPIPM-style solver
//! factors). The values are stand-ins of the right structure: one unit on P's pattern and 10 on its diagonal, 0.5
//! on A's, the inequalities' scaling H = I; the work of a numeric factorisation depends on the pattern only.

use std::collections::BTreeMap;
use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::qdldl::{QDLDLFactorisation, QDLDLSettingsBuilder};
use serde::Serialize;

use super::QpLayout;

/// One way of factoring, timed.
#[derive(Debug, Clone, Serialize)]
pub struct KktTiming {
    /// What is factored, and how.
    pub method: &'static str,
    /// Rows of the system.
    pub rows: usize,
    /// Nonzeros of its upper triangle.
    pub nnz: usize,
    /// Strictly lower nonzeros of L.
    pub nnz_l: usize,
    /// Multiply-adds of the numeric factorisation (Σ over L's columns of c(c+1)/2, c the column's count).
    pub multiply_adds: usize,
    /// Median over the repeats of the mean time of one factorisation.
    pub factor_us: f64,
    /// The same for one solve (L, D, Lᵀ and the permutations), where measured.
    pub solve_us: Option<f64>,
}

/// The upper triangle of a symmetric matrix given by its (row ≤ column) entries.
fn upper(dim: usize, entries: &BTreeMap<(usize, usize), f64>) -> CscMatrix<f64> {
    let mut by_col: Vec<Vec<(usize, f64)>> = vec![Vec::new(); dim];
    for (&(r, c), &v) in entries {
        by_col[c].push((r, v));
    }
    let (mut colptr, mut rowval, mut nzval) = (vec![0], Vec::new(), Vec::new());
    for col in by_col {
        for (r, v) in col {
            rowval.push(r);
            nzval.push(v);
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(dim, dim, colptr, rowval, nzval)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Mean microseconds of `reps` calls of `f`, median of `repeats`.
fn time(repeats: usize, reps: usize, mut f: impl FnMut()) -> f64 {
    median(
        (0..repeats)
            .map(|_| {
                let t = Instant::now();
                for _ in 0..reps {
                    f();
                }
                t.elapsed().as_secs_f64() * 1e6 / reps as f64
            })
            .collect(),
    )
}

fn qdldl(
    method: &'static str,
    k: &CscMatrix<f64>,
    signs: Vec<i8>,
    repeats: usize,
    reps: usize,
) -> (KktTiming, QDLDLFactorisation<f64>) {
    let settings = QDLDLSettingsBuilder::default()
        .Dsigns(signs)
        .build()
        .expect("valid QDLDL settings");
    let mut f = QDLDLFactorisation::new(k, Some(settings)).expect("a quasi-definite stand-in");
    let (idx, vals): (Vec<usize>, Vec<f64>) = (0..k.nnz()).map(|i| (i, k.nzval[i])).unzip();
    let factor_us = time(repeats, reps, || {
        f.update_values(&idx, &vals);
        f.refactor().expect("a quasi-definite stand-in");
    });
    let mut b = vec![1.0; k.n];
    let solve_us = time(repeats, reps, || f.solve(&mut b));
    let multiply_adds = (0..k.n)
        .map(|j| {
            let c = f.L.colptr[j + 1] - f.L.colptr[j];
            c * (c + 1) / 2
        })
        .sum();
    let timing = KktTiming {
        method,
        rows: k.n,
        nnz: k.nnz(),
        nnz_l: f.nnzL(),
        multiply_adds,
        factor_us,
        solve_us: Some(solve_us),
    };
    (timing, f)
}

/// The left-looking factorisation of `k` on `f`'s ordering and pattern (whose work `qdldl` counted), from a schedule
/// computed once; returns its timing and the largest difference from `f`'s factors.
fn scheduled(
    k: &CscMatrix<f64>,
    f: &QDLDLFactorisation<f64>,
    qdldl: &KktTiming,
    repeats: usize,
    reps: usize,
) -> (KktTiming, f64) {
    let n = k.n;
    let mut iperm = vec![0; n];
    for (i, &p) in f.perm.iter().enumerate() {
        iperm[p] = i;
    }
    // Column j of the permuted lower triangle: (row, index into k's values).
    let mut cols: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for c in 0..n {
        for p in k.colptr[c]..k.colptr[c + 1] {
            let (a, b) = (iperm[k.rowval[p]], iperm[c]);
            cols[a.min(b)].push((a.max(b), p));
        }
    }
    // Row j of L: (column, position of L[j, column]).
    let (lp, li) = (&f.L.colptr, &f.L.rowval);
    let mut rows: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for c in 0..n {
        for p in lp[c]..lp[c + 1] {
            rows[li[p]].push((c, p));
        }
    }
    let (mut lx, mut d, mut w) = (vec![0.0; li.len()], vec![0.0; n], vec![0.0; n]);
    let mut factor = |lx: &mut [f64], d: &mut [f64]| {
        for j in 0..n {
            for &(r, p) in &cols[j] {
                w[r] += k.nzval[p];
            }
            for &(c, p) in &rows[j] {
                let scale = lx[p] * d[c];
                for q in p..lp[c + 1] {
                    w[li[q]] -= scale * lx[q];
                }
            }
            d[j] = std::mem::take(&mut w[j]);
            for q in lp[j]..lp[j + 1] {
                lx[q] = std::mem::take(&mut w[li[q]]) / d[j];
            }
        }
    };
    factor(&mut lx, &mut d);
    let diff = lx
        .iter()
        .zip(&f.L.nzval)
        .chain(d.iter().zip(&f.D))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    let factor_us = time(repeats, reps, || factor(&mut lx, &mut d));
    let timing = KktTiming {
        method: "the same factors, left-looking over a precomputed schedule",
        rows: n,
        nnz: k.nnz(),
        nnz_l: f.nnzL(),
        multiply_adds: qdldl.multiply_adds,
        factor_us,
        solve_us: None,
    };
    (timing, diff)
}

impl QpLayout {
    /// Times the factorisations of this layout's KKT system (module docs); `repeats` medians of `reps` calls.
    pub fn kkt_timings(&self, repeats: usize, reps: usize) -> Vec<KktTiming> {
        let (n, m, m_eq) = (self.n(), self.m(), self.m_eq());
        let mut full = BTreeMap::new();
        for (r, c) in self.p_pat.entries() {
            *full.entry((r.min(c), r.max(c))).or_insert(0.0) += 1.0;
        }
        for c in 0..n {
            *full.entry((c, c)).or_insert(0.0) += 10.0;
        }
        let mut rows_of_a: Vec<Vec<usize>> = vec![Vec::new(); m];
        for (r, c) in self.a_pat.entries() {
            full.insert((c, n + r), 0.5);
            rows_of_a[r].push(c);
        }
        for r in 0..m {
            full.insert((n + r, n + r), -1.0);
        }
        let signs = (0..n + m).map(|i| if i < n { 1 } else { -1 }).collect();
        let k = upper(n + m, &full);
        let (clarabel, f) = qdldl(
            "QDLDL on Clarabel's KKT system (AMD ordering)",
            &k,
            signs,
            repeats,
            reps,
        );
        let (scheduled, diff) = scheduled(&k, &f, &clarabel, repeats, reps);
        assert!(diff < 1e-9, "the scheduled factors differ by {diff}");
        // The inequality rows eliminated: P + Σᵢ aᵢ aᵢᵀ / hᵢ over them, the equality rows kept.
        let mut reduced: BTreeMap<(usize, usize), f64> = full
            .range(..)
            .filter(|(&(_, c), _)| c < n)
            .map(|(&k, &v)| (k, v))
            .collect();
        for cols in &rows_of_a[m_eq..] {
            for &i in cols {
                for &j in cols.iter().filter(|&&j| j >= i) {
                    *reduced.entry((i, j)).or_insert(0.0) += 0.25;
                }
            }
        }
        for (r, cols) in rows_of_a[..m_eq].iter().enumerate() {
            for &c in cols {
                reduced.insert((c, n + r), 0.5);
            }
            reduced.insert((n + r, n + r), -1e-7);
        }
        let signs = (0..n + m_eq).map(|i| if i < n { 1 } else { -1 }).collect();
        let (eliminated, _) = qdldl(
            "QDLDL with the inequality rows eliminated (P + A_I' H^-1 A_I)",
            &upper(n + m_eq, &reduced),
            signs,
            repeats,
            reps,
        );
        vec![clarabel, scheduled, eliminated]
    }
}
