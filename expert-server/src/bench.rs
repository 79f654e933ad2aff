//! MPCC step times on one core (closed-loop drives from the fixed spawn) and the relabelling service's solves per
//! second with one thread and with every core: the library behind `expert-server bench`.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use cabc_proto::messages::{ExpertQuery, ExpertRequest, StreamId};
use cabc_proto::stats;
use cabc_sim::vehicle::VehicleParams;
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::drive::{drive, DriveEnd, DriveOptions};
use crate::mpcc::{Mpcc, MpccError};
use crate::relabel::{Expert, Relabeller};

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
            ms(self.p50),
            ms(self.p99),
            ms(self.mean),
            ms(self.max),
            ms(self.solve_p50),
            self.iterations_p50,
            self.failures
        )
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
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
    let mut step: Vec<f64> = r.steps.iter().map(|s| s.step_time).collect();
    let mut solve: Vec<f64> = r.steps.iter().map(|s| s.solve_time).collect();
    let mut iterations: Vec<f64> = r.steps.iter().map(|s| s.qp_iterations as f64).collect();
    let secs = |x: Option<f64>| Duration::from_secs_f64(x.unwrap_or(0.0));
    Ok(BenchReport {
        steps: step.len(),
        p50: secs(stats::percentile(&mut step, 0.5)),
        p99: secs(stats::percentile_sorted(&step, 0.99)),
        mean: secs(stats::mean(&step)),
        max: secs(stats::percentile_sorted(&step, 1.0)),
        solve_p50: secs(stats::median(&mut solve)),
        iterations_p50: stats::median(&mut iterations).unwrap_or(0.0) as u32,
        failures: r.failures,
    })
}

/// `expert-server bench`: `repeat` timed drives of `steps` steps (the run whose median is the median of the runs'
/// medians stands for them all, as a shared machine's speed drifts by ±20 % over minutes) and the batch
/// throughput, as JSON.
pub fn report(mpcc: &Arc<Mpcc>, steps: usize, repeat: usize) -> anyhow::Result<serde_json::Value> {
    let mut runs = (0..repeat.max(1))
        .map(|_| bench(mpcc, &VehicleParams::default(), steps))
        .collect::<Result<Vec<_>, _>>()?;
    let run_p50s: Vec<f64> = runs.iter().map(|r| ms(r.p50)).collect();
    runs.sort_by_key(|r| r.p50);
    let report = runs.swap_remove(runs.len() / 2);
    Ok(json!({
        "single_stream": {
            "steps": report.steps,
            "failures": report.failures,
            "step_ms_p50": ms(report.p50),
            "step_ms_p99": ms(report.p99),
            "step_ms_mean": ms(report.mean),
            "step_ms_max": ms(report.max),
            "solve_ms_p50": ms(report.solve_p50),
            "clarabel_iterations_p50": report.iterations_p50,
            "runs": run_p50s.len(),
            "step_ms_p50_of_each_run": run_p50s,
        },
        "batch_throughput": batch_throughput(mpcc, steps)?
    }))
}

/// Solves per second of the relabelling service on batches of 8 streams replaying a closed-loop drive, with 1 thread
/// and with every core: the server's scaling with its cores.
pub fn batch_throughput(mpcc: &Arc<Mpcc>, steps: usize) -> anyhow::Result<serde_json::Value> {
    const STREAMS: usize = 8;
    let drive = drive(
        mpcc,
        &VehicleParams::default(),
        &DriveOptions {
            laps: 100,
            max_steps: steps,
            stop_on_failure: false,
        },
    );
    let states: Vec<_> = drive.steps.iter().map(|s| (s.state, s.frenet)).collect();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut rows = Vec::new();
    for threads in [1, cores] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .context("building a thread pool")?;
        let service = Relabeller::new(Expert::Mpcc(mpcc.clone()), 64, 64);
        let started = Instant::now();
        let mut solved = 0usize;
        for k in 0..states.len() {
            let queries = (0..STREAMS)
                .map(|i| {
                    let (q, f) = states[(k + i * 7) % states.len()];
                    ExpertQuery {
                        stream: StreamId {
                            actor: "bench".into(),
                            env: i as u32,
                            episode: 0,
                        },
                        start: k == 0,
                        vehicle: q,
                        frenet: [q[0], q[1], q[2], f.s, f.x_tran, f.e_psi],
                    }
                })
                .collect();
            let request = ExpertRequest {
                request_id: k as u64,
                queries,
            };
            let answered = pool.install(|| service.answer(&request))?;
            solved += answered.0.answers.len();
        }
        let secs = started.elapsed().as_secs_f64();
        rows.push(
            json!({ "threads": threads, "solves_per_s": solved as f64 / secs, "batch": STREAMS }),
        );
    }
    Ok(json!(rows))
}
