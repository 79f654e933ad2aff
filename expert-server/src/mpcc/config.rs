//! Every number of MPCC-conv (expert.md §2–§9), in one place. `Default` = the reference wrapper's values.

use serde::{Deserialize, Serialize};

/// The MPCC-conv configuration. Weights are the *effective* ones (expert.md §4: the reference's `0.5·c·v²` costs
/// with a doubled Hessian minimise `c·v²`); the slack weight is HPIPM's `Z` (cost `½·Z·σ²`).
///
/// A run's expert always takes `Default`, in one place: [`crate::Mpcc::from_config`], the constructor of the run's
/// MPCC that every process goes through (the expert server, `learner run --local` and the actors' in-process expert
/// by `Expert::from_config`, `expert-server drive`, `bench`, and [`crate::Mpcc::reference`] for the Python bindings
/// and the tests). It is not a section of the run configuration: no run varies these numbers (the paper's expert is
/// the reference's), and every recorded `config.toml` would grow by a section; a study that tunes the expert sets
/// the fields here and builds with [`crate::Mpcc::new`], as the MPCC's own tests do.
/// Which LDL factorisation Clarabel runs on the KKT system.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Ldl {
    /// QDLDL, Clarabel's default.
    Qdldl,
    /// faer's sparse LDLᵀ.
    Faer,
}

impl Ldl {
    /// Clarabel's name for it (`direct_solve_method`).
    pub fn clarabel_name(self) -> &'static str {
        match self {
            Ldl::Qdldl => "qdldl",
            Ldl::Faer => "faer",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MpccConfig {
    /// Horizon length N (stages).
    pub horizon: usize,
    /// Control period dt [s] (the plant's, `cabc_sim::env::DT`).
    pub dt: f64,
    /// RK4 sub-steps per dt in the prediction model (M = 10, h = 0.01 s).
    pub rk4_substeps: usize,

    /// Contouring-error weight q_c (also terminal q_cN).
    pub q_contour: f64,
    /// Lag-error weight q_l (also terminal q_lN).
    pub q_lag: f64,
    /// Yaw-rate weight at stages 1..N−1.
    pub q_yaw_rate: f64,
    /// Yaw-rate weight at the terminal stage N.
    pub q_yaw_rate_terminal: f64,
    /// Input weights on (a, δ, v_s).
    pub r_input: [f64; 3],
    /// Linear progress reward on v_s (the cost is −reward·v_s per stage).
    pub progress_reward: f64,
    /// Weights on the **scaled** input rates r = T_w·Δw/dt (expert.md §6).
    pub r_rate: [f64; 3],
    /// Quadratic track-slack weight Z (cost ½·Z·σ²; HPIPM's Zl = Zu).
    pub slack_weight: f64,
    /// Regularisation added to each scaled stage Hessian diagonal (the reference's 1e−10·I).
    pub hessian_reg: f64,

    /// Lower state bounds on (v_x, v_y, ω, ψ); X and Y are unbounded (the reference's ±1e9).
    pub state_lb: [f64; 4],
    /// Upper state bounds on (v_x, v_y, ω, ψ).
    pub state_ub: [f64; 4],
    /// Progress bounds: s ∈ [s_lb, s_ub_laps·L].
    pub s_lb: f64,
    /// Upper progress bound in track lengths (2).
    pub s_ub_laps: f64,
    /// Input lower bounds (a, δ, v_s).
    pub input_lb: [f64; 3],
    /// Input upper bounds (a, δ, v_s).
    pub input_ub: [f64; 3],
    /// Symmetric bounds on the scaled rates r (40, 4.5, 5).
    pub rate_bound: [f64; 3],

    /// Boundary tightening [m]: the boundary splines sit at e_y = ±(half_width − tightening).
    pub track_tightening: f64,
    /// Number of spline sample points along the track (100, including both ends).
    pub spline_points: usize,
    /// The most arc length between two spline points (m): a track longer than the L-track gets more points, at
    /// the L-track's density (0.2 m; its 100 points are 0.176 m apart).
    pub max_spline_spacing: f64,

    /// State scaling T_x⁻¹ (physical = scale × scaled) for (v_x, v_y, ω, X, Y, ψ); s uses ⌈L⌉.
    pub state_scale: [f64; 6],
    /// Input scaling T_w⁻¹ for (a, δ, v_s).
    pub input_scale: [f64; 3],

    /// QP iterations per control step.
    pub qp_iters: usize,
    /// A control step stops its QP loop early once a QP's step D* − D is this small (the largest change of a scaled
    /// stage variable, inputs and states alike), as an SQP stops at convergence: the next QP would be built around
    /// nearly the same iterate. 0: always `qp_iters` QPs (the reference).
    pub qp_converged_step: f64,
    /// Weight of the previous iterate in the damped update D ← damping·D + (1 − damping)·D*.
    pub damping: f64,
    /// QP iterations at a stream's start.
    pub start_qp_iters: usize,
    /// Damping at a stream's start.
    pub start_damping: f64,
    /// Initial (a, δ) of the warm start and of w_prev at a stream's start (v_s starts at 0).
    pub start_input: f64,

    /// Clarabel iteration limit.
    pub max_iter: u32,
    /// Clarabel absolute and relative gap tolerance (1e-5: HPIPM's tol_comp in the reference).
    pub tol_gap: f64,
    /// Clarabel feasibility tolerance.
    pub tol_feas: f64,
    /// (gap, feasibility) tolerances of every QP of a step but its last, which only moves the point the last is
    /// linearised around. None: every QP at `tol_gap`, `tol_feas` (the reference).
    pub lead_qp_tol: Option<(f64, f64)>,
    /// Clarabel's relative gap tolerance when it differs from the absolute one (None: `tol_gap`).
    pub tol_gap_rel: Option<f64>,
    /// Clarabel's largest step toward the cone's boundary (its default 0.99).
    pub max_step_fraction: f64,
    /// Count Clarabel's `AlmostSolved` (reduced accuracy) as success. Off: HPIPM has no such status and stops
    /// with "max iterations" where Clarabel would fall back to reduced tolerances.
    pub accept_almost_solved: bool,
    /// Clarabel's iterative refinement of each KKT solve. Off: about 40 % faster steps here, with the same
    /// iteration counts and success rate (the residual checks that decide `Solved` use the exact data).
    pub iterative_refinement: bool,
    /// Clarabel's Ruiz equilibration on top of the reference's variable scaling T_x, T_w. Off (like HPIPM, which
    /// has none): the T-scaling is enough, and it takes ~40 % fewer interior-point iterations with the same
    /// closed-loop results.
    pub equilibrate: bool,
    /// Solve each QP first without the box rows of v_x, v_y, ω and ψ (bounds a drive does not reach), and again
    /// with them only when its minimiser leaves those boxes: the same minimiser (the lean QP is a relaxation of the
    /// full one), a smaller KKT system (issue 75). False: every row, always (the reference).
    pub lazy_state_boxes: bool,
    /// The LDL factorisation of Clarabel's KKT system: QDLDL (Clarabel's own, the default) or faer's sparse LDLᵀ
    /// (Clarabel's `faer-sparse` back end; this crate's `faer` feature).
    pub ldl: Ldl,
    /// Reuse one Clarabel solver per stream and overwrite its data (`update_P/q/A/b`) instead of rebuilding.
    pub reuse_solver: bool,
}

impl Default for MpccConfig {
    fn default() -> Self {
        Self {
            horizon: 20,
            dt: cabc_sim::env::DT,
            rk4_substeps: cabc_sim::env::SUBSTEPS,
            q_contour: 0.1,
            q_lag: 1000.0,
            q_yaw_rate: 1e-5,
            q_yaw_rate_terminal: 1e-4,
            r_input: [1e-3, 1e-3, 1e-4],
            progress_reward: 0.03,
            r_rate: [0.01, 0.01, 1e-3],
            slack_weight: 10000.0,
            hessian_reg: 1e-10,
            state_lb: [-4.0, -2.0, -7.0, -10.0],
            state_ub: [4.0, 2.0, 7.0, 10.0],
            s_lb: -1.0,
            s_ub_laps: 2.0,
            input_lb: [-2.0, -0.45, 0.0],
            input_ub: [2.0, 0.45, 4.5],
            rate_bound: [40.0, 4.5, 5.0],
            track_tightening: 0.1,
            spline_points: 100,
            max_spline_spacing: 0.2,
            state_scale: [4.0, 2.0, 7.0, 6.0, 6.0, 2.0 * std::f64::consts::PI],
            input_scale: [2.0, 0.436, 4.5],
            qp_iters: 2,
            qp_converged_step: 0.0,
            damping: 0.25,
            start_qp_iters: 5,
            start_damping: 0.5,
            start_input: 1e-3,
            max_iter: 200,
            tol_gap: 1e-5,
            tol_feas: 1e-6,
            lead_qp_tol: None,
            tol_gap_rel: None,
            max_step_fraction: 0.99,
            accept_almost_solved: false,
            iterative_refinement: false,
            equilibrate: false,
            lazy_state_boxes: false,
            ldl: Ldl::Qdldl,
            reuse_solver: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_through_json_and_fills_defaults() {
        let c = MpccConfig {
            qp_iters: 3,
            ..MpccConfig::default()
        };
        let s = serde_json::to_string(&c).unwrap();
        assert_eq!(serde_json::from_str::<MpccConfig>(&s).unwrap(), c);
        let partial: MpccConfig = serde_json::from_str(r#"{"damping": 0.5}"#).unwrap();
        assert_eq!(partial.damping, 0.5);
        assert_eq!(partial.horizon, 20);
    }
}
