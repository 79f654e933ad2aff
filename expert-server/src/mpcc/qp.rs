//! The MPCC-conv QP in Clarabel's form `min ½zᵀPz + qᵀz s.t. Az + s = b, s ∈ K` (expert.md §3–§6, §9).
//!
//! Decision vector z (scaled, n = 11N), per stage k = 1..N at `11(k−1)`:
//! (x_k, w_{k−1}) = (v_x, v_y, ω, X, Y, ψ, s, a, δ, v_s), scaled x̃ = T·x, then the track slack σ_k (one per
//! stage, relaxing both sides of the slab).
//!
//! Eliminated variables (exact substitutions, smaller KKT system than the reference's HPIPM layout):
//! * stage 0 (x_0, w_{−1}) is fixed by the measurement and w_prev, so it moves to the right-hand side (HPIPM
//!   keeps it with lbx = ubx);
//! * the scaled rates r_k = (w̃_k − w̃_{k−1})/dt (HPIPM's stage inputs with the integration w̃_k = w̃_{k−1} + dt·r_k
//!   as dynamics) are substituted: their cost becomes a banded quadratic in w̃ and their boxes become rows on
//!   w̃_k − w̃_{k−1};
//! * σ_k ≥ 0 is not imposed: for fixed (X, Y) the minimiser over σ of ½Zσ² subject to the slab is
//!   max(0, violation) ≥ 0 anyway.
//!
//! Rows: 7N equalities (dynamics of x_{k+1}), then the inequalities, per stage k ≥ 1: two box rows for each
//! bounded variable, two rate rows for each input on w̃_{k−1} − w̃_{k−2}, two slab rows.
//!
//! An input's rate rows at stages k ≥ 2 can never bind when the input's own box is narrower than its rate bound
//! allows, |w̃_{k−1} − w̃_{k−2}| ≤ (ub − lb)/T ≤ dt·r_max, and are then not emitted: the minimiser is unchanged and
//! the KKT system that Clarabel factors at every interior-point iteration shrinks (620 → 582 rows with the
//! reference numbers: the acceleration's scaled box is 2 wide and its rate bound 0.1·40 = 4). Stage 1's rows
//! compare with w_prev, which is data, and are always kept. The progress box s ∈ [−1, 2L] can never bind either
//! (s_0 ∈ [0, L), v_s ∈ [0, 4.5]), but it stays: its barrier terms are what keep the KKT system well conditioned
//! along the (X, Y, s) direction that the two contour residuals leave flat, and without them Clarabel stopped
//! with `NumericalError` at its first iteration on some states of a closed-loop lap.
//!
//! The sparsity pattern never changes: every assembly emits the same entries in the same order, so the first
//! assembly fixes the pattern and later ones only scatter values, which is what Clarabel's `update_P/q/A/b` need.

use std::time::{Duration, Instant};

use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SupportedConeT,
};

use super::config::MpccConfig;
use super::contour::{ContourErrors, Slab};
use super::pattern::Pattern;
pub use super::status::QpStatus;
use crate::rk4::{JacQ, JacU, NQ};

mod assemble;
pub mod kkt;

/// Variables per stage: x_k (7) and w_{k−1} (3).
pub const NZ: usize = 10;
/// Index of v_s in a stage.
pub const VS: usize = 9;
/// Index of s in a stage.
pub const S: usize = 6;
const X: usize = 3;
const Y: usize = 4;
const OMEGA: usize = 2;
/// Stage variables with box rows (X, Y have none: the reference's ±1e9 bounds are dropped).
const BOXED: [usize; 8] = [0, 1, 2, 5, S, 7, 8, VS];
/// The boxes a lean layout leaves out (`MpccConfig::lazy_state_boxes`): v_y, ω and ψ, state bounds that a
/// closed-loop drive does not reach. The inputs' boxes bind (saturated steering and acceleration), and s's box keeps
/// the KKT system well conditioned (module docs), so they stay.
const LAZY: [usize; 3] = [1, 2, 5];
const EQ_PER_STAGE: usize = 7;
/// Variables per stage in z: the 10 stage variables and σ.
const VARS_PER_STAGE: usize = NZ + 1;

/// A stage of the iterate in physical units.
pub type Stage = [f64; NZ];

/// One affine transition x_{k+1} = A_k x_k + B_k w_k + g_k, linearised at (q̄_k, w̄_{k−1}).
#[derive(Debug, Clone, Copy)]
pub struct Linearisation {
    /// f_d(q̄_k, w̄_{k−1}).
    pub f: [f64; NQ],
    /// ∂f_d/∂q.
    pub a: JacQ,
    /// ∂f_d/∂(a, δ).
    pub b: JacU,
}

/// Whether A_d[i][j] can be nonzero: the dynamics of (v_x, v_y, ω, ψ) do not depend on X, Y, ψ, and X and Y
/// depend on each other only through themselves. These zeros are exact in the forward sensitivities too.
fn a_structural(i: usize, j: usize) -> bool {
    match j {
        0..=2 => true,
        3 | 4 => i == j,
        _ => matches!(i, 3..=5),
    }
}

/// Everything the QP needs from one iterate D (stages 0..N, physical units).
pub struct QpInput<'a> {
    /// The iterate D: stage 0 is (q̂, ŝ, w_prev), stages 1..N the current guess.
    pub iterate: &'a [Stage],
    /// Transition k = 0..N−1 linearised at (q̄_k, w̄_{k−1}).
    pub lin: &'a [Linearisation],
    /// Contouring/lag errors at D's stages 1..N.
    pub errors: &'a [ContourErrors],
    /// Slabs at the warm-start progress of stages 1..N.
    pub slabs: &'a [Slab],
    /// w_{−1} (the expert's previous output).
    pub w_prev: [f64; 3],
}

/// The assembled data, in emission order (so the pattern can be checked) and as vectors.
#[derive(Debug, Default)]
struct Assembled {
    p: Vec<(usize, usize, f64)>,
    a: Vec<(usize, usize, f64)>,
    q: Vec<f64>,
    b: Vec<f64>,
}

/// The immutable shape of the QP for one configuration and track length.
#[derive(Debug, Clone)]
pub struct QpLayout {
    horizon: usize,
    dt: f64,
    /// Physical = scale × scaled, per stage variable.
    pub(super) scale: [f64; NZ],
    lb: [f64; NZ],
    ub: [f64; NZ],
    /// Whether input j has rate rows at stages k ≥ 2.
    rate_rows: [bool; 3],
    /// The stage variables with box rows: [`BOXED`], or without [`LAZY`] in a lean layout.
    boxed: Vec<usize>,
    cfg: MpccConfig,
    p_pat: Pattern,
    a_pat: Pattern,
}

/// Per-stream (or per-thread) solver memory: buffers and, with `reuse_solver`, the Clarabel solver.
#[derive(Default)]
pub struct QpWorkspace {
    asm: Assembled,
    p_nz: Vec<f64>,
    a_nz: Vec<f64>,
    zbar: Vec<f64>,
    solver: Option<DefaultSolver<f64>>,
}

impl std::fmt::Debug for QpWorkspace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QpWorkspace")
            .field("solver_cached", &self.solver.is_some())
            .finish()
    }
}

/// The result of one QP.
#[derive(Debug, Clone)]
pub struct QpSolution {
    /// Solver status.
    pub status: QpStatus,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Wall time inside Clarabel (setup or data update, and the solve).
    pub solve_time: Duration,
    /// D*: stages 0..N in physical units (stage 0 copied from the input). Empty unless solved.
    pub stages: Vec<Stage>,
    /// σ_k, k = 1..N.
    pub slacks: Vec<f64>,
    /// Scaled rates r_k, k = 0..N−1.
    pub rates: Vec<[f64; 3]>,
}

impl QpLayout {
    /// The layout for `cfg` on a track of length `track_length`.
    pub fn new(cfg: &MpccConfig, track_length: f64) -> Self {
        Self::build(cfg, track_length, true, false)
    }

    /// The lean layout: [`QpLayout::new`]'s without the box rows of [`LAZY`]'s state variables. Its minimiser is
    /// the full QP's whenever it lies within those boxes ([`QpLayout::within_lazy_boxes`]): the lean QP is a
    /// relaxation of the full one.
    pub fn lean(cfg: &MpccConfig, track_length: f64) -> Self {
        Self::build(cfg, track_length, true, true)
    }

    /// The layout, with the rate rows that can never bind left out (`prune`) or kept (to test that leaving them
    /// out changes nothing), and with or without the box rows of [`LAZY`] (`lean`).
    pub(super) fn build(cfg: &MpccConfig, track_length: f64, prune: bool, lean: bool) -> Self {
        let (sx, sw) = (cfg.state_scale, cfg.input_scale);
        let scale = [
            sx[0],
            sx[1],
            sx[2],
            sx[3],
            sx[4],
            sx[5],
            track_length.ceil(),
            sw[0],
            sw[1],
            sw[2],
        ];
        let (l, u) = (cfg.state_lb, cfg.state_ub);
        let (il, iu) = (cfg.input_lb, cfg.input_ub);
        let inf = f64::INFINITY;
        let lb = [
            l[0], l[1], l[2], -inf, -inf, l[3], cfg.s_lb, il[0], il[1], il[2],
        ];
        let ub = [
            u[0],
            u[1],
            u[2],
            inf,
            inf,
            u[3],
            cfg.s_ub_laps * track_length,
            iu[0],
            iu[1],
            iu[2],
        ];
        let rate_rows: [bool; 3] = std::array::from_fn(|j| {
            !prune || (ub[7 + j] - lb[7 + j]) / scale[7 + j] > cfg.dt * cfg.rate_bound[j]
        });
        let mut layout = Self {
            horizon: cfg.horizon,
            dt: cfg.dt,
            scale,
            lb,
            ub,
            rate_rows,
            boxed: BOXED
                .into_iter()
                .filter(|j| !(lean && LAZY.contains(j)))
                .collect(),
            cfg: cfg.clone(),
            p_pat: Pattern::new(0, 0, &[]),
            a_pat: Pattern::new(0, 0, &[]),
        };
        // Any finite data fixes the pattern (every entry is emitted regardless of its value).
        let n = cfg.horizon;
        let iterate = vec![[0.0; NZ]; n + 1];
        let lin = vec![
            Linearisation {
                f: [0.0; NQ],
                a: JacQ::zeros(),
                b: JacU::zeros()
            };
            n
        ];
        let errors = vec![
            ContourErrors {
                e_c: 0.0,
                e_l: 0.0,
                grad_c: [0.0; 3],
                grad_l: [0.0; 3]
            };
            n
        ];
        let slabs = vec![
            Slab {
                normal: [1.0, 0.0],
                lo: -1.0,
                hi: 1.0
            };
            n
        ];
        let input = QpInput {
            iterate: &iterate,
            lin: &lin,
            errors: &errors,
            slabs: &slabs,
            w_prev: [0.0; 3],
        };
        let mut asm = Assembled::default();
        layout.assemble(&input, &mut asm);
        layout.p_pat = Pattern::new(layout.n(), layout.n(), &asm.p);
        layout.a_pat = Pattern::new(layout.m(), layout.n(), &asm.a);
        layout
    }

    /// Number of variables.
    pub fn n(&self) -> usize {
        VARS_PER_STAGE * self.horizon
    }

    /// Number of equality rows.
    pub fn m_eq(&self) -> usize {
        EQ_PER_STAGE * self.horizon
    }

    /// Number of rows.
    pub fn m(&self) -> usize {
        // Per stage: the box rows, the rate rows (all three inputs at stage 1), the two slab rows.
        let later_rates = self.rate_rows.iter().filter(|&&r| r).count();
        let stage = |rates: usize| 2 * self.boxed.len() + 2 * rates + 2;
        self.m_eq() + stage(3) + stage(later_rates) * (self.horizon - 1)
    }

    /// Whether a solution of this layout keeps the boxes it leaves out, to the solver's feasibility tolerance (in
    /// scaled units, as the full layout's rows would hold them): then it is the full QP's minimiser too. True for a
    /// layout that leaves none out; false for an unsolved QP.
    pub fn within_lazy_boxes(&self, sol: &QpSolution) -> bool {
        let tol = self.cfg.tol_feas;
        let left_out: Vec<usize> = BOXED
            .into_iter()
            .filter(|j| !self.boxed.contains(j))
            .collect();
        !sol.stages.is_empty()
            && sol.stages[1..].iter().all(|z| {
                left_out.iter().all(|&j| {
                    let (v, c) = (z[j], self.scale[j]);
                    v / c <= self.ub[j] / c + tol && v / c >= self.lb[j] / c - tol
                })
            })
    }

    /// Nonzeros of (P, A).
    pub fn nnz(&self) -> (usize, usize) {
        (self.p_pat.nnz(), self.a_pat.nnz())
    }

    fn stage_var(&self, k: usize, j: usize) -> usize {
        debug_assert!((1..=self.horizon).contains(&k));
        VARS_PER_STAGE * (k - 1) + j
    }

    fn slack_var(&self, k: usize) -> usize {
        VARS_PER_STAGE * (k - 1) + NZ
    }

    fn settings(&self) -> DefaultSettings<f64> {
        DefaultSettingsBuilder::default()
            .verbose(false)
            .max_iter(self.cfg.max_iter)
            .tol_gap_abs(self.cfg.tol_gap)
            .tol_gap_rel(self.cfg.tol_gap_rel.unwrap_or(self.cfg.tol_gap))
            .max_step_fraction(self.cfg.max_step_fraction)
            .tol_feas(self.cfg.tol_feas)
            // Presolve would drop rows and forbid the data-update interface; there are no infinite bounds anyway.
            .presolve_enable(false)
            .equilibrate_enable(self.cfg.equilibrate)
            .iterative_refinement_enable(self.cfg.iterative_refinement)
            .direct_solve_method(self.cfg.ldl.clarabel_name().to_string())
            .build()
            .expect("valid Clarabel settings")
    }

    fn cones(&self) -> [SupportedConeT<f64>; 2] {
        [
            SupportedConeT::ZeroConeT(self.m_eq()),
            SupportedConeT::NonnegativeConeT(self.m() - self.m_eq()),
        ]
    }

    /// Re-pose the assembled QP in the deviation Δ = z − z̄ from the iterate (rates and slacks at 0):
    /// q ← q + P z̄, b ← b − A z̄. Same minimiser, but the objective and residual norms are those of the step, not
    /// of the Gauss–Newton expansion around the origin (~1e5), so Clarabel's relative tolerances stay meaningful.
    fn to_deviations(&self, inp: &QpInput, ws: &mut QpWorkspace) {
        let zbar = &mut ws.zbar;
        zbar.clear();
        zbar.resize(self.n(), 0.0);
        for k in 1..=self.horizon {
            for j in 0..NZ {
                zbar[self.stage_var(k, j)] = inp.iterate[k][j] / self.scale[j];
            }
        }
        let Assembled { p, a, q, b } = &mut ws.asm;
        for &(r, c, v) in p.iter() {
            q[r] += v * zbar[c];
            if r != c {
                q[c] += v * zbar[r];
            }
        }
        for &(r, c, v) in a.iter() {
            b[r] -= v * zbar[c];
        }
    }

    /// Assemble and solve the QP around `inp`.
    pub fn solve(&self, inp: &QpInput, ws: &mut QpWorkspace) -> QpSolution {
        let mut sol = QpSolution {
            status: QpStatus::NotRun,
            iterations: 0,
            solve_time: Duration::ZERO,
            stages: Vec::new(),
            slacks: Vec::new(),
            rates: Vec::new(),
        };
        self.assemble(inp, &mut ws.asm);
        self.to_deviations(inp, ws);
        self.p_pat.scatter(&ws.asm.p, &mut ws.p_nz);
        self.a_pat.scatter(&ws.asm.a, &mut ws.a_nz);
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(finite(&ws.p_nz) && finite(&ws.a_nz) && finite(&ws.asm.q) && finite(&ws.asm.b)) {
            sol.status = QpStatus::NonFiniteData;
            return sol;
        }
        let t0 = Instant::now();
        let updated = self.cfg.reuse_solver
            && ws.solver.as_mut().is_some_and(|s| {
                s.update_P(&ws.p_nz).is_ok()
                    && s.update_A(&ws.a_nz).is_ok()
                    && s.update_q(&ws.asm.q).is_ok()
                    && s.update_b(&ws.asm.b).is_ok()
            });
        let mut handed_over = t0.elapsed();
        if updated {
            let solver = ws.solver.as_mut().expect("updated above");
            solver.solve();
            sol.status = solver.solution.status.into();
            sol.iterations = solver.solution.iterations;
            record_phases(handed_over, solver);
        }
        // A fresh solver: first use, no reuse, or (with equilibration) a reused solver that failed, because its
        // equilibration belongs to an earlier QP of the stream and can be poor for this one.
        if !updated
            || (self.cfg.equilibrate && !sol.status.is_success(self.cfg.accept_almost_solved))
        {
            let set_up = Instant::now();
            let (p, a) = (self.p_pat.matrix(&ws.p_nz), self.a_pat.matrix(&ws.a_nz));
            match DefaultSolver::new(&p, &ws.asm.q, &a, &ws.asm.b, &self.cones(), self.settings()) {
                Ok(mut s) => {
                    handed_over = set_up.elapsed();
                    s.solve();
                    sol.status = s.solution.status.into();
                    sol.iterations += s.solution.iterations;
                    record_phases(handed_over, &s);
                    ws.solver = Some(s);
                }
                Err(_) => {
                    ws.solver = None;
                    sol.status = QpStatus::SetupFailed;
                    sol.solve_time = t0.elapsed();
                    return sol;
                }
            }
        }
        sol.solve_time = t0.elapsed();
        let r = &ws.solver.as_ref().expect("solved above").solution;
        if sol.status.is_success(self.cfg.accept_almost_solved) {
            let z: Vec<f64> = r.x.iter().zip(&ws.zbar).map(|(dz, zb)| zb + dz).collect();
            sol.stages.push(inp.iterate[0]);
            for k in 1..=self.horizon {
                sol.stages.push(std::array::from_fn(|j| {
                    z[self.stage_var(k, j)] * self.scale[j]
                }));
            }
            sol.slacks = (1..=self.horizon).map(|k| z[self.slack_var(k)]).collect();
            let st = &sol.stages;
            sol.rates = (0..self.horizon)
                .map(|k| {
                    std::array::from_fn(|j| {
                        let prev = if k == 0 { inp.w_prev[j] } else { st[k][7 + j] };
                        (st[k + 1][7 + j] - prev) / (self.scale[7 + j] * self.dt)
                    })
                })
                .collect();
        }
        if !self.cfg.reuse_solver {
            ws.solver = None;
        }
        sol
    }
}

/// Adds a solve to the phases being recorded on this thread, if any ([`super::phases`]).
fn record_phases(handed_over: Duration, solver: &DefaultSolver<f64>) {
    if super::phases::recording() {
        let timers = format!("{:?}", solver.timers);
        let ldl = &solver.info.linsolver;
        let nnz = (ldl.nnzA, ldl.nnzL);
        super::phases::add(handed_over, solver.solution.iterations, &timers, nnz);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_match_expert_md() {
        let l = QpLayout::new(&MpccConfig::default(), 17.461412207630154);
        assert_eq!(l.n(), 220);
        assert_eq!(l.m_eq(), 140);
        // 7N equalities; 24 inequality rows at stage 1 and 22 at later stages (no acceleration rate rows).
        assert_eq!(l.m(), 140 + 24 + 22 * 19);
        let (np, na) = l.nnz();
        assert!(np > 280 && na > 1000, "{np} {na}");
    }
}
