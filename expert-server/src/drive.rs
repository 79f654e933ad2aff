//! Closed-loop drives of the MPCC in the nominal plant, and the step-time benchmark.
//!
//! The plant is the simulator's vehicle: 10 RK4 sub-steps of 0.01 s per 0.1 s step, the Frenet projection after
//! every sub-step, and the env's truncation rules (simulator.md §1.4, §3.5–3.6): left the 0.85 m band,
//! |x_tran| > 0.55, v_long < 0.25, |e_ψ| > π/2. A lap is the start-line crossing with decreasing s; its time is
//! (steps since the previous lap or the spawn) × dt (the env's logged `lap_time` adds one step more).

use std::time::Duration;

use cabc_sim::track::{Frenet, Track};
use cabc_sim::vehicle::{clip_action, State, VehicleParams};
use serde::{Deserialize, Serialize};

use crate::mpcc::{Mpcc, MpccError, QpStatus};

/// Evaluation spawn (simulator.md §3.2): s = 0.1, x_tran = 0, e_ψ = 0, v_long = 0.5, v_tran = ω = 0.
pub fn fixed_spawn(track: &Track) -> State {
    let p = track.local_to_global(0.1, 0.0, 0.0);
    [0.5, 0.0, 0.0, p.x, p.y, p.psi]
}

/// How long to drive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveOptions {
    /// Stop after this many completed laps.
    pub laps: usize,
    /// Stop after this many steps regardless.
    pub max_steps: usize,
    /// Stop at the first failed MPCC step (otherwise its fallback action is applied and the drive goes on).
    pub stop_on_failure: bool,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self {
            laps: 3,
            max_steps: 2000,
            stop_on_failure: true,
        }
    }
}

/// One closed-loop step: the state the controller saw and what it did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DriveStep {
    /// Time at the start of the step [s].
    pub t: f64,
    /// Measured state (v_x, v_y, ω, X, Y, ψ unwrapped).
    pub state: State,
    /// Its Frenet coordinates.
    pub frenet: Frenet,
    /// Applied action (a, δ).
    pub action: [f64; 2],
    /// MPCC success.
    pub success: bool,
    /// MPCC status.
    pub status: QpStatus,
    /// Clarabel iterations summed over the step's QPs.
    pub qp_iterations: u32,
    /// Clarabel solve time [s].
    pub solve_time: f64,
    /// Whole MPCC step wall time [s].
    pub step_time: f64,
}

/// Why a drive ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum DriveEnd {
    /// The requested laps were completed.
    Laps,
    /// The env would truncate (the reason).
    Truncated(String),
    /// An MPCC step failed and `stop_on_failure` was set.
    Failure,
    /// `max_steps` reached.
    MaxSteps,
    /// The controller rejected the state.
    Error(String),
}

/// A drive's record.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DriveReport {
    /// Per-step records.
    pub steps: Vec<DriveStep>,
    /// Completed lap times [s] (the first lap starts at the spawn, s = 0.1).
    pub lap_times: Vec<f64>,
    /// Failed MPCC steps.
    pub failures: usize,
    /// Why it ended.
    pub end: DriveEnd,
}

/// The env's truncation test on a Frenet state and the forward speed.
fn truncation(f: &Frenet, v_long: f64, half_width: f64) -> Option<String> {
    if f.x_tran.abs() > half_width {
        Some(format!("|x_tran| = {:.3} > {half_width}", f.x_tran.abs()))
    } else if v_long < 0.25 {
        Some(format!("v_long = {v_long:.3} < 0.25"))
    } else if f.e_psi.abs() > std::f64::consts::FRAC_PI_2 {
        Some(format!("|e_psi| = {:.3} > pi/2", f.e_psi.abs()))
    } else {
        None
    }
}

/// Drive the MPCC from the fixed spawn in the nominal plant.
pub fn drive(mpcc: &Mpcc, plant: &VehicleParams, opts: &DriveOptions) -> DriveReport {
    drive_from(mpcc, plant, fixed_spawn(mpcc.track()), opts)
}

/// Drive the MPCC from state `spawn` (global frame) in the nominal plant.
pub fn drive_from(
    mpcc: &Mpcc,
    plant: &VehicleParams,
    spawn: State,
    opts: &DriveOptions,
) -> DriveReport {
    let track = mpcc.track();
    let dt = mpcc.config().dt;
    let mut q = spawn;
    let mut report = DriveReport {
        steps: Vec::new(),
        lap_times: Vec::new(),
        failures: 0,
        end: DriveEnd::MaxSteps,
    };
    let mut frenet = match track.global_to_local(q[3], q[4], q[5]) {
        Ok(f) => f,
        Err(e) => {
            report.end = DriveEnd::Error(e.to_string());
            return report;
        }
    };
    let mut stream = match mpcc.start(&q) {
        Ok(s) => s,
        Err(e) => {
            report.end = DriveEnd::Error(e.to_string());
            return report;
        }
    };
    let mut lap_start = 0usize;
    for i in 0..opts.max_steps {
        let step = match mpcc.step(&mut stream, &q) {
            Ok(s) => s,
            Err(e) => {
                report.end = DriveEnd::Error(e.to_string());
                return report;
            }
        };
        let u = clip_action(&step.action);
        report.steps.push(DriveStep {
            t: i as f64 * dt,
            state: q,
            frenet,
            action: u,
            success: step.success,
            status: step.status,
            qp_iterations: step.qp_iterations,
            solve_time: step.solve_time.as_secs_f64(),
            step_time: step.step_time.as_secs_f64(),
        });
        if !step.success {
            report.failures += 1;
            if opts.stop_on_failure {
                report.end = DriveEnd::Failure;
                return report;
            }
        }
        // Plant: 10 RK4 sub-steps, projecting after each (a failed projection truncates).
        let old = (q, frenet);
        let substeps = 10;
        let mut left_band = None;
        for _ in 0..substeps {
            q = plant.rk4(&q, &u, dt / substeps as f64);
            match track.global_to_local(q[3], q[4], q[5]) {
                Ok(f) => frenet = f,
                Err(e) => left_band = Some(e.to_string()),
            }
        }
        if let Some(e) = left_band {
            report.end = DriveEnd::Truncated(e);
            return report;
        }
        if track.crosses_start_line((old.0[3], old.0[4]), (q[3], q[4])) && frenet.s < old.1.s {
            report.lap_times.push((i + 1 - lap_start) as f64 * dt);
            lap_start = i + 1;
            if report.lap_times.len() >= opts.laps {
                report.end = DriveEnd::Laps;
                return report;
            }
        }
        if let Some(why) = truncation(&frenet, q[0], track.half_width()) {
            report.end = DriveEnd::Truncated(why);
            return report;
        }
    }
    report
}

/// Step-time statistics of a closed-loop run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BenchReport {
    /// Steps measured.
    pub steps: usize,
    /// Median MPCC step wall time.
    pub p50: Duration,
    /// 99th percentile.
    pub p99: Duration,
    /// Mean.
    pub mean: Duration,
    /// Maximum.
    pub max: Duration,
    /// Median of Clarabel's own solve time per step (both QPs).
    pub solve_p50: Duration,
    /// Median Clarabel iterations per step.
    pub iterations_p50: u32,
    /// Failed steps.
    pub failures: usize,
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} MPCC steps: p50 {:.3} ms, p99 {:.3} ms, mean {:.3} ms, max {:.3} ms; Clarabel solve p50 {:.3} ms, \
             {} IPM iterations p50; {} failures",
            self.steps,
            self.p50.as_secs_f64() * 1e3,
            self.p99.as_secs_f64() * 1e3,
            self.mean.as_secs_f64() * 1e3,
            self.max.as_secs_f64() * 1e3,
            self.solve_p50.as_secs_f64() * 1e3,
            self.iterations_p50,
            self.failures
        )
    }
}

fn quantile<T: Copy + Ord>(v: &mut [T], p: f64) -> T {
    v.sort_unstable();
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Time `steps` MPCC steps of a closed-loop drive from the fixed spawn (on the calling thread, one core).
pub fn bench(mpcc: &Mpcc, plant: &VehicleParams, steps: usize) -> Result<BenchReport, MpccError> {
    let opts = DriveOptions {
        laps: usize::MAX,
        max_steps: steps.max(1),
        stop_on_failure: false,
    };
    let r = drive(mpcc, plant, &opts);
    if let DriveEnd::Error(e) = &r.end {
        return Err(MpccError::Config(format!("bench drive stopped: {e}")));
    }
    let mut t: Vec<Duration> = r
        .steps
        .iter()
        .map(|s| Duration::from_secs_f64(s.step_time))
        .collect();
    let mut st: Vec<Duration> = r
        .steps
        .iter()
        .map(|s| Duration::from_secs_f64(s.solve_time))
        .collect();
    let mut it: Vec<u32> = r.steps.iter().map(|s| s.qp_iterations).collect();
    let n = t.len();
    Ok(BenchReport {
        steps: n,
        p50: quantile(&mut t, 0.5),
        p99: quantile(&mut t, 0.99),
        mean: t.iter().sum::<Duration>() / n as u32,
        max: *t.iter().max().expect("at least one step"),
        solve_p50: quantile(&mut st, 0.5),
        iterations_p50: quantile(&mut it, 0.5),
        failures: r.failures,
    })
}
