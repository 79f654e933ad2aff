//! The MPC's discrete prediction model: RK4 with M sub-steps, input held, and its exact Jacobians (expert.md §2).
//!
//! The reference differentiates the RK4 map with CasADi AD through all sub-steps. Here the same derivatives come
//! from forward sensitivities: each RK4 stage `k_i = f(q_i, u)` is differentiated with the ODE's continuous
//! Jacobians, `dk_i = ∂f/∂q(q_i,u)·dq_i + ∂f/∂u(q_i,u)·du`, and the sensitivities are accumulated like the state.
//! The result equals AD of the discrete map up to round-off.

use nalgebra::{SMatrix, SVector};

/// State dimension of the vehicle model (v_x, v_y, ω, X, Y, ψ).
pub const NQ: usize = 6;
/// Input dimension (a, δ).
pub const NU: usize = 2;

/// Jacobian of the discrete map with respect to the state.
pub type JacQ = SMatrix<f64, NQ, NQ>;
/// Jacobian of the discrete map with respect to the input.
pub type JacU = SMatrix<f64, NQ, NU>;

/// A continuous-time model `q̇ = f(q, u)` with its Jacobians.
pub trait Ode {
    /// `f(q, u)`.
    fn f(&self, q: &[f64; NQ], u: &[f64; NU]) -> [f64; NQ];
    /// `(∂f/∂q, ∂f/∂u)` at `(q, u)`.
    fn jac(&self, q: &[f64; NQ], u: &[f64; NU]) -> (JacQ, JacU);
    /// `f` and its Jacobians together (override where they share work: the tyre forces).
    fn f_and_jac(&self, q: &[f64; NQ], u: &[f64; NU]) -> ([f64; NQ], JacQ, JacU) {
        let (a, b) = self.jac(q, u);
        (self.f(q, u), a, b)
    }
}

impl Ode for cabc_sim::vehicle::VehicleParams {
    fn f(&self, q: &[f64; NQ], u: &[f64; NU]) -> [f64; NQ] {
        self.derivatives(q, u)
    }
    fn jac(&self, q: &[f64; NQ], u: &[f64; NU]) -> (JacQ, JacU) {
        self.jacobians(q, u)
    }
    fn f_and_jac(&self, q: &[f64; NQ], u: &[f64; NU]) -> ([f64; NQ], JacQ, JacU) {
        self.derivatives_and_jacobians(q, u)
    }
}

/// The RK4 map over `dt` in `substeps` equal sub-steps, input held constant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rk4 {
    /// Control period [s] (0.1).
    pub dt: f64,
    /// Number of RK4 sub-steps (10, so h = 0.01 s).
    pub substeps: usize,
}

fn axpy(q: &[f64; NQ], a: f64, k: &[f64; NQ]) -> [f64; NQ] {
    std::array::from_fn(|i| q[i] + a * k[i])
}

impl Rk4 {
    /// `f_d(q, u)`.
    pub fn map<M: Ode + ?Sized>(&self, model: &M, q: &[f64; NQ], u: &[f64; NU]) -> [f64; NQ] {
        let h = self.dt / self.substeps as f64;
        let mut q = *q;
        for _ in 0..self.substeps {
            let k1 = model.f(&q, u);
            let k2 = model.f(&axpy(&q, h / 2.0, &k1), u);
            let k3 = model.f(&axpy(&q, h / 2.0, &k2), u);
            let k4 = model.f(&axpy(&q, h, &k3), u);
            q = std::array::from_fn(|i| {
                q[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
        }
        q
    }

    /// `f_d(q, u)` with its exact Jacobians `A_d = ∂f_d/∂q`, `B_d = ∂f_d/∂u`.
    pub fn map_with_jacobians<M: Ode + ?Sized>(
        &self,
        model: &M,
        q: &[f64; NQ],
        u: &[f64; NU],
    ) -> ([f64; NQ], JacQ, JacU) {
        let h = self.dt / self.substeps as f64;
        let mut q = *q;
        // Sensitivities of the current sub-step state with respect to the initial (q, u).
        let mut sq = JacQ::identity();
        let mut su = JacU::zeros();
        // dk = Jq·(sq, su) + (0, Ju) for the stage evaluated at `qs` whose sensitivities are (sq, su).
        let stage = |qs: &[f64; NQ], sq: &JacQ, su: &JacU| {
            let (k, jq, ju) = model.f_and_jac(qs, u);
            (k, jq * sq, jq * su + ju)
        };
        for _ in 0..self.substeps {
            let (k1, dq1, du1) = stage(&q, &sq, &su);
            let (k2, dq2, du2) = stage(
                &axpy(&q, h / 2.0, &k1),
                &(sq + dq1 * (h / 2.0)),
                &(su + du1 * (h / 2.0)),
            );
            let (k3, dq3, du3) = stage(
                &axpy(&q, h / 2.0, &k2),
                &(sq + dq2 * (h / 2.0)),
                &(su + du2 * (h / 2.0)),
            );
            let (k4, dq4, du4) = stage(&axpy(&q, h, &k3), &(sq + dq3 * h), &(su + du3 * h));
            q = std::array::from_fn(|i| {
                q[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
            sq += (dq1 + (dq2 + dq3) * 2.0 + dq4) * (h / 6.0);
            su += (du1 + (du2 + du3) * 2.0 + du4) * (h / 6.0);
        }
        (q, sq, su)
    }
}

/// `[f64; NQ]` as a column vector.
pub fn col(q: &[f64; NQ]) -> SVector<f64, NQ> {
    SVector::from_column_slice(q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_sim::vehicle::VehicleParams;

    /// Central finite differences of the RK4 map, one column per perturbed coordinate.
    fn fd(rk: &Rk4, p: &VehicleParams, q: &[f64; NQ], u: &[f64; NU], eps: f64) -> (JacQ, JacU) {
        let mut a = JacQ::zeros();
        let mut b = JacU::zeros();
        for j in 0..NQ {
            let (mut qp, mut qm) = (*q, *q);
            qp[j] += eps;
            qm[j] -= eps;
            let (fp, fm) = (rk.map(p, &qp, u), rk.map(p, &qm, u));
            for i in 0..NQ {
                a[(i, j)] = (fp[i] - fm[i]) / (2.0 * eps);
            }
        }
        for j in 0..NU {
            let (mut up, mut um) = (*u, *u);
            up[j] += eps;
            um[j] -= eps;
            let (fp, fm) = (rk.map(p, q, &up), rk.map(p, q, &um));
            for i in 0..NQ {
                b[(i, j)] = (fp[i] - fm[i]) / (2.0 * eps);
            }
        }
        (a, b)
    }

    #[test]
    fn jacobians_match_central_differences() {
        let p = VehicleParams::default();
        let rk = Rk4 {
            dt: 0.1,
            substeps: 10,
        };
        let cases: [([f64; NQ], [f64; NU]); 4] = [
            ([2.0, 0.0, 0.0, 1.0, 0.2, 0.3], [0.5, 0.0]),
            ([3.1, 0.35, 2.4, -1.0, 3.0, 2.0], [-1.2, 0.3]),
            ([1.2, -0.4, -3.0, 0.5, 0.5, -1.0], [1.8, -0.42]),
            ([3.9, 0.1, 1.0, 2.2, 2.0, 6.0], [2.0, 0.1]),
        ];
        for (q, u) in cases {
            let (qn, a, b) = rk.map_with_jacobians(&p, &q, &u);
            assert_eq!(qn, rk.map(&p, &q, &u));
            let (af, bf) = fd(&rk, &p, &q, &u, 1e-6);
            let rel_a = (a - af).norm() / a.norm();
            let rel_b = (b - bf).norm() / b.norm();
            assert!(
                rel_a < 1e-6 && rel_b < 1e-6,
                "q={q:?} u={u:?}: rel err A {rel_a:e}, B {rel_b:e}"
            );
            // Entry-wise, relative to the column scale.
            for j in 0..NQ {
                let s = af.column(j).norm().max(1.0);
                assert!((a.column(j) - af.column(j)).norm() / s < 1e-6);
            }
        }
    }

    #[test]
    fn map_matches_the_simulator_step() {
        let p = VehicleParams::default();
        let rk = Rk4 {
            dt: 0.1,
            substeps: 10,
        };
        let q = [2.5, 0.1, 0.5, 0.3, -0.2, 0.4];
        let u = [0.7, 0.12];
        let ours = rk.map(&p, &q, &u);
        let sim = p.step(&q, &u, 0.1, 10);
        for i in 0..NQ {
            assert!((ours[i] - sim[i]).abs() < 1e-12, "{ours:?} vs {sim:?}");
        }
    }
}
