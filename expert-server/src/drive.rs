//! Closed-loop drives of the MPCC in the nominal plant, `sim::Env`: its sub-stepping, truncation rules and lap
//! detection (simulator.md §1.4, §3.5–3.6), with no lap limit. A drive ends at the wanted laps, the first
//! truncation (a lap completed on the truncating step still counts, unless the car left the band), a failed step
//! when asked, or the step limit.

use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use cabc_proto::stats;
use cabc_sim::env::{fixed_spawn_state, Env, EnvConfig, Truncation};
use cabc_sim::track::Frenet;
use cabc_sim::vehicle::{clip_action, State, VehicleParams};
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::mpcc::{Mpcc, QpStatus};

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
    /// QPs solved in the step.
    pub qps: u32,
    /// QPs solved again with every row (`lazy_state_boxes`).
    pub full_resolves: u32,
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
    /// The env truncated the episode.
    Truncated(Truncation),
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

/// Drive the MPCC from the fixed spawn in the nominal plant.
pub fn drive(mpcc: &Mpcc, plant: &VehicleParams, opts: &DriveOptions) -> DriveReport {
    drive_from(mpcc, plant, fixed_spawn_state(mpcc.track()), opts)
}

/// Drive the MPCC from state `spawn` (global frame) in the nominal plant.
pub fn drive_from(
    mpcc: &Mpcc,
    plant: &VehicleParams,
    spawn: State,
    opts: &DriveOptions,
) -> DriveReport {
    let mut report = DriveReport {
        steps: Vec::new(),
        lap_times: Vec::new(),
        failures: 0,
        end: DriveEnd::MaxSteps,
    };
    let config = EnvConfig {
        max_laps: u32::MAX,
        ..EnvConfig::default()
    };
    let mut env = Env::new(Arc::new(mpcc.track().clone()), plant.clone(), config);
    if let Err(e) = env.set_state(spawn) {
        report.end = DriveEnd::Error(e.to_string());
        return report;
    }
    let mut stream = match mpcc.start(&spawn) {
        Ok(s) => s,
        Err(e) => {
            report.end = DriveEnd::Error(e.to_string());
            return report;
        }
    };
    let dt = env.config().dt;
    for i in 0..opts.max_steps {
        let q = env.vehicle_state();
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
            frenet: env.frenet(),
            action: u,
            success: step.success,
            status: step.status,
            qps: step.qps,
            full_resolves: step.full_resolves,
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
        let r = env.step(&u);
        if r.truncation == Some(Truncation::LeftBand) {
            report.end = DriveEnd::Truncated(Truncation::LeftBand);
            return report;
        }
        if let Some(lap_time) = r.lap_time {
            report.lap_times.push(lap_time);
            if report.lap_times.len() >= opts.laps {
                report.end = DriveEnd::Laps;
                return report;
            }
        }
        if let Some(t) = r.truncation {
            report.end = DriveEnd::Truncated(t);
            return report;
        }
    }
    report
}

impl DriveReport {
    /// The JSON summary: laps, lap times with their mean and (population) std, failures, how it ended,
    /// max |x_tran|, solve-time percentiles.
    pub fn summary(&self) -> serde_json::Value {
        let mut solve_ms: Vec<f64> = self.steps.iter().map(|s| s.solve_time * 1e3).collect();
        solve_ms.sort_by(f64::total_cmp);
        let lap = stats::mean_std(&self.lap_times);
        json!({
            "steps": self.steps.len(),
            "laps": self.lap_times.len(),
            "lap_times": self.lap_times,
            "lap_time_mean": lap.map(|(m, _)| m),
            "lap_time_std": lap.map(|(_, s)| s),
            "failures": self.failures,
            "end": format!("{:?}", self.end),
            "max_abs_x_tran": self.steps.iter().map(|s| s.frenet.x_tran.abs()).fold(0.0, f64::max),
            "solve_ms_p50": stats::percentile_sorted(&solve_ms, 0.5),
            "solve_ms_p99": stats::percentile_sorted(&solve_ms, 0.99),
        })
    }

    /// Every step as CSV.
    pub fn write_csv(&self, path: &Path) -> std::io::Result<()> {
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(f, "t,v_x,v_y,omega,X,Y,psi,s,x_tran,e_psi,a,delta,success,status,qp_iterations,solve_ms,step_ms")?;
        for s in &self.steps {
            write!(f, "{:.2}", s.t)?;
            for v in s.state {
                write!(f, ",{v}")?;
            }
            let (fr, a) = (s.frenet, s.action);
            writeln!(
                f,
                ",{},{},{},{},{},{},{},{},{:.4},{:.4}",
                fr.s,
                fr.x_tran,
                fr.e_psi,
                a[0],
                a[1],
                s.success,
                s.status,
                s.qp_iterations,
                s.solve_time * 1e3,
                s.step_time * 1e3
            )?;
        }
        f.flush()
    }
}
