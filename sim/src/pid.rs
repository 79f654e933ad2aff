//! The PID lane follower expert (`PIDWrapper` + `PIDLaneFollower`; expert.md §12, simulator.md §5).
//!
//! Two independent saturated PID loops at dt = 0.1 s on the ground-truth Frenet state:
//! speed  e_v = v_long − v_ref,            u_a     = −1.5 e_v,  clip ±2;
//! steer  e_δ = 5.0 x_tran + 1.0 e_psi,    u_steer = −0.5 e_δ,  clip ±0.436.
//! The general form (integral, derivative, per-call rate limit) is kept so the numbers stay in one place,
//! even though with the reference gains it reduces to the closed form above.

use crate::vehicle::Input;

/// One saturated PID loop in the reference's form:
/// e = x − x_ref; ei = clamp(ei + e·dt, ±ei_max); de = (e − e_prev)/dt;
/// u = −(Kp e + Ki ei + Kd de) + u_ref; then |u − u_prev| ≤ du_max (per call, not scaled by dt); then clip.
#[derive(Clone, Debug, PartialEq)]
pub struct Pid {
    pub kp: f64,
    pub ki: f64,
    pub kd: f64,
    pub x_ref: f64,
    pub u_ref: f64,
    pub u_min: f64,
    pub u_max: f64,
    pub du_max: f64,
    pub ei_max: f64,
    pub dt: f64,
    e_prev: f64,
    ei: f64,
    u_prev: f64,
}

impl Pid {
    pub fn new(kp: f64, x_ref: f64, u_max: f64, du_max: f64) -> Self {
        Pid {
            kp,
            ki: 0.0,
            kd: 0.0,
            x_ref,
            u_ref: 0.0,
            u_min: -u_max,
            u_max,
            du_max,
            ei_max: 100.0,
            dt: crate::env::DT,
            e_prev: 0.0,
            ei: 0.0,
            u_prev: 0.0,
        }
    }

    /// Forget the error history and the previous output (the reference rebuilds the PIDs on reset).
    pub fn reset(&mut self) {
        self.e_prev = 0.0;
        self.ei = 0.0;
        self.u_prev = 0.0;
    }

    pub fn update(&mut self, x: f64) -> f64 {
        let e = x - self.x_ref;
        self.ei = (self.ei + e * self.dt).clamp(-self.ei_max, self.ei_max);
        let de = (e - self.e_prev) / self.dt;
        let raw = -(self.kp * e + self.ki * self.ei + self.kd * de) + self.u_ref;
        let limited = self.u_prev + (raw - self.u_prev).clamp(-self.du_max, self.du_max);
        let u = limited.clamp(self.u_min, self.u_max);
        self.e_prev = e;
        self.u_prev = u;
        u
    }
}

/// The PID lane follower: [`Default`] is the reference expert (target speed 1.0 m/s).
#[derive(Clone, Debug, PartialEq)]
pub struct PidLaneFollower {
    /// Speed loop on v_long (Kp 1.5, clip ±2 m/s², rate ±20 per call).
    pub speed: Pid,
    /// Steering loop on `steer_weights · (x_tran, e_psi)` (Kp 0.5, clip ±0.436 rad, rate ±4.5 per call).
    pub steer: Pid,
    /// Weights of x_tran and e_psi in the steering error: (5.0, 1.0).
    pub steer_weights: (f64, f64),
}

impl PidLaneFollower {
    pub fn new(target_speed: f64) -> Self {
        PidLaneFollower {
            speed: Pid::new(1.5, target_speed, 2.0, 20.0),
            steer: Pid::new(0.5, 0.0, 0.436, 4.5),
            steer_weights: (5.0, 1.0),
        }
    }

    pub fn reset(&mut self) {
        self.speed.reset();
        self.steer.reset();
    }

    /// The action [a, δ] from the ground-truth longitudinal speed and Frenet offsets.
    pub fn action(&mut self, v_long: f64, x_tran: f64, e_psi: f64) -> Input {
        let a = self.speed.update(v_long);
        let steer_err = self.steer_weights.0 * x_tran + self.steer_weights.1 * e_psi;
        let delta = self.steer.update(steer_err);
        [a, delta]
    }
}

impl Default for PidLaneFollower {
    fn default() -> Self {
        PidLaneFollower::new(1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form() {
        let mut pid = PidLaneFollower::default();
        for &(v, e, p) in &[
            (0.5, 0.0, 0.0),
            (1.7, 0.1, -0.2),
            (3.0, -0.5, 0.4),
            (0.0, 0.3, 0.3),
        ] {
            let u = pid.action(v, e, p);
            let a = (1.5 * (1.0 - v)).clamp(-2.0, 2.0);
            let d = (-2.5 * e - 0.5 * p).clamp(-0.436, 0.436);
            assert!(
                (u[0] - a).abs() < 1e-12 && (u[1] - d).abs() < 1e-12,
                "{u:?} vs {a} {d}"
            );
        }
    }
}
