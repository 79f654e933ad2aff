//! MPCC-conv: the convexified model predictive contouring controller of the seed paper's expert (expert.md).
//!
//! Per control step (expert.md §7): measure (q̂ with ψ mod 2π, ŝ from the exact Frenet projection), roll the
//! shifted warm start w̄_ws out with the nonlinear RK4 model, then `qp_iters` (2) times build the convex QP around
//! the iterate D — RK4 Jacobians, Gauss–Newton contouring/lag errors on not-a-knot track splines, input-rate
//! variables, a soft track slab frozen at the warm-start progress, hard boxes, scaled variables — solve it with
//! Clarabel and take the damped step D ← 0.25·D + 0.75·D*. The action is the first input of the *blended* iterate.
//! A stream starts with 5 such iterations, damping 0.5, from a 1e−3 input guess (`Mpcc::start`).
//!
//! # Reference quirks kept on purpose
//! * Transition k → k+1 is linearised at (q̄_k, w̄_{k−1}), the input stored with stage k, not the one applied on
//!   the interval (the reference linearises the rate-augmented dynamics at zero rate).
//! * Rate bounds and weights act on *scaled* rates r = T_w·Δw/dt (|Δδ| ≤ 0.196 rad per step, §6).
//! * The track constraint is a soft slab with a quadratic-only penalty, linearised at the warm-start progress and
//!   kept fixed over the iterations of a step; the reference point is the midpoint of the two tightened boundaries.
//! * The applied action comes from the blended (damped) iterate; no line search, no convergence test.
//! * On failure the shifted previous plan is replayed (its first input is applied) and `success = false`; start-up
//!   failures only stop the start-up loop. w_prev is the expert's own previous output (not the applied action).
//! * Spline lookups use C `fmod(s, L)`; the splines are not periodic (derivatives jump slightly at s = 0 ≡ L).
//! * The first step after `start` uses w_prev = (1e−3, 1e−3, 0) (the reference never stores it at reset).
//!
//! # Deviations from the reference (and why)
//! * **Clarabel instead of HPIPM** (the project's solver); the QP has the same minimiser, posed differently:
//!   - stage 0 is substituted into the right-hand side instead of being fixed by lbx = ubx;
//!   - the input rates are eliminated (r_k = T_w(w_k − w_{k−1})/dt): their cost becomes a banded quadratic in w
//!     and their boxes rows on w_k − w_{k−1} (HPIPM has them as stage inputs); a smaller KKT system;
//!   - one free σ_k per stage relaxes both slab sides (HPIPM: σ_l, σ_u ≥ 0). Equivalent: for fixed (X, Y) the
//!     minimiser of ½Zσ² over the relaxed slab is σ = max(0, violation), and at most one side is violated;
//!   - the inactive ±1e9 bounds on X, Y are dropped, and so are the acceleration's rate rows after stage 1, which
//!     can never bind (its box is narrower than its rate bound allows; see the `qp` module docs);
//!   - the QP is posed in the deviation Δ = z − z̄ from the iterate (Gauss–Newton expanded around the origin makes
//!     the objective ~1e5, and Clarabel's *relative* gap tolerance then left slacks at ~6e−4 on a straight);
//!   - tolerances: feasibility 1e−6 as HPIPM's tol_eq/ineq, gap (abs, rel) 1e−5 as HPIPM's tol_comp (the duality
//!     gap is the complementarity measure), 200 iterations; 1e−6 on the gap cost 3 more iterations a step (18
//!     against 15) for the same laps. Clarabel's equilibration and iterative refinement are off by default
//!     (HPIPM has neither; the reference's T-scaling conditions the problem): ~40 % fewer iterations and ~40 %
//!     cheaper iterations, the same laps and the same random-spawn failure rate (`MpccConfig::equilibrate`,
//!     `MpccConfig::iterative_refinement` turn them back on).
//! * **success = Clarabel `Solved`**. `AlmostSolved` (reduced accuracy after a stall) counts as a failure by
//!   default, matching HPIPM, which would stop at its iteration limit instead; `accept_almost_solved` flips it.
//! * Exact RK4 Jacobians come from forward sensitivities with the simulator's hand-derived continuous Jacobians
//!   instead of CasADi AD (equal to round-off; tested against central differences).
//! * A QP whose assembled data is not finite is not handed to the solver: status `NonFiniteData`, a failure.
//! * q_pred, the nonlinear rollout of the plan (§7.5, "for prediction output only"), is computed on demand by
//!   [`Mpcc::predict`] instead of inside every step: neither the control loop nor the relabelling service uses it.
//! * Measurements that are not finite or farther than 0.85 m from the centreline return [`MpccError`] (the
//!   reference raises from `global_to_local`); the stream is left unchanged.
//! * The solver is cached per stream and refilled through Clarabel's data-update interface (the pattern is
//!   fixed). With equilibration on, a reused solver that fails is retried once with a fresh one (its
//!   equilibration belongs to an earlier QP and was seen to cause spurious `NumericalError`s).
//!
//! # Known behaviour of the reference algorithm (kept, measured here)
//! * From the fixed spawn: no failure, no truncation; flying laps 4.6–4.8 s (mean 4.70 s), first lap 5.5 s.
//!   The env's logged `lap_time` adds one step (simulator.md §3.7): ≈ 4.81 s, the paper's 4.805 s.
//! * From random spawns *in curves* the start-up QPs (all slabs at ŝ, an infinite strip along the tangent there)
//!   plan to stop before leaving the strip; predicted speeds then fall below ≈ 0.36 m/s, where RK4 with
//!   h = 0.01 s is unstable for the tyre dynamics (λ ≈ −2·B·C·D/(m v_x)), the Jacobians reach ~1e6, the QPs fail
//!   (`NumericalError`), the fallback replays the braking plan and the car stalls (v_long < 0.25). About 40 % of
//!   random spawns with |e_y|, |e_ψ| ≤ 0.5 end this way within 60 steps (`stress_random_spawns`). The model,
//!   the slab linearisation and the fallback are the reference's, so this is expected of it too.

mod config;
mod contour;
mod pattern;
pub mod phases;
mod qp;
mod status;

use std::time::{Duration, Instant};

use cabc_proto::config::RunConfig;
use cabc_sim::track::{Track, TrackError};
use cabc_sim::vehicle::{State, VehicleParams};

pub use config::{Ldl, MpccConfig};
pub use contour::{ContourErrors, Slab, TrackSplines};
pub use qp::{Linearisation, QpLayout, QpSolution, QpStatus, QpWorkspace, Stage};

use crate::rk4::{Rk4, NQ};
use crate::spline::SplineError;
use qp::{QpInput, NZ, S, VS};

/// Why the controller could not be built or could not run a step.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpccError {
    #[error("invalid MPCC configuration: {0}")]
    Config(String),
    #[error("track splines: {0}")]
    Spline(#[from] SplineError),
    #[error("measured state is not finite: {0:?}")]
    NonFinite(State),
    #[error("measured state is off the track: {0}")]
    OffTrack(#[from] TrackError),
    #[error("the track (sim.track): {0}")]
    Track(TrackError),
}

/// The controller: track splines, model and configuration. Immutable, `Send + Sync`; one per process is enough.
#[derive(Debug, Clone)]
pub struct Mpcc {
    cfg: MpccConfig,
    track: Track,
    splines: TrackSplines,
    model: VehicleParams,
    rk4: Rk4,
    layout: QpLayout,
    /// The lean layout tried first under `lazy_state_boxes`.
    lean: Option<QpLayout>,
    /// The layout of the QPs before a step's last, at `lead_qp_tol`.
    lead: Option<QpLayout>,
}

/// Per-stream controller memory (expert.md §7): the warm start w̄_ws (N+1 rows of (a, δ, v_s)), w_prev, and the
/// cached QP solver. Create with [`Mpcc::start`]; one per episode.
#[derive(Debug)]
pub struct MpccStream {
    w_ws: Vec<[f64; 3]>,
    w_prev: [f64; 3],
    steps: u64,
    /// The QP solvers: the layout a step solves first, and the full layout's under `lazy_state_boxes` (its
    /// fallback).
    ws: [QpWorkspace; 2],
}

impl MpccStream {
    /// The current warm start w̄_ws (rows 0..N of (a, δ, v_s)).
    pub fn warm_start(&self) -> &[[f64; 3]] {
        &self.w_ws
    }

    /// w_prev = w_{−1} of the next QP.
    pub fn w_prev(&self) -> [f64; 3] {
        self.w_prev
    }

    /// Steps taken on this stream.
    pub fn steps(&self) -> u64 {
        self.steps
    }
}

/// What one control step returns.
#[derive(Debug, Clone)]
pub struct MpccStep {
    /// (a, δ) to apply.
    pub action: [f64; 2],
    /// Every QP of the step returned `Solved`.
    pub success: bool,
    /// The first failing QP's status, else the last QP's.
    pub status: QpStatus,
    /// QPs solved (attempted) in this step.
    pub qps: u32,
    /// Sum of Clarabel's interior-point iterations.
    pub qp_iterations: u32,
    /// QPs solved again with every row because the lean QP's minimiser left a lazy box (`lazy_state_boxes`).
    pub full_resolves: u32,
    /// Wall time spent inside Clarabel (setup or data update, and solve), summed over the QPs.
    pub solve_time: Duration,
    /// Wall time of the whole step (rollout, linearisation, assembly, solves).
    pub step_time: Duration,
    /// The measurement (q̂ with ψ mod 2π, ŝ) the step started from.
    pub measured: [f64; 7],
    /// The plan w_pred (N rows of (a, δ, v_s)); `plan[0]` holds the action.
    pub plan: Vec<[f64; 3]>,
}

/// The predicted trajectory q_pred of a step (expert.md §7.5): the nonlinear rollout of its plan.
#[derive(Debug, Clone)]
pub struct Prediction {
    /// N+1 states from q̂ (ψ continues from ψ̂ = ψ mod 2π).
    pub states: Vec<State>,
    /// Progress s along them (N+1 values, not wrapped).
    pub s: Vec<f64>,
}

/// Outcome of the QP loop around one warm start.
struct LoopOutcome {
    iterate: Vec<Stage>,
    success: bool,
    status: QpStatus,
    qps: u32,
    iterations: u32,
    full_resolves: u32,
    solve_time: Duration,
}

impl Mpcc {
    /// The controller for `track` with the prediction model `model` (the simulator's vehicle).
    pub fn new(track: Track, model: VehicleParams, cfg: MpccConfig) -> Result<Self, MpccError> {
        if cfg.horizon == 0 || cfg.rk4_substeps == 0 || cfg.dt.is_nan() || cfg.dt <= 0.0 {
            return Err(MpccError::Config(
                "horizon, rk4_substeps and dt must be positive".into(),
            ));
        }
        if !(0.0..1.0).contains(&cfg.damping) || !(0.0..1.0).contains(&cfg.start_damping) {
            return Err(MpccError::Config("damping must lie in [0, 1)".into()));
        }
        let tolerance = |t: f64| t > 0.0 && t < 1.0;
        if !(tolerance(cfg.tol_gap) && tolerance(cfg.tol_feas)) {
            return Err(MpccError::Config(
                "tol_gap and tol_feas must lie in (0, 1)".into(),
            ));
        }
        if !(cfg.qp_converged_step >= 0.0 && cfg.qp_converged_step.is_finite()) {
            return Err(MpccError::Config(
                "qp_converged_step must be a number >= 0".into(),
            ));
        }
        if cfg!(not(feature = "faer")) && cfg.ldl == Ldl::Faer {
            return Err(MpccError::Config(
                "ldl = faer needs cabc-expert's `faer` feature (Clarabel's faer back end)".into(),
            ));
        }
        if !(cfg.max_spline_spacing > 0.0 && cfg.max_spline_spacing.is_finite()) {
            return Err(MpccError::Config(
                "max_spline_spacing must be a positive number".into(),
            ));
        }
        if cfg.lead_qp_tol.is_some() && cfg.lazy_state_boxes {
            return Err(MpccError::Config(
                "lead_qp_tol and lazy_state_boxes both use the second QP workspace".into(),
            ));
        }
        if cfg.spline_points < 4 {
            return Err(MpccError::Config("spline_points must be at least 4".into()));
        }
        // A longer track than the L-track keeps the L-track's density of spline points.
        let points = cfg
            .spline_points
            .max((track.length() / cfg.max_spline_spacing).ceil() as usize + 1);
        let splines = TrackSplines::new(&track, points, cfg.track_tightening)?;
        let layout = QpLayout::new(&cfg, track.length());
        let lean = cfg
            .lazy_state_boxes
            .then(|| QpLayout::lean(&cfg, track.length()));
        let lead = cfg.lead_qp_tol.map(|(gap, feas)| {
            let loose = MpccConfig {
                tol_gap: gap,
                tol_feas: feas,
                ..cfg.clone()
            };
            QpLayout::new(&loose, track.length())
        });
        let rk4 = Rk4 {
            dt: cfg.dt,
            substeps: cfg.rk4_substeps,
        };
        Ok(Self {
            cfg,
            track,
            splines,
            model,
            rk4,
            layout,
            lean,
            lead,
        })
    }

    /// The run's expert: the reference controller ([`MpccConfig::default`]) with the run's `expert.mpcc_lazy_boxes`
    /// (off by default) and `expert.mpcc_tol_gap`, `expert.mpcc_tol_feas` (the reference's 1e-5 and 1e-6 by
    /// default) on the run's track (`sim.track`), its prediction model the simulator's vehicle. The one
    /// constructor of the MPCC of a run (expert server, actors, `learner run --local`, `expert-server drive` and
    /// `bench`).
    pub fn from_config(config: &RunConfig) -> Result<Self, MpccError> {
        let cfg = MpccConfig {
            lazy_state_boxes: config.expert.mpcc_lazy_boxes,
            tol_gap: config.expert.mpcc_tol_gap,
            tol_feas: config.expert.mpcc_tol_feas,
            ..MpccConfig::default()
        };
        let track = Track::of(&config.sim).map_err(MpccError::Track)?;
        Self::new(track.as_ref().clone(), VehicleParams::default(), cfg)
    }

    /// The reference controller on `L_track_barc` with the reference vehicle: the default configuration's expert.
    pub fn reference() -> Self {
        Self::from_config(&RunConfig::default()).expect("the reference configuration is valid")
    }

    /// The configuration.
    pub fn config(&self) -> &MpccConfig {
        &self.cfg
    }

    /// The track.
    pub fn track(&self) -> &Track {
        &self.track
    }

    /// The track splines.
    pub fn splines(&self) -> &TrackSplines {
        &self.splines
    }

    /// The QP layout.
    pub fn layout(&self) -> &QpLayout {
        &self.layout
    }

    /// (q̂, ŝ): ψ mod 2π and the exact Frenet progress (expert.md §7.1).
    fn measure(&self, q: &State) -> Result<[f64; 7], MpccError> {
        if q.iter().any(|v| !v.is_finite()) {
            return Err(MpccError::NonFinite(*q));
        }
        let psi = q[5].rem_euclid(2.0 * std::f64::consts::PI);
        let s = self.track.global_to_local(q[3], q[4], psi)?.s;
        Ok([q[0], q[1], q[2], q[3], q[4], psi, s])
    }

    /// Nonlinear rollout of inputs `w[0..N]` (w[k] applied on [k, k+1]) from x0; returns N+1 stages' (q, s).
    fn rollout(&self, x0: &[f64; 7], w: &[[f64; 3]]) -> Vec<[f64; 7]> {
        let mut out = Vec::with_capacity(w.len() + 1);
        out.push(*x0);
        for wk in w {
            let x = out.last().expect("nonempty");
            let q: [f64; NQ] = std::array::from_fn(|i| x[i]);
            let qn = self.rk4.map(&self.model, &q, &[wk[0], wk[1]]);
            out.push([
                qn[0],
                qn[1],
                qn[2],
                qn[3],
                qn[4],
                qn[5],
                x[S] + self.cfg.dt * wk[2],
            ]);
        }
        out
    }

    /// The QP loop of expert.md §7.2–3 around the warm start `w_ws` (N+1 rows) from `x0`.
    fn qp_loop(
        &self,
        ws: &mut [QpWorkspace; 2],
        x0: &[f64; 7],
        w_ws: &[[f64; 3]],
        w_prev: [f64; 3],
        iters: usize,
        damping: f64,
    ) -> LoopOutcome {
        let (mut d, slabs) = self.initial_iterate(x0, w_ws);
        let mut out = LoopOutcome {
            iterate: Vec::new(),
            success: true,
            status: QpStatus::NotRun,
            qps: 0,
            iterations: 0,
            full_resolves: 0,
            solve_time: Duration::ZERO,
        };
        for i in 0..iters {
            let (sol, resolved) = self.qp_around(&d, &slabs, w_prev, ws, i + 1 < iters);
            out.qps += 1;
            out.full_resolves += u32::from(resolved);
            out.iterations += sol.iterations;
            out.solve_time += sol.solve_time;
            out.status = sol.status;
            if !sol.status.is_success(self.cfg.accept_almost_solved) {
                out.success = false;
                break;
            }
            let mut largest_step = 0.0f64;
            for (dk, sk) in d.iter_mut().zip(&sol.stages).skip(1) {
                for j in 0..NZ {
                    largest_step = largest_step.max((sk[j] - dk[j]).abs() / self.layout.scale[j]);
                    dk[j] = damping * dk[j] + (1.0 - damping) * sk[j];
                }
            }
            if largest_step < self.cfg.qp_converged_step {
                break;
            }
        }
        out.iterate = d;
        out
    }

    /// Start a stream at state `q` (expert.md §7, reset): 1e−3 input guess, `start_qp_iters` (5) QP iterations
    /// with damping `start_damping` (0.5); QP failures only stop the loop.
    pub fn start(&self, q: &State) -> Result<MpccStream, MpccError> {
        let x0 = self.measure(q)?;
        let u0 = self.cfg.start_input;
        let w0 = [u0, u0, 0.0];
        let w_ws = vec![w0; self.cfg.horizon + 1];
        let mut ws = [QpWorkspace::default(), QpWorkspace::default()];
        let out = self.qp_loop(
            &mut ws,
            &x0,
            &w_ws,
            w0,
            self.cfg.start_qp_iters,
            self.cfg.start_damping,
        );
        Ok(MpccStream {
            w_ws: out.iterate.iter().map(|z| [z[7], z[8], z[VS]]).collect(),
            w_prev: w0,
            steps: 0,
            ws,
        })
    }

    /// One control step for the stream at measured state `q` (global frame, ψ may be unwrapped).
    pub fn step(&self, stream: &mut MpccStream, q: &State) -> Result<MpccStep, MpccError> {
        let t0 = Instant::now();
        let n = self.cfg.horizon;
        let x0 = self.measure(q)?;
        let out = self.qp_loop(
            &mut stream.ws,
            &x0,
            &stream.w_ws,
            stream.w_prev,
            self.cfg.qp_iters,
            self.cfg.damping,
        );
        let plan: Vec<[f64; 3]> = if out.success {
            out.iterate[1..]
                .iter()
                .map(|z| [z[7], z[8], z[VS]])
                .collect()
        } else {
            stream.w_ws[1..].to_vec()
        };
        // Shift: w̄_ws ← [w_pred[0..N], w_pred[N−1]], w_prev ← w_pred[0].
        stream.w_ws.clear();
        stream.w_ws.extend_from_slice(&plan);
        stream.w_ws.push(plan[n - 1]);
        stream.w_prev = plan[0];
        stream.steps += 1;
        Ok(MpccStep {
            action: [plan[0][0], plan[0][1]],
            success: out.success,
            status: out.status,
            qps: out.qps,
            qp_iterations: out.iterations,
            full_resolves: out.full_resolves,
            solve_time: out.solve_time,
            step_time: t0.elapsed(),
            measured: x0,
            plan,
        })
    }

    /// The predicted trajectory of `step`: its plan rolled out with the nonlinear model from its measurement.
    /// The reference computes it inside every step "for prediction output only"; nothing in the control loop or
    /// the relabelling service uses it, so it is computed on demand (it costs 20 more RK4 intervals).
    pub fn predict(&self, step: &MpccStep) -> Prediction {
        let xs = self.rollout(&step.measured, &step.plan);
        Prediction {
            states: xs.iter().map(|x| std::array::from_fn(|i| x[i])).collect(),
            s: xs.iter().map(|x| x[S]).collect(),
        }
    }

    /// Build and solve a single QP around the warm start of `stream` at `q` without changing the stream
    /// (diagnostics and tests).
    pub fn probe_qp(&self, stream: &MpccStream, q: &State) -> Result<QpSolution, MpccError> {
        let x0 = self.measure(q)?;
        let (d, slabs) = self.initial_iterate(&x0, &stream.w_ws);
        let mut ws = [QpWorkspace::default(), QpWorkspace::default()];
        Ok(self.qp_around(&d, &slabs, stream.w_prev, &mut ws, false).0)
    }

    /// The initial iterate of a step (nonlinear rollout of w̄_ws[1..N] from x0; stage k holds w̄_ws[k]) and the
    /// slabs at its progress, which stay fixed for all iterations of the step.
    fn initial_iterate(&self, x0: &[f64; 7], w_ws: &[[f64; 3]]) -> (Vec<Stage>, Vec<Slab>) {
        let xs = self.rollout(x0, &w_ws[1..]);
        let d = xs
            .iter()
            .zip(w_ws)
            .map(|(x, w)| [x[0], x[1], x[2], x[3], x[4], x[5], x[6], w[0], w[1], w[2]])
            .collect();
        let slabs = xs[1..].iter().map(|x| self.splines.slab(x[S])).collect();
        (d, slabs)
    }

    /// Linearise around the iterate `d` (transition k at (q̄_k, w̄_{k−1}), errors at stages 1..N) and solve: with
    /// `lazy_state_boxes` the lean QP first (workspace 0), and the full one (workspace 1) only when the lean
    /// minimiser leaves a box it left out or the lean QP failed; whether it was solved again.
    /// A step's QPs before its last (`lead`) go to the `lead_qp_tol` layout (workspace 1) when there is one.
    fn qp_around(
        &self,
        d: &[Stage],
        slabs: &[Slab],
        w_prev: [f64; 3],
        ws: &mut [QpWorkspace; 2],
        lead: bool,
    ) -> (QpSolution, bool) {
        let n = self.cfg.horizon;
        let lin: Vec<Linearisation> = d[..n]
            .iter()
            .map(|z| {
                let q: [f64; NQ] = std::array::from_fn(|i| z[i]);
                let (f, a, b) = self.rk4.map_with_jacobians(&self.model, &q, &[z[7], z[8]]);
                Linearisation { f, a, b }
            })
            .collect();
        let errors: Vec<ContourErrors> = d[1..]
            .iter()
            .map(|z| self.splines.errors(z[3], z[4], z[S]))
            .collect();
        let input = QpInput {
            iterate: d,
            lin: &lin,
            errors: &errors,
            slabs,
            w_prev,
        };
        let [ws, ws_full] = ws;
        if let (true, Some(layout)) = (lead, &self.lead) {
            return (layout.solve(&input, ws_full), false);
        }
        let Some(lean) = &self.lean else {
            return (self.layout.solve(&input, ws), false);
        };
        let tried = lean.solve(&input, ws);
        if tried.status.is_success(self.cfg.accept_almost_solved) && lean.within_lazy_boxes(&tried)
        {
            return (tried, false);
        }
        let mut full = self.layout.solve(&input, ws_full);
        full.iterations += tried.iterations;
        full.solve_time += tried.solve_time;
        (full, true)
    }
}

#[cfg(test)]
mod tests;
