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
use crate::mpcc::{phases, Mpcc, MpccError};
use crate::relabel::{Expert, Relabeller};

mod candidates;
pub use candidates::{candidates, candidates_table, chosen, compare, Candidate, CandidateRow};

/// `expert-server bench`'s options.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Closed-loop steps to time.
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    /// Time the closed-loop drive this many times and report the median of the runs' medians (a shared machine's
    /// speed drifts by ±20 % over minutes; one run is one sample of it).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Where a step's time goes instead: Clarabel's own timers per phase and the time outside Clarabel.
    #[arg(long, conflicts_with = "candidates")]
    pub profile: bool,
    /// How fast the KKT system of a step's QP factors instead (issue 75): QDLDL as Clarabel runs it, the same
    /// factors from a precomputed schedule, and the smaller system with the inequality rows eliminated; --repeat
    /// medians of 1000 factorisations each.
    #[arg(long, conflicts_with_all = ["candidates", "profile"])]
    pub kkt: bool,
    /// Measure the ways of cutting a step (issue 75) side by side with the reference's: step time (median of
    /// --repeat interleaved drives), iterations, QPs, laps from the fixed spawn, failures from random spawns.
    #[arg(long)]
    pub candidates: bool,
    /// With --candidates: only these (by name, repeatable; the reference is always measured first).
    #[arg(long = "only", value_name = "NAME")]
    pub only: Vec<String>,
    /// With --candidates: random spawns (the training distribution) each candidate drives.
    #[arg(long, default_value_t = 40)]
    pub spawns: usize,
    /// With --candidates: steps of each random-spawn episode.
    #[arg(long, default_value_t = 100)]
    pub spawn_steps: usize,
}

/// `expert-server bench` with `mpcc` (the run's expert): the report, the profile (`--profile`) or the candidates'
/// rows (`--candidates`, their Markdown table on stderr), as JSON.
pub fn run(mpcc: &Mpcc, args: &BenchArgs) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(args.steps >= 10, "--steps must be at least 10");
    anyhow::ensure!(args.repeat >= 1, "--repeat must be at least 1");
    if args.profile {
        return Ok(profile(mpcc, args.steps)?);
    }
    if args.kkt {
        return Ok(serde_json::to_value(
            mpcc.layout().kkt_timings(args.repeat, 1000),
        )?);
    }
    if args.candidates {
        let chosen = chosen(&args.only)?;
        let (steps, spawns) = (args.steps, args.spawns);
        let rows = compare(
            mpcc.track(),
            &chosen,
            steps,
            args.repeat,
            spawns,
            args.spawn_steps,
        )?;
        eprint!("{}", candidates_table(&rows));
        return Ok(serde_json::to_value(rows)?);
    }
    report(&Arc::new(mpcc.clone()), args.steps, args.repeat)
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

/// `expert-server bench --profile`: where one stream's MPCC step goes, from Clarabel's own timers
/// ([`phases::SolverPhases`]) and the step's wall time outside Clarabel (the rollout, the RK4 Jacobians, the
/// contour errors, the QP's assembly), over a closed-loop drive of `steps` steps from the fixed spawn.
pub fn profile(mpcc: &Mpcc, steps: usize) -> Result<serde_json::Value, MpccError> {
    phases::start();
    let r = drive(
        mpcc,
        &VehicleParams::default(),
        &DriveOptions {
            laps: usize::MAX,
            max_steps: steps.max(1),
            stop_on_failure: false,
        },
    );
    let p = phases::take();
    if let DriveEnd::Error(e) = &r.end {
        return Err(MpccError::Config(format!("profile drive stopped: {e}")));
    }
    let n = r.steps.len().max(1) as f64;
    let per_step = |d: Duration| ms(d) / n;
    let step: f64 = r.steps.iter().map(|s| s.step_time).sum::<f64>() * 1e3 / n;
    let solve: f64 = r.steps.iter().map(|s| s.solve_time).sum::<f64>() * 1e3 / n;
    let parts = [
        (
            "outside Clarabel (rollout, Jacobians, contour, assembly)",
            step - solve,
        ),
        (
            "Clarabel: data (update_P/A/q/b or set-up)",
            per_step(p.data),
        ),
        ("Clarabel: default start", per_step(p.default_start)),
        ("Clarabel: scale cones", per_step(p.scale_cones)),
        (
            "Clarabel: kkt update (numeric LDL factorisation)",
            per_step(p.kkt_update),
        ),
        (
            "Clarabel: kkt solve (two solves an iteration)",
            per_step(p.kkt_solve),
        ),
        (
            "Clarabel: rest of the iteration (residuals, step length)",
            per_step(p.iteration_rest),
        ),
    ];
    Ok(json!({
        "steps": r.steps.len(),
        "step_ms_mean": step,
        "qps_per_step": p.qps as f64 / n,
        "iterations_per_qp": p.iterations as f64 / (p.qps.max(1) as f64),
        "qp": {"variables": mpcc.layout().n(), "rows": mpcc.layout().m(), "kkt_nnz": p.kkt_nnz, "ldl_nnz": p.ldl_nnz},
        "ms_per_step": parts.iter().map(|(k, v)| json!({"part": k, "ms": v, "share": v / step})).collect::<Vec<_>>(),
    }))
}
