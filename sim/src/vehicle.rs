//! The ground-truth vehicle: the reference's `CasadiDynamicBicycle` (simulator.md §1).
//!
//! Dynamic bicycle in the global frame with body-frame velocities and Pacejka lateral tyres, all-wheel
//! drive, no drag, no delay, no noise. State q = [v_x, v_y, ω, X, Y, ψ] (m/s, m/s, rad/s, m, m, rad; v_x
//! forward, v_y left, ψ CCW and never wrapped); input u = [a, δ] (m/s², rad; δ > 0 steers left).
//!
//! Integrator: the reference sub-steps with scipy's adaptive RK45 (rtol 1e-3). We use classic RK4; with one
//! h = 0.01 s step per sub-step it agrees with RK45 to ≤ 3e-4 over 250 closed-loop steps (simulator.md §7,
//! checked in `tests/vehicle.rs`).

use nalgebra::SMatrix;

/// q = [v_x, v_y, ω, X, Y, ψ].
pub type State = [f64; 6];
/// u = [a, δ].
pub type Input = [f64; 2];

/// The env's action box (simulator.md §1.5): a ∈ [-2, 2] m/s², δ ∈ [-0.45, 0.45] rad.
pub const ACTION_LOW: Input = [-2.0, -0.45];
pub const ACTION_HIGH: Input = [2.0, 0.45];

/// Clip an action into the env's box. NaN components become 0 (the box's centre) so a bad policy
/// output can never poison the state.
pub fn clip_action(u: &Input) -> Input {
    let mut out = [0.0; 2];
    for i in 0..2 {
        out[i] = if u[i].is_nan() {
            0.0
        } else {
            u[i].clamp(ACTION_LOW[i], ACTION_HIGH[i])
        };
    }
    out
}

/// Physical parameters (simulator.md §1.2). Drag, damping and rolling resistance are zero in the
/// reference, so they are not modelled.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VehicleParams {
    /// Mass (kg).
    pub m: f64,
    /// Yaw inertia (kg m²).
    pub iz: f64,
    /// Gravity (m/s²).
    pub g: f64,
    /// CoM to front axle (m).
    pub lf: f64,
    /// CoM to rear axle (m).
    pub lr: f64,
    /// Tyre friction coefficient.
    pub mu: f64,
    /// Pacejka B, front and rear.
    pub bf: f64,
    pub br: f64,
    /// Pacejka C, front and rear.
    pub cf: f64,
    pub cr: f64,
}

impl Default for VehicleParams {
    fn default() -> Self {
        VehicleParams {
            m: 2.2187,
            iz: 0.02723,
            g: 9.81,
            lf: 0.13,
            lr: 0.13,
            mu: 0.9,
            bf: 5.0,
            br: 5.0,
            cf: 2.28,
            cr: 2.28,
        }
    }
}

/// An input held constant over an integration interval (zero-order hold), with the steering angle's sine and
/// cosine computed once for all the RK4 stages that share it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldInput {
    /// Longitudinal acceleration command a (m/s²).
    pub a: f64,
    /// Steering angle δ (rad).
    pub delta: f64,
    sin_delta: f64,
    cos_delta: f64,
}

impl HeldInput {
    /// Hold `u` = [a, δ].
    pub fn new(u: &Input) -> Self {
        let (sin_delta, cos_delta) = u[1].sin_cos();
        Self {
            a: u[0],
            delta: u[1],
            sin_delta,
            cos_delta,
        }
    }
}

/// Tyre quantities shared by `derivatives` and `jacobians`.
struct Tyres {
    /// Front slip angle and its gradient w.r.t. (v_x, v_y, ω, δ).
    alpha_f: f64,
    dalpha_f: [f64; 4],
    /// Rear slip angle and its gradient w.r.t. (v_x, v_y, ω).
    alpha_r: f64,
    dalpha_r: [f64; 3],
}

/// d atan2(n, d) = (d·dn − n·dd)/(n² + d²); 0 at the standstill singularity n = d = 0.
#[inline]
fn datan2(n: f64, d: f64, dn: f64, dd: f64) -> f64 {
    let q = n * n + d * d;
    if q == 0.0 {
        0.0
    } else {
        (d * dn - n * dd) / q
    }
}

impl VehicleParams {
    /// Front peak lateral force D_f = μ m g l_r/(l_f + l_r) (N); 9.79445115 by default.
    pub fn df(&self) -> f64 {
        self.mu * self.m * self.g * self.lr / (self.lf + self.lr)
    }

    /// Rear peak lateral force D_r = μ m g l_f/(l_f + l_r) (N).
    pub fn dr(&self) -> f64 {
        self.mu * self.m * self.g * self.lf / (self.lf + self.lr)
    }

    fn tyres(&self, q: &State, u: &HeldInput, with_grad: bool) -> Tyres {
        let (vx, vy, w) = (q[0], q[1], q[2]);
        let (sd, cd) = (u.sin_delta, u.cos_delta);
        let vyf = vy + self.lf * w;
        let nf = vyf * cd - vx * sd;
        let df = vx * cd + vyf * sd;
        let nr = vy - self.lr * w;
        let dr = vx;
        // Rust's atan2(0, 0) is 0, matching the reference's standstill convention.
        let alpha_f = -nf.atan2(df);
        let alpha_r = -nr.atan2(dr);
        let (mut dalpha_f, mut dalpha_r) = ([0.0; 4], [0.0; 3]);
        if with_grad {
            // (∂n_f, ∂d_f) w.r.t. v_x, v_y, ω, δ.
            let dn = [-sd, cd, self.lf * cd, -df];
            let dd = [cd, sd, self.lf * sd, nf];
            for k in 0..4 {
                dalpha_f[k] = -datan2(nf, df, dn[k], dd[k]);
            }
            let dn = [0.0, 1.0, -self.lr];
            let dd = [1.0, 0.0, 0.0];
            for k in 0..3 {
                dalpha_r[k] = -datan2(nr, dr, dn[k], dd[k]);
            }
        }
        Tyres {
            alpha_f,
            dalpha_f,
            alpha_r,
            dalpha_r,
        }
    }

    /// Pacejka lateral force D sin(C atan(B α)) and its derivative w.r.t. α.
    #[inline]
    fn pacejka(d: f64, c: f64, b: f64, alpha: f64) -> (f64, f64) {
        let ba = b * alpha;
        let (sin, cos) = (c * ba.atan()).sin_cos();
        (d * sin, d * cos * c * b / (1.0 + ba * ba))
    }

    /// Pacejka lateral force alone.
    #[inline]
    fn pacejka_force(d: f64, c: f64, b: f64, alpha: f64) -> f64 {
        d * (c * (b * alpha).atan()).sin()
    }

    /// Continuous dynamics q̇ = f(q, u), simulator.md §1.3 exactly.
    pub fn derivatives(&self, q: &State, u: &Input) -> State {
        self.derivatives_held(q, &HeldInput::new(u))
    }

    /// [`Self::derivatives`] for an input whose trigonometry is already computed (RK4 stages share it).
    pub fn derivatives_held(&self, q: &State, u: &HeldInput) -> State {
        let t = self.tyres(q, u, false);
        let fyf = Self::pacejka_force(self.df(), self.cf, self.bf, t.alpha_f);
        let fyr = Self::pacejka_force(self.dr(), self.cr, self.br, t.alpha_r);
        self.rates(q, u, q[5].sin_cos(), fyf, fyr)
    }

    /// q̇ from the state, the held input, (sin ψ, cos ψ) and the lateral tyre forces (simulator.md §1.3).
    #[inline]
    fn rates(&self, q: &State, u: &HeldInput, (sp, cp): (f64, f64), fyf: f64, fyr: f64) -> State {
        let (vx, vy, w) = (q[0], q[1], q[2]);
        let (a, sd, cd) = (u.a, u.sin_delta, u.cos_delta);
        let ax = a / 2.0 + (a / 2.0) * cd - fyf * sd / self.m;
        let ay = (a / 2.0) * sd + (fyf * cd + fyr) / self.m;
        [
            ax + w * vy,
            ay - w * vx,
            (self.lf * fyf * cd - self.lr * fyr) / self.iz,
            vx * cp - vy * sp,
            vx * sp + vy * cp,
            w,
        ]
    }

    /// Analytic Jacobians (∂f/∂q, ∂f/∂u) of [`Self::derivatives`]. At standstill the slip angles' 0/0
    /// derivative terms are taken as 0.
    pub fn jacobians(&self, q: &State, u: &Input) -> (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>) {
        let (_, jq, ju) = self.derivatives_and_jacobians(q, u);
        (jq, ju)
    }

    /// [`Self::derivatives`] and [`Self::jacobians`] together: they share the tyre forces, the costly part (the
    /// MPC's linearisation evaluates both at every RK4 stage).
    pub fn derivatives_and_jacobians(
        &self,
        q: &State,
        u: &Input,
    ) -> (State, SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>) {
        self.derivatives_and_jacobians_held(q, &HeldInput::new(u))
    }

    /// [`Self::derivatives_and_jacobians`] for an input whose trigonometry is already computed.
    ///
    /// Structure (relied on by the MPC's linearisation and checked by the tests): f depends on neither X nor Y,
    /// and (v̇_x, v̇_y, ω̇) do not depend on ψ.
    pub fn derivatives_and_jacobians_held(
        &self,
        q: &State,
        u: &HeldInput,
    ) -> (State, SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>) {
        let (vx, vy, w, psi) = (q[0], q[1], q[2], q[5]);
        let t = self.tyres(q, u, true);
        let (fyf, dfyf) = Self::pacejka(self.df(), self.cf, self.bf, t.alpha_f);
        let (fyr, dfyr) = Self::pacejka(self.dr(), self.cr, self.br, t.alpha_r);
        let (a, sd, cd) = (u.a, u.sin_delta, u.cos_delta);
        let (sp, cp) = psi.sin_cos();
        let m = self.m;
        let f = self.rates(q, u, (sp, cp), fyf, fyr);
        // ∂F_yf/∂(v_x, v_y, ω, δ) and ∂F_yr/∂(v_x, v_y, ω).
        let ff: [f64; 4] = std::array::from_fn(|k| dfyf * t.dalpha_f[k]);
        let fr: [f64; 3] = std::array::from_fn(|k| dfyr * t.dalpha_r[k]);

        let mut jq = SMatrix::<f64, 6, 6>::zeros();
        let mut ju = SMatrix::<f64, 6, 2>::zeros();
        for k in 0..3 {
            jq[(0, k)] = -sd * ff[k] / m;
            jq[(1, k)] = (cd * ff[k] + fr[k]) / m;
            jq[(2, k)] = (self.lf * cd * ff[k] - self.lr * fr[k]) / self.iz;
        }
        // The Coriolis terms ω v_y and −ω v_x.
        jq[(0, 1)] += w;
        jq[(0, 2)] += vy;
        jq[(1, 0)] -= w;
        jq[(1, 2)] -= vx;
        jq[(3, 0)] = cp;
        jq[(3, 1)] = -sp;
        jq[(3, 5)] = -vx * sp - vy * cp;
        jq[(4, 0)] = sp;
        jq[(4, 1)] = cp;
        jq[(4, 5)] = vx * cp - vy * sp;
        jq[(5, 2)] = 1.0;

        let ffd = ff[3];
        ju[(0, 0)] = 0.5 + 0.5 * cd;
        ju[(0, 1)] = -(a / 2.0) * sd - (ffd * sd + fyf * cd) / m;
        ju[(1, 0)] = 0.5 * sd;
        ju[(1, 1)] = (a / 2.0) * cd + (ffd * cd - fyf * sd) / m;
        ju[(2, 1)] = self.lf * (ffd * cd - fyf * sd) / self.iz;
        (f, jq, ju)
    }

    /// One classic fourth-order Runge–Kutta step of length `h` (s) with u held constant.
    pub fn rk4(&self, q: &State, u: &Input, h: f64) -> State {
        self.rk4_held(q, &HeldInput::new(u), h)
    }

    /// [`Self::rk4`] for a held input.
    pub fn rk4_held(&self, q: &State, u: &HeldInput, h: f64) -> State {
        let add =
            |a: &State, k: &State, c: f64| -> State { std::array::from_fn(|i| a[i] + c * k[i]) };
        let k1 = self.derivatives_held(q, u);
        let k2 = self.derivatives_held(&add(q, &k1, h / 2.0), u);
        let k3 = self.derivatives_held(&add(q, &k2, h / 2.0), u);
        let k4 = self.derivatives_held(&add(q, &k3, h), u);
        std::array::from_fn(|i| q[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
    }

    /// Zero-order hold over `dt`: `substeps` RK4 steps of dt/substeps (at least one).
    pub fn step(&self, q: &State, u: &Input, dt: f64, substeps: usize) -> State {
        let n = substeps.max(1);
        let h = dt / n as f64;
        let held = HeldInput::new(u);
        let mut x = *q;
        for _ in 0..n {
            x = self.rk4_held(&x, &held, h);
        }
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_forces() {
        let p = VehicleParams::default();
        assert!((p.df() - 9.79445115).abs() < 1e-8);
        assert!((p.dr() - 9.79445115).abs() < 1e-8);
    }

    #[test]
    fn standstill_is_finite() {
        let p = VehicleParams::default();
        let q = [0.0; 6];
        let u = [1.0, 0.3];
        assert!(p.derivatives(&q, &u).iter().all(|v| v.is_finite()));
        let (a, b) = p.jacobians(&q, &u);
        assert!(a.iter().chain(b.iter()).all(|v| v.is_finite()));
    }

    #[test]
    fn clip_handles_nan_and_bounds() {
        assert_eq!(clip_action(&[5.0, -1.0]), [2.0, -0.45]);
        assert_eq!(clip_action(&[f64::NAN, 0.1]), [0.0, 0.1]);
    }
}
