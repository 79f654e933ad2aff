//! Safety auto-labelling, eq. (19) and Proposition 1 of the paper (algorithm.md 3):
//!
//! ```text
//!     D- = D? \ { x in D? : x in conv(D+ ∩ B_rho(x)) }
//! ```
//!
//! For every query x of D?: S = the points of D+ within radius rho (k-d tree, [`crate::kdtree`]); if |S| >= d + 1
//! and x lies in conv(S) (exact LP test, [`crate::hull`]) x is removed. Queries run in parallel (rayon). Generic in
//! the dimension d (6 for states, 2 in the Fig. 3 example).

use crate::hull::{HullTester, Membership};
use crate::kdtree::KdTree;
use crate::replay::Replay;
use cabc_proto::config::RunConfig;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// The knobs of auto-labelling, all from the run configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutolabelOptions {
    /// rho of eq. (19) (`algorithm.rho`).
    pub rho: f64,
    /// Divide each dimension by its standard deviation over D+ before the search (`algorithm.scale_states`).
    pub scale_states: bool,
    /// Adaptive rho (`algorithm.adaptive_rho`): rho_eff = rho * min(1, (n_ref / |D+|)^(1/d)), which keeps the
    /// expected neighbour count of a uniform D+ constant once D+ outgrows `n_ref`; None = off.
    pub adaptive_reference: Option<usize>,
    /// Thin D+ to at most this many points first, spread over its support (`algorithm.autolabel_max_plus`; the
    /// reference's FADS subsample of 32,768); 0 = all of D+.
    pub max_plus: usize,
    /// Remove a point only when the hull of its neighbours has at least this many vertices
    /// (`algorithm.autolabel_min_vertices`; the reference's Qhull check, 8); 0 = no check.
    pub min_vertices: usize,
    /// Seeds the thinning's draw.
    pub seed: u64,
}

impl AutolabelOptions {
    /// From the run configuration; the adaptive reference size is the epoch-0 step budget
    /// (`collection.initial_steps`), the D+ size for which the configured rho was chosen.
    pub fn from_config(config: &RunConfig) -> Self {
        AutolabelOptions {
            rho: config.algorithm.rho,
            scale_states: config.algorithm.scale_states,
            adaptive_reference: config
                .algorithm
                .adaptive_rho
                .then_some(config.collection.initial_steps as usize),
            max_plus: config.algorithm.autolabel_max_plus,
            min_vertices: config.algorithm.autolabel_min_vertices,
            seed: config.run.seed ^ 0xFAD5,
        }
    }

    /// A fixed radius, no scaling.
    pub fn fixed(rho: f64) -> Self {
        AutolabelOptions {
            rho,
            scale_states: false,
            adaptive_reference: None,
            max_plus: 0,
            min_vertices: 0,
            seed: 0,
        }
    }

    /// The radius used for a D+ of `n_plus` points in `dim` dimensions.
    pub fn effective_rho(&self, n_plus: usize, dim: usize) -> f64 {
        match self.adaptive_reference {
            Some(n_ref) if n_plus > n_ref => {
                self.rho * (n_ref as f64 / n_plus as f64).powf(1.0 / dim as f64)
            }
            _ => self.rho,
        }
    }
}

/// What one labelling pass did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AutolabelReport {
    /// Indices into D? (the `uncertain` slice) of the removed, likely-safe points, ascending.
    pub removed: Vec<usize>,
    pub queries: usize,
    /// Kept: fewer than d + 1 neighbours.
    pub too_few_neighbours: usize,
    /// Kept: outside the hull of its neighbours.
    pub outside: usize,
    /// Kept: the LP did not settle (should stay 0).
    pub undecided: usize,
    /// Kept: inside, but the hull of its neighbours has fewer than `min_vertices` vertices.
    pub few_vertices: usize,
    /// D+ points searched (after thinning).
    pub plus_used: usize,
    pub rho: f64,
    pub mean_neighbours: f64,
    pub seconds: f64,
}

impl AutolabelReport {
    pub fn kept(&self) -> usize {
        self.queries - self.removed.len()
    }
}

/// Auto-labels `uncertain` (D?) against `plus` (D+), both row-major with `dim` values per point.
pub fn autolabel(
    plus: &[f64],
    uncertain: &[f64],
    dim: usize,
    options: &AutolabelOptions,
) -> AutolabelReport {
    let start = Instant::now();
    assert!(dim > 0 && plus.len() % dim == 0 && uncertain.len() % dim == 0);
    let n_plus = plus.len() / dim;
    let queries = uncertain.len() / dim;
    let rho = options.effective_rho(n_plus, dim);
    let scale: Vec<f64> = if options.scale_states {
        std_per_dim(plus, dim)
    } else {
        vec![1.0; dim]
    };
    let scaled = |pts: &[f64]| -> Vec<f64> {
        pts.chunks_exact(dim)
            .flat_map(|p| p.iter().zip(&scale).map(|(v, s)| v / s))
            .collect()
    };
    let (plus_s, uncertain_s);
    let (plus, uncertain) = if options.scale_states {
        plus_s = scaled(plus);
        uncertain_s = scaled(uncertain);
        (plus_s.as_slice(), uncertain_s.as_slice())
    } else {
        (plus, uncertain)
    };
    let thinned;
    let plus = match options.max_plus {
        cap if cap > 0 && n_plus > cap => {
            thinned = thin(plus, dim, cap, options.seed);
            thinned.as_slice()
        }
        _ => plus,
    };
    let tree = KdTree::new(plus, dim);
    let verdicts: Vec<(Verdict, usize)> = uncertain
        .par_chunks_exact(dim)
        .map_init(
            || (HullTester::new(), Vec::new()),
            |(tester, neighbours), x| {
                neighbours.clear();
                tree.within(x, rho, neighbours);
                let n = neighbours.len();
                if n < dim + 1 {
                    return (Verdict::TooFew, n);
                }
                let v = match tester.contains(x, neighbours.iter().map(|&p| tree.point(p)), rho) {
                    Membership::Inside
                        if vertices_at_least(
                            tester,
                            &tree,
                            neighbours,
                            rho,
                            options.min_vertices,
                        ) =>
                    {
                        Verdict::Inside
                    }
                    Membership::Inside => Verdict::FewVertices,
                    Membership::Outside => Verdict::Outside,
                    Membership::Undecided => Verdict::Undecided,
                };
                (v, n)
            },
        )
        .collect();
    let mut report = AutolabelReport {
        queries,
        rho,
        plus_used: tree.len(),
        ..Default::default()
    };
    let mut total_neighbours = 0usize;
    for (i, (v, n)) in verdicts.iter().enumerate() {
        total_neighbours += n;
        match v {
            Verdict::Inside => report.removed.push(i),
            Verdict::Outside => report.outside += 1,
            Verdict::TooFew => report.too_few_neighbours += 1,
            Verdict::Undecided => report.undecided += 1,
            Verdict::FewVertices => report.few_vertices += 1,
        }
    }
    report.mean_neighbours = total_neighbours as f64 / queries.max(1) as f64;
    report.seconds = start.elapsed().as_secs_f64();
    report
}

/// Auto-labels the replay's D? against its D+ (raw 6-d states, as the reference). Apply the result with
/// [`Replay::apply_labels`], which sets D-.
pub fn autolabel_replay(replay: &Replay, options: &AutolabelOptions) -> AutolabelReport {
    let flat =
        |states: &[[f32; 6]]| -> Vec<f64> { states.iter().flatten().map(|&v| v as f64).collect() };
    autolabel(
        &flat(&replay.plus.states),
        &flat(&replay.uncertain.states),
        6,
        options,
    )
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Verdict {
    Inside,
    Outside,
    TooFew,
    Undecided,
    FewVertices,
}

/// Whether the hull of the `neighbours` (positions in `tree`) has at least `min` vertices: a point is a vertex when
/// it lies outside the hull of the others (one LP each, stopping at the `min`-th vertex). `min` = 0 always holds.
fn vertices_at_least(
    tester: &mut HullTester,
    tree: &KdTree,
    neighbours: &[usize],
    scale: f64,
    min: usize,
) -> bool {
    if min == 0 {
        return true;
    }
    if neighbours.len() < min {
        return false;
    }
    let mut found = 0;
    for (k, &p) in neighbours.iter().enumerate() {
        let others = neighbours
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .map(|(_, &q)| tree.point(q));
        if tester.contains(tree.point(p), others, scale) == Membership::Outside {
            found += 1;
            if found >= min {
                return true;
            }
        }
        // Too few candidates left to reach `min`.
        if found + (neighbours.len() - k - 1) < min {
            return false;
        }
    }
    false
}

/// Bins per dimension of the thinning's grid.
const THIN_BINS: usize = 5;

/// At most `cap` of the row-major `points`, spread over their support: each point's weight is the inverse of how
/// many points share its cell of a grid of [`THIN_BINS`] bins per dimension over the points' bounding box, and
/// `cap` points are drawn without replacement by weight (Efraimidis-Spirakis keys, seeded), in their original
/// order. Dense regions (the racing line, visited every lap) give up points first, sparse ones (rare recoveries)
/// keep theirs: the aim of the reference's FADS subsample (a density-inverse draw on a Gaussian-mixture density
/// estimate), without its mixture fit.
pub fn thin(points: &[f64], dim: usize, cap: usize, seed: u64) -> Vec<f64> {
    use rand::{Rng, SeedableRng};
    let n = points.len() / dim;
    if n <= cap {
        return points.to_vec();
    }
    let (mut lo, mut hi) = (vec![f64::INFINITY; dim], vec![f64::NEG_INFINITY; dim]);
    for p in points.chunks_exact(dim) {
        for k in 0..dim {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let cell = |p: &[f64]| -> u64 {
        (0..dim).fold(0u64, |acc, k| {
            let width = (hi[k] - lo[k]).max(f64::MIN_POSITIVE);
            let bin = (((p[k] - lo[k]) / width) * THIN_BINS as f64) as usize;
            acc * THIN_BINS as u64 + bin.min(THIN_BINS - 1) as u64
        })
    };
    let cells: Vec<u64> = points.chunks_exact(dim).map(cell).collect();
    let mut counts = std::collections::HashMap::new();
    for &c in &cells {
        *counts.entry(c).or_insert(0usize) += 1;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    // Key u^(1/w) with w = 1 / count: the largest `cap` keys are a weighted draw without replacement. Compared in
    // log space: ln(u) * count.
    let mut keyed: Vec<(f64, usize)> = cells
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let u: f64 = rng.gen_range(f64::MIN_POSITIVE..1.0);
            (u.ln() * counts[c] as f64, i)
        })
        .collect();
    keyed.select_nth_unstable_by(cap - 1, |a, b| b.0.total_cmp(&a.0));
    let mut chosen: Vec<usize> = keyed[..cap].iter().map(|&(_, i)| i).collect();
    chosen.sort_unstable();
    chosen
        .iter()
        .flat_map(|&i| points[i * dim..(i + 1) * dim].iter().copied())
        .collect()
}

fn std_per_dim(points: &[f64], dim: usize) -> Vec<f64> {
    let n = (points.len() / dim).max(1) as f64;
    (0..dim)
        .map(|k| {
            let mean = points.iter().skip(k).step_by(dim).sum::<f64>() / n;
            let var = points
                .iter()
                .skip(k)
                .step_by(dim)
                .map(|v| (v - mean).powi(2))
                .sum::<f64>()
                / n;
            if var > 0.0 {
                var.sqrt()
            } else {
                1.0
            }
        })
        .collect()
}
