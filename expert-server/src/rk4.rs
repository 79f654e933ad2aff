//! The MPC's discrete prediction model: RK4 with M sub-steps, input held, and its exact Jacobians (expert.md §2).
//!
//! The reference differentiates the RK4 map with CasADi AD through all sub-steps. Here the same derivatives come
//! from forward sensitivities: each RK4 stage `k_i = f(q_i, u)` is differentiated with the ODE's continuous
//! Jacobians, `dk_i = ∂f/∂q(q_i,u)·dq_i + ∂f/∂u(q_i,u)·du`, and the sensitivities are accumulated like the state.
//! The result equals AD of the discrete map up to round-off.

use cabc_sim::vehicle::{HeldInput, VehicleParams};
use nalgebra::{SMatrix, SVector};

/// State dimension of the vehicle model (v_x, v_y, ω, X, Y, ψ).
pub const NQ: usize = 6;
/// Input dimension (a, δ).
pub const NU: usize = 2;

/// Jacobian of the discrete map with respect to the state.
pub type JacQ = SMatrix<f64, NQ, NQ>;
/// Jacobian of the discrete map with respect to the input.
pub type JacU = SMatrix<f64, NQ, NU>;

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

/// Sensitivities of a sub-step state, one row per state component, with respect to the initial
/// (v_x, v_y, ω, ψ, a, δ). Those with respect to X and Y are the unit vectors for the whole interval (f depends on
/// neither), so they are not carried.
type Sens = [[f64; NS]; NQ];
/// Columns of [`Sens`].
const NS: usize = 6;

fn sens_axpy(s: &Sens, a: f64, d: &Sens) -> Sens {
    std::array::from_fn(|i| std::array::from_fn(|j| s[i][j] + a * d[i][j]))
}

/// dS = J_q·S + [0 | J_u] for one RK4 stage, using the bicycle's structure (∂f/∂X = ∂f/∂Y = 0; the velocity rows
/// do not depend on ψ; ψ̇ = ω): 16 of J_q's 36 entries can be nonzero.
fn stage_sens(jq: &JacQ, ju: &JacU, s: &Sens) -> Sens {
    let mut d = [[0.0; NS]; NQ];
    for i in 0..3 {
        let (j0, j1, j2) = (jq[(i, 0)], jq[(i, 1)], jq[(i, 2)]);
        for c in 0..NS {
            d[i][c] = j0 * s[0][c] + j1 * s[1][c] + j2 * s[2][c];
        }
    }
    for i in 3..5 {
        let (j0, j1, j5) = (jq[(i, 0)], jq[(i, 1)], jq[(i, 5)]);
        for c in 0..NS {
            d[i][c] = j0 * s[0][c] + j1 * s[1][c] + j5 * s[5][c];
        }
    }
    d[5] = s[2];
    for i in 0..NQ {
        d[i][4] += ju[(i, 0)];
        d[i][5] += ju[(i, 1)];
    }
    d
}

impl Rk4 {
    /// `f_d(q, u)`.
    pub fn map(&self, model: &VehicleParams, q: &[f64; NQ], u: &[f64; NU]) -> [f64; NQ] {
        model.step(q, u, self.dt, self.substeps)
    }

    /// `f_d(q, u)` with its exact Jacobians `A_d = ∂f_d/∂q`, `B_d = ∂f_d/∂u`.
    pub fn map_with_jacobians(
        &self,
        model: &VehicleParams,
        q: &[f64; NQ],
        u: &[f64; NU],
    ) -> ([f64; NQ], JacQ, JacU) {
        let h = self.dt / self.substeps as f64;
        let u = HeldInput::new(u);
        let mut q = *q;
        // ∂q/∂(v_x, v_y, ω, ψ, a, δ) at the start: the unit vectors of v_x, v_y, ω, ψ; zero for the inputs.
        let mut s: Sens = [[0.0; NS]; NQ];
        for (i, c) in [(0, 0), (1, 1), (2, 2), (5, 3)] {
            s[i][c] = 1.0;
        }
        // (k, dk) of the stage evaluated at `qs` whose sensitivities are `ss`.
        let stage = |qs: &[f64; NQ], ss: &Sens| {
            let (k, jq, ju) = model.derivatives_and_jacobians_held(qs, &u);
            (k, stage_sens(&jq, &ju, ss))
        };
        for _ in 0..self.substeps {
            let (k1, d1) = stage(&q, &s);
            let (k2, d2) = stage(&axpy(&q, h / 2.0, &k1), &sens_axpy(&s, h / 2.0, &d1));
            let (k3, d3) = stage(&axpy(&q, h / 2.0, &k2), &sens_axpy(&s, h / 2.0, &d2));
            let (k4, d4) = stage(&axpy(&q, h, &k3), &sens_axpy(&s, h, &d3));
            q = std::array::from_fn(|i| {
                q[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
            for i in 0..NQ {
                for c in 0..NS {
                    s[i][c] += h / 6.0 * (d1[i][c] + 2.0 * d2[i][c] + 2.0 * d3[i][c] + d4[i][c]);
                }
            }
        }
        let mut a = JacQ::zeros();
        let mut b = JacU::zeros();
        for i in 0..NQ {
            for (j, c) in [(0, 0), (1, 1), (2, 2), (5, 3)] {
                a[(i, j)] = s[i][c];
            }
            b[(i, 0)] = s[i][4];
            b[(i, 1)] = s[i][5];
        }
        a[(3, 3)] = 1.0;
        a[(4, 4)] = 1.0;
        (q, a, b)
    }
}

/// `[f64; NQ]` as a column vector.
pub fn col(q: &[f64; NQ]) -> SVector<f64, NQ> {
    SVector::from_column_slice(q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_sim::env::{DT, SUBSTEPS};
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
            dt: DT,
            substeps: SUBSTEPS,
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

    /// `stage_sens` assumes the bicycle's Jacobian structure; a model change that breaks it must fail here.
    #[test]
    fn vehicle_jacobian_has_the_structure_the_sensitivities_assume() {
        let p = VehicleParams::default();
        let may_be_nonzero = |i: usize, j: usize| match i {
            0..=2 => j <= 2,
            3 | 4 => matches!(j, 0 | 1 | 5),
            _ => j == 2,
        };
        for (q, u) in [
            ([3.1, 0.35, 2.4, -1.0, 3.0, 2.0], [-1.2, 0.3]),
            ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [1.0, -0.2]),
            ([1.2, -0.4, -3.0, 0.5, 0.5, -1.0], [1.8, -0.42]),
        ] {
            let (jq, _) = p.jacobians(&q, &u);
            for i in 0..NQ {
                for j in 0..NQ {
                    assert!(
                        may_be_nonzero(i, j) || jq[(i, j)] == 0.0,
                        "J_q[{i},{j}] at {q:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn map_matches_the_simulator_step() {
        let p = VehicleParams::default();
        let rk = Rk4 {
            dt: DT,
            substeps: SUBSTEPS,
        };
        let q = [2.5, 0.1, 0.5, 0.3, -0.2, 0.4];
        let u = [0.7, 0.12];
        let ours = rk.map(&p, &q, &u);
        let sim = p.step(&q, &u, DT, SUBSTEPS);
        for i in 0..NQ {
            assert!((ours[i] - sim[i]).abs() < 1e-12, "{ours:?} vs {sim:?}");
        }
    }
}
