//! Auto-labelling (eq. (19)): the hull test agrees with an LP solver, keeps points outside the hull, and is
//! exact on a 6-d simplex.

use cabc_learning::autolabel::{autolabel, AutolabelOptions};
use cabc_learning::hull::{in_convex_hull, Membership};
use clarabel::algebra::CscMatrix;
use clarabel::solver::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The feasibility LP with Clarabel: lambda >= 0, sum lambda = 1, sum lambda_i s_i = x.
fn clarabel_inside(x: &[f64], points: &[f64]) -> bool {
    let d = x.len();
    let n = points.len() / d;
    let mut rows: Vec<Vec<f64>> = Vec::new();
    for k in 0..d {
        rows.push((0..n).map(|i| points[i * d + k]).collect());
    }
    rows.push(vec![1.0; n]);
    for i in 0..n {
        let mut r = vec![0.0; n];
        r[i] = -1.0;
        rows.push(r);
    }
    let a = CscMatrix::from(&rows);
    let mut b: Vec<f64> = x.to_vec();
    b.push(1.0);
    b.extend(std::iter::repeat_n(0.0, n));
    let p = CscMatrix::<f64>::zeros((n, n));
    let q = vec![0.0; n];
    let cones = [ZeroConeT(d + 1), NonnegativeConeT(n)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .unwrap();
    let mut solver = DefaultSolver::new(&p, &q, &a, &b, &cones, settings).unwrap();
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => true,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => false,
        s => panic!("clarabel: {s:?}"),
    }
}

#[test]
fn hull_test_agrees_with_an_lp_solver() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut counts = [0usize; 2];
    for trial in 0..300 {
        let d = [2, 3, 4, 6][trial % 4];
        let n = rng.gen_range(d + 1..4 * d + 30);
        let points: Vec<f64> = (0..n * d).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let x: Vec<f64> = (0..d).map(|_| rng.gen_range(-0.9..0.9)).collect();
        let want = clarabel_inside(&x, &points);
        let got = in_convex_hull(&x, &points, 1.0);
        assert_ne!(got, Membership::Undecided, "trial {trial}");
        assert_eq!(
            got == Membership::Inside,
            want,
            "trial {trial}: d {d}, n {n}"
        );
        counts[want as usize] += 1;
    }
    // Both verdicts were exercised.
    assert!(counts[0] > 30 && counts[1] > 30, "{counts:?}");
}

/// 2-d: the hull by Andrew's monotone chain, membership by the sign of cross products.
fn inside_2d(x: (f64, f64), pts: &[(f64, f64)]) -> bool {
    let mut p = pts.to_vec();
    p.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64)> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    (0..hull.len()).all(|i| cross(hull[i], hull[(i + 1) % hull.len()], x) >= 0.0)
}

#[test]
fn autolabel_removes_exactly_the_points_inside_their_local_hull() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let plus: Vec<f64> = (0..2 * 800).map(|_| rng.gen_range(-0.5..0.5)).collect();
    let uncertain: Vec<f64> = (0..2 * 1000).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let rho = 0.3;
    let report = autolabel(&plus, &uncertain, 2, &AutolabelOptions::fixed(rho));
    assert_eq!(report.undecided, 0);
    let removed: std::collections::HashSet<usize> = report.removed.iter().copied().collect();
    for (i, x) in uncertain.chunks_exact(2).enumerate() {
        let x = (x[0], x[1]);
        let near: Vec<(f64, f64)> = plus
            .chunks_exact(2)
            .map(|p| (p[0], p[1]))
            .filter(|p| (p.0 - x.0).powi(2) + (p.1 - x.1).powi(2) <= rho * rho)
            .collect();
        let want = near.len() >= 3 && inside_2d(x, &near);
        assert_eq!(
            removed.contains(&i),
            want,
            "query {i} at {x:?}, {} neighbours",
            near.len()
        );
        // Points outside the square [-0.5, 0.5]^2 are outside every hull of D+: always kept.
        if x.0.abs() > 0.5 || x.1.abs() > 0.5 {
            assert!(!removed.contains(&i));
        }
    }
    assert!(report.removed.len() > 100, "{}", report.removed.len());
    assert_eq!(report.kept(), 1000 - report.removed.len());
}

#[test]
fn six_d_simplex_inside_and_outside() {
    let d = 6;
    // Vertices: the origin and the unit vectors, plus points on the simplex's faces.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut vertices = vec![0.0; d];
    for k in 0..d {
        let mut e = vec![0.0; d];
        e[k] = 1.0;
        vertices.extend(e);
    }
    for _ in 0..40 {
        // A random point of the boundary face sum = 1.
        let mut w: Vec<f64> = (0..d).map(|_| rng.gen::<f64>()).collect();
        let s: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= s);
        vertices.extend(w);
    }
    let inside = |x: &[f64]| x.iter().all(|&v| v >= 0.0) && x.iter().sum::<f64>() <= 1.0;
    let mut seen = [0; 2];
    for _ in 0..400 {
        let x: Vec<f64> = (0..d).map(|_| rng.gen_range(-0.1..0.4)).collect();
        let margin = x
            .iter()
            .cloned()
            .fold(f64::INFINITY, f64::min)
            .min(1.0 - x.iter().sum::<f64>());
        if margin.abs() < 1e-6 {
            continue;
        }
        let got = in_convex_hull(&x, &vertices, 1.0);
        assert_eq!(got == Membership::Inside, inside(&x), "{x:?}");
        seen[inside(&x) as usize] += 1;
    }
    assert!(seen[0] > 20 && seen[1] > 20, "{seen:?}");
    let barycentre = vec![1.0 / (d + 1) as f64; d];
    assert_eq!(
        in_convex_hull(&barycentre, &vertices, 1.0),
        Membership::Inside
    );
    // Through autolabel: the barycentre is removed, a point beyond a face is kept, and a query with fewer than
    // d + 1 neighbours is kept even when inside.
    let queries: Vec<f64> = [barycentre.clone(), vec![0.3; d], vec![0.01; d]].concat();
    let report = autolabel(&vertices, &queries, d, &AutolabelOptions::fixed(10.0));
    assert_eq!(report.removed, vec![0, 2]);
    let few = &vertices[..d * d]; // d points: too few for a d-dimensional hull
    let report = autolabel(few, &queries[..d], d, &AutolabelOptions::fixed(10.0));
    assert_eq!((report.removed.len(), report.too_few_neighbours), (0, 1));
}

#[test]
fn adaptive_rho_shrinks_with_d_plus() {
    let mut o = AutolabelOptions::fixed(1.0);
    assert_eq!(o.effective_rho(1_000_000, 6), 1.0);
    o.adaptive_reference = Some(1024);
    assert_eq!(o.effective_rho(1000, 6), 1.0);
    let r = o.effective_rho(1024 * 64, 6);
    assert!((r - 0.5).abs() < 1e-12, "{r}");
}

/// Issue 18 (6): the reference's hull needs at least 8 vertices. A query inside a 6-d simplex (7 vertices) is kept
/// with that rule and removed without it; with an 8th neighbour outside the simplex it is removed again.
#[test]
fn the_vertex_rule_keeps_points_inside_a_bare_simplex() {
    let dim = 6;
    let mut simplex = vec![0.0; dim];
    for k in 0..dim {
        let mut v = vec![0.0; dim];
        v[k] = 0.5;
        simplex.extend(v);
    }
    let x = vec![0.05; dim];
    let run = |plus: &[f64], min_vertices: usize| {
        let options = AutolabelOptions {
            min_vertices,
            ..AutolabelOptions::fixed(1.0)
        };
        autolabel(plus, &x, dim, &options)
    };
    assert_eq!(run(&simplex, 0).removed, vec![0]);
    let kept = run(&simplex, 8);
    assert!(kept.removed.is_empty());
    assert_eq!(kept.few_vertices, 1);
    let mut eight = simplex.clone();
    eight.extend(vec![0.2; dim]);
    assert_eq!(run(&eight, 8).removed, vec![0], "the 8th point is a vertex");
    // A point inside the simplex adds a neighbour, not a vertex.
    let mut inner = simplex.clone();
    inner.extend(vec![0.03; dim]);
    assert!(run(&inner, 8).removed.is_empty());
}

/// Issue 18 (6): D+ is thinned to the cap before the search, spread over its support: a dense cluster gives up
/// points before a sparse one, the draw is the seed's, and the points kept are D+'s own.
#[test]
fn thinning_keeps_the_cap_and_favours_sparse_regions() {
    use cabc_learning::autolabel::thin;
    let dim = 2;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut points = Vec::new();
    // 900 points in a small dense corner, 100 spread over the rest of the box.
    for _ in 0..900 {
        points.extend([rng.gen_range(0.0..0.1), rng.gen_range(0.0..0.1)]);
    }
    for _ in 0..100 {
        points.extend([rng.gen_range(0.2..1.0), rng.gen_range(0.2..1.0)]);
    }
    let kept = thin(&points, dim, 200, 7);
    assert_eq!(kept.len(), 200 * dim);
    assert_eq!(kept, thin(&points, dim, 200, 7), "the seed's draw");
    assert_ne!(kept, thin(&points, dim, 200, 8));
    let sparse = kept.chunks_exact(dim).filter(|p| p[0] >= 0.2).count();
    assert!(
        sparse > 60,
        "{sparse} of the 100 sparse points kept (a uniform draw keeps ~20)"
    );
    assert!(kept
        .chunks_exact(dim)
        .all(|p| points.chunks_exact(dim).any(|q| q == p)));
    assert_eq!(
        thin(&points, dim, 5000, 7),
        points,
        "under the cap nothing is dropped"
    );
    // autolabel reports how many D+ points it searched.
    let report = autolabel(
        &points,
        &[0.5, 0.5],
        dim,
        &AutolabelOptions {
            max_plus: 300,
            ..AutolabelOptions::fixed(0.1)
        },
    );
    assert_eq!(report.plus_used, 300);
}
