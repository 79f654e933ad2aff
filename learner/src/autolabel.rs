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
        }
    }

    /// A fixed radius, no scaling.
    pub fn fixed(rho: f64) -> Self {
        AutolabelOptions {
            rho,
            scale_states: false,
            adaptive_reference: None,
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
                    Membership::Inside => Verdict::Inside,
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
