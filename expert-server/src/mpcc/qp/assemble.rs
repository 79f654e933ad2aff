//! The QP's data at an iterate ([`QpLayout::assemble`]), concept by concept: each stage's cost (contouring and lag,
//! the weights, the input rates), the dynamics' transitions as equalities, and each stage's inequalities (boxes,
//! rate limits, the track slab). The parts emit their entries in the pattern's order (the module doc of
//! [`super`]), stage by stage.

use super::{a_structural, Assembled, QpInput, QpLayout, EQ_PER_STAGE, NZ, OMEGA, S, VS, X, Y};
use crate::rk4::NQ;

/// Entries (row, column, value) of a sparse matrix, in the pattern's order.
type Entries = Vec<(usize, usize, f64)>;

/// What a stage's cost terms add to: the stage's diagonal of P (emitted after its terms), P's other entries, q.
struct Cost<'a> {
    diag: [f64; NZ],
    p: &'a mut Entries,
    q: &'a mut [f64],
}

impl QpLayout {
    /// The QP's data at `inp`: the cost (P, q), the equalities (the dynamics' transitions) and the inequalities
    /// (boxes, rates, track slabs), stage by stage in the pattern's order.
    pub(super) fn assemble(&self, inp: &QpInput, out: &mut Assembled) {
        let Assembled { p, a, q, b } = out;
        p.clear();
        a.clear();
        q.clear();
        q.resize(self.n(), 0.0);
        b.clear();
        b.resize(self.m(), 0.0);
        for k in 1..=self.horizon {
            self.stage_cost(inp, k, p, q);
        }
        for k in 0..self.horizon {
            self.transition(inp, k, a, b);
        }
        let mut row = self.m_eq();
        for k in 1..=self.horizon {
            row = self.box_rows(k, row, a, b);
            row = self.rate_limit_rows(inp, k, row, a, b);
            row = self.slab_rows(inp, k, row, a, b);
        }
        debug_assert_eq!(row, self.m());
    }

    /// Stage k's cost: contouring and lag, the yaw rate, the inputs, the progress reward, the input rates and the
    /// slack.
    fn stage_cost(&self, inp: &QpInput, k: usize, p: &mut Entries, q: &mut [f64]) {
        let (c, cfg) = (&self.scale, &self.cfg);
        let sv = |j| self.stage_var(k, j);
        let mut cost = Cost {
            diag: [cfg.hessian_reg; NZ],
            p,
            q,
        };
        self.contouring_cost(inp, k, &mut cost);
        let w_omega = if k == self.horizon {
            cfg.q_yaw_rate_terminal
        } else {
            cfg.q_yaw_rate
        };
        cost.diag[OMEGA] += 2.0 * w_omega * c[OMEGA] * c[OMEGA];
        for j in 0..3 {
            cost.diag[7 + j] += 2.0 * cfg.r_input[j] * c[7 + j] * c[7 + j];
        }
        cost.q[sv(VS)] -= cfg.progress_reward * c[VS];
        self.rate_cost(inp, k, &mut cost);
        for (j, &d) in cost.diag.iter().enumerate() {
            cost.p.push((sv(j), sv(j), d));
        }
        cost.p
            .push((self.slack_var(k), self.slack_var(k), cfg.slack_weight));
    }

    /// Gauss–Newton contouring/lag of stage k: q_c(e_c + g_c·Δ)² + q_l(e_l + g_l·Δ)² over (X, Y, s).
    fn contouring_cost(&self, inp: &QpInput, k: usize, cost: &mut Cost) {
        let (c, cfg) = (&self.scale, &self.cfg);
        let (z, e) = (&inp.iterate[k], &inp.errors[k - 1]);
        let sv = |j| self.stage_var(k, j);
        let idx = [X, Y, S];
        let r_c = e.e_c - (0..3).map(|i| e.grad_c[i] * z[idx[i]]).sum::<f64>();
        let r_l = e.e_l - (0..3).map(|i| e.grad_l[i] * z[idx[i]]).sum::<f64>();
        for i in 0..3 {
            for j in i..3 {
                let h = 2.0
                    * (cfg.q_contour * e.grad_c[i] * e.grad_c[j]
                        + cfg.q_lag * e.grad_l[i] * e.grad_l[j])
                    * c[idx[i]]
                    * c[idx[j]];
                if i == j {
                    cost.diag[idx[i]] += h;
                } else {
                    cost.p.push((sv(idx[i]), sv(idx[j]), h));
                }
            }
            cost.q[sv(idx[i])] += 2.0
                * (cfg.q_contour * r_c * e.grad_c[i] + cfg.q_lag * r_l * e.grad_l[i])
                * c[idx[i]];
        }
    }

    /// Stage k's rate cost c_r·r² with r = (w̃_{k−1} − w̃_{k−2})/dt (w̃_{−1} = w_prev is data).
    fn rate_cost(&self, inp: &QpInput, k: usize, cost: &mut Cost) {
        let (dt, c, cfg) = (self.dt, &self.scale, &self.cfg);
        for j in 0..3 {
            let h = 2.0 * cfg.r_rate[j] / (dt * dt);
            let v = self.stage_var(k, 7 + j);
            cost.diag[7 + j] += h;
            if k == 1 {
                cost.q[v] -= h * inp.w_prev[j] / c[7 + j];
            } else {
                cost.p.push((self.stage_var(k - 1, 7 + j), v, -h));
                // The previous stage's diagonal gets its share when that stage is emitted (below).
            }
            if k < self.horizon {
                cost.diag[7 + j] += 2.0 * cfg.r_rate[j] / (dt * dt);
            }
        }
    }

    /// The equalities of the transition k → k+1: the linearised dynamics and the exact integration of s.
    fn transition(&self, inp: &QpInput, k: usize, a: &mut Entries, b: &mut [f64]) {
        let (dt, c) = (self.dt, &self.scale);
        let x0 = &inp.iterate[0];
        let row0 = EQ_PER_STAGE * k;
        let lin = &inp.lin[k];
        let q_bar = &inp.iterate[k];
        let w_bar = [q_bar[7], q_bar[8]];
        // g_k = f − A q̄ − B w̄, and for k = 0 the fixed x_0 moves to the right-hand side: A x_0 + g_0.
        for i in 0..NQ {
            let row = row0 + i;
            let ri = 1.0 / c[i];
            a.push((row, self.stage_var(k + 1, i), 1.0));
            let mut g = lin.f[i] - lin.b[(i, 0)] * w_bar[0] - lin.b[(i, 1)] * w_bar[1];
            for j in 0..NQ {
                if a_structural(i, j) {
                    g -= lin.a[(i, j)] * q_bar[j];
                    if k == 0 {
                        g += lin.a[(i, j)] * x0[j];
                    } else {
                        a.push((row, self.stage_var(k, j), -lin.a[(i, j)] * c[j] * ri));
                    }
                }
            }
            for j in 0..2 {
                a.push((
                    row,
                    self.stage_var(k + 1, 7 + j),
                    -lin.b[(i, j)] * c[7 + j] * ri,
                ));
            }
            b[row] = g * ri;
        }
        // s_{k+1} = s_k + dt·v_s,k (exact).
        let row = row0 + S;
        a.push((row, self.stage_var(k + 1, S), 1.0));
        a.push((row, self.stage_var(k + 1, VS), -dt * c[VS] / c[S]));
        if k == 0 {
            b[row] = x0[S] / c[S];
        } else {
            a.push((row, self.stage_var(k, S), -1.0));
        }
    }

    /// Stage k's box rows (Az ≤ b) from `row` on; the next free row.
    fn box_rows(&self, k: usize, mut row: usize, a: &mut Entries, b: &mut [f64]) -> usize {
        let c = &self.scale;
        for &j in &self.boxed {
            a.push((row, self.stage_var(k, j), 1.0));
            b[row] = self.ub[j] / c[j];
            a.push((row + 1, self.stage_var(k, j), -1.0));
            b[row + 1] = -self.lb[j] / c[j];
            row += 2;
        }
        row
    }

    /// Stage k's rate rows from `row` on, |w̃_{k−1} − w̃_{k−2}| ≤ dt·r_max (scaled rates, expert.md §6); the next
    /// free row.
    fn rate_limit_rows(
        &self,
        inp: &QpInput,
        k: usize,
        mut row: usize,
        a: &mut Entries,
        b: &mut [f64],
    ) -> usize {
        let (dt, c, cfg) = (self.dt, &self.scale, &self.cfg);
        for j in (0..3).filter(|&j| k == 1 || self.rate_rows[j]) {
            let (v, rb) = (self.stage_var(k, 7 + j), dt * cfg.rate_bound[j]);
            a.push((row, v, 1.0));
            a.push((row + 1, v, -1.0));
            if k == 1 {
                let w = inp.w_prev[j] / c[7 + j];
                b[row] = rb + w;
                b[row + 1] = rb - w;
            } else {
                let u = self.stage_var(k - 1, 7 + j);
                a.push((row, u, -1.0));
                a.push((row + 1, u, 1.0));
                b[row] = rb;
                b[row + 1] = rb;
            }
            row += 2;
        }
        row
    }

    /// Stage k's track slab from `row` on, lo − σ ≤ c·(X, Y) ≤ hi + σ; the next free row.
    fn slab_rows(
        &self,
        inp: &QpInput,
        k: usize,
        row: usize,
        a: &mut Entries,
        b: &mut [f64],
    ) -> usize {
        let c = &self.scale;
        let sl = &inp.slabs[k - 1];
        let (vx, vy, vs) = (
            self.stage_var(k, X),
            self.stage_var(k, Y),
            self.slack_var(k),
        );
        a.push((row, vx, sl.normal[0] * c[X]));
        a.push((row, vy, sl.normal[1] * c[Y]));
        a.push((row, vs, -1.0));
        b[row] = sl.hi;
        a.push((row + 1, vx, -sl.normal[0] * c[X]));
        a.push((row + 1, vy, -sl.normal[1] * c[Y]));
        a.push((row + 1, vs, -1.0));
        b[row + 1] = -sl.lo;
        row + 2
    }
}
