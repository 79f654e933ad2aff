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

use crate::drive::{drive, drive_from, DriveEnd, DriveOptions};
use crate::mpcc::{phases, Mpcc, MpccConfig, MpccError};
use crate::relabel::{Expert, Relabeller};

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

/// One way of running MPCC-conv that `expert-server bench --candidates` measures beside the reference's.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// Short name.
    pub name: &'static str,
    /// What it changes, against the reference.
    pub change: &'static str,
    /// The controller's configuration.
    pub config: MpccConfig,
}

/// The candidates of issue 75, the reference first.
pub fn candidates() -> Vec<Candidate> {
    let reference = MpccConfig::default();
    let with = |f: &dyn Fn(&mut MpccConfig)| {
        let mut c = reference.clone();
        f(&mut c);
        c
    };
    #[allow(unused_mut)]
    let mut all = vec![
        Candidate {
            name: "reference",
            change: "none: 2 QPs a step, gap 1e-5, feasibility 1e-6, every row",
            config: reference.clone(),
        },
        Candidate {
            name: "lazy-boxes",
            change: "the v_y, ω, ψ boxes only when the minimiser leaves them (the same minimiser)",
            config: with(&|c| c.lazy_state_boxes = true),
        },
        Candidate {
            name: "tol-1e-4",
            change: "gap 1e-4, feasibility 1e-5",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-4, 1e-5)),
        },
        Candidate {
            name: "tol-3e-4",
            change: "gap 3e-4, feasibility 3e-5",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-4, 3e-5)),
        },
        Candidate {
            name: "tol-1e-3",
            change: "gap 1e-3, feasibility 1e-4",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-3, 1e-4)),
        },
        Candidate {
            name: "tol-3e-3",
            change: "gap 3e-3, feasibility 3e-4",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-3, 3e-4)),
        },
        Candidate {
            name: "converged-1e-2",
            change: "the second QP only when the first moved a scaled variable by 1e-2 or more",
            config: with(&|c| c.qp_converged_step = 1e-2),
        },
        Candidate {
            name: "one-qp",
            change: "one QP a step",
            config: with(&|c| c.qp_iters = 1),
        },
        Candidate {
            name: "one-qp-undamped",
            change: "one QP a step, its minimiser taken whole (damping 0)",
            config: with(&|c| (c.qp_iters, c.damping) = (1, 0.0)),
        },
        Candidate {
            name: "one-qp-damping-0.1",
            change: "one QP a step, damping 0.1",
            config: with(&|c| (c.qp_iters, c.damping) = (1, 0.1)),
        },
        Candidate {
            name: "lead-1e-2",
            change: "the first QP of a step at gap 1e-2, feasibility 1e-3",
            config: with(&|c| c.lead_qp_tol = Some((1e-2, 1e-3))),
        },
        Candidate {
            name: "lead-1e-3",
            change: "the first QP of a step at gap 1e-3, feasibility 1e-4",
            config: with(&|c| c.lead_qp_tol = Some((1e-3, 1e-4))),
        },
        Candidate {
            name: "lead-1e-2-tol-1e-3",
            change: "lead-1e-2 and the last at tol-1e-3",
            config: with(&|c| {
                c.lead_qp_tol = Some((1e-2, 1e-3));
                (c.tol_gap, c.tol_feas) = (1e-3, 1e-4);
            }),
        },
        Candidate {
            name: "tol-1e-2",
            change: "gap 1e-2, feasibility 1e-3",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-2, 1e-3)),
        },
        Candidate {
            name: "tol-3e-2",
            change: "gap 3e-2, feasibility 3e-3",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-2, 3e-3)),
        },
        Candidate {
            name: "tol-1e-1",
            change: "gap 1e-1, feasibility 1e-2",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-1, 1e-2)),
        },
        Candidate {
            name: "lazy-tol-1e-2",
            change: "lazy-boxes and tol-1e-2",
            config: with(&|c| {
                c.lazy_state_boxes = true;
                (c.tol_gap, c.tol_feas) = (1e-2, 1e-3);
            }),
        },
        Candidate {
            name: "gap-1e-2",
            change: "gap 1e-2, feasibility 1e-6",
            config: with(&|c| c.tol_gap = 1e-2),
        },
        Candidate {
            name: "feas-1e-3",
            change: "gap 1e-5, feasibility 1e-3",
            config: with(&|c| c.tol_feas = 1e-3),
        },
        Candidate {
            name: "gap-rel-1e-2",
            change: "gap 1e-5 absolute, 1e-2 relative",
            config: with(&|c| c.tol_gap_rel = Some(1e-2)),
        },
        Candidate {
            name: "step-0.999",
            change: "max step fraction 0.999",
            config: with(&|c| c.max_step_fraction = 0.999),
        },
        Candidate {
            name: "step-0.999-tol-1e-2",
            change: "max step fraction 0.999, tol-1e-2",
            config: with(&|c| {
                c.max_step_fraction = 0.999;
                (c.tol_gap, c.tol_feas) = (1e-2, 1e-3);
            }),
        },
        Candidate {
            name: "lazy-tol-1e-3",
            change: "lazy-boxes and tol-1e-3",
            config: with(&|c| {
                c.lazy_state_boxes = true;
                (c.tol_gap, c.tol_feas) = (1e-3, 1e-4);
            }),
        },
    ];
    #[cfg(feature = "faer")]
    all.push(Candidate {
        name: "faer",
        change: "faer's sparse LDLᵀ instead of QDLDL (the same KKT system)",
        config: with(&|c| c.ldl = crate::mpcc::Ldl::Faer),
    });
    all
}

/// The reference and the candidates named in `only` (all of them when it is empty), in [`candidates`]' order; an
/// unknown name is an error that lists the names.
pub fn chosen(only: &[String]) -> anyhow::Result<Vec<Candidate>> {
    let all = candidates();
    if let Some(unknown) = only.iter().find(|n| !all.iter().any(|c| c.name == **n)) {
        let names: Vec<_> = all.iter().map(|c| c.name).collect();
        anyhow::bail!("no candidate {unknown:?}; candidates: {}", names.join(", "));
    }
    Ok(all
        .into_iter()
        .enumerate()
        .filter(|(i, c)| *i == 0 || only.is_empty() || only.iter().any(|n| n == c.name))
        .map(|(_, c)| c)
        .collect())
}

/// A candidate's figures: its step time side by side with the others, its laps from the fixed spawn, and its
/// failures from random spawns.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CandidateRow {
    pub name: String,
    pub change: String,
    /// Median over the repeats of each drive's step p50 [ms].
    pub step_ms_p50: f64,
    /// Its ratio to the reference's.
    pub step_ratio: f64,
    pub solve_ms_p50: f64,
    /// Clarabel iterations per step, mean.
    pub iterations_per_step: f64,
    /// QPs per step, mean.
    pub qps_per_step: f64,
    /// QPs solved again with every row, per step (`lazy_state_boxes`).
    pub full_resolves_per_step: f64,
    /// Flying laps (all but the first) of the drive from the fixed spawn: mean [s] and count.
    pub flying_lap_mean_s: Option<f64>,
    pub flying_laps: usize,
    /// Failed steps of the drive from the fixed spawn.
    pub failures: usize,
    /// Random spawns (the training distribution, `Spawn::Random`): episodes, failed steps, episodes that ended
    /// off the band or stalled before `spawn_steps`.
    pub spawn_episodes: usize,
    pub spawn_failed_steps: usize,
    pub spawn_truncated: usize,
    /// The random-spawn episodes' steps (states off the racing line, as an actor's policy visits them): mean step
    /// time [ms] and Clarabel iterations per step.
    pub spawn_step_ms_mean: f64,
    pub spawn_iterations_per_step: f64,
}

/// Measures `cands` side by side: `repeat` rounds, each timing every candidate's drive of `steps` steps in turn
/// (so that a drift of the machine's speed falls on all of them), then each one's random-spawn episodes
/// (`spawns` of `spawn_steps` steps, spawns drawn from seed 75).
pub fn compare(
    track: &cabc_sim::track::Track,
    cands: &[Candidate],
    steps: usize,
    repeat: usize,
    spawns: usize,
    spawn_steps: usize,
) -> Result<Vec<CandidateRow>, MpccError> {
    let plant = VehicleParams::default();
    let mpccs = cands
        .iter()
        .map(|c| Mpcc::new(track.clone(), plant.clone(), c.config.clone()))
        .collect::<Result<Vec<_>, _>>()?;
    let mut reports: Vec<Vec<BenchReport>> = vec![Vec::new(); cands.len()];
    for _ in 0..repeat.max(1) {
        for (m, out) in mpccs.iter().zip(reports.iter_mut()) {
            out.push(bench(m, &plant, steps)?);
        }
    }
    let opts = DriveOptions {
        laps: usize::MAX,
        max_steps: steps.max(1),
        stop_on_failure: false,
    };
    let spawn_states: Vec<_> = (0..spawns as u64)
        .map(|i| {
            let mut env = cabc_sim::env::Env::new(
                std::sync::Arc::new(track.clone()),
                plant.clone(),
                cabc_sim::env::EnvConfig::default(),
            );
            env.reset(
                cabc_proto::config::Spawn::Random,
                &mut cabc_sim::env::Env::rng(75, i),
            );
            env.vehicle_state()
        })
        .collect();
    let spawn_opts = DriveOptions {
        laps: usize::MAX,
        max_steps: spawn_steps,
        stop_on_failure: false,
    };
    let mut rows = Vec::new();
    for ((c, m), runs) in cands.iter().zip(&mpccs).zip(&reports) {
        let mut p50s: Vec<f64> = runs.iter().map(|r| ms(r.p50)).collect();
        let mut solves: Vec<f64> = runs.iter().map(|r| ms(r.solve_p50)).collect();
        let laps = drive(m, &plant, &opts);
        let flying = laps.lap_times.get(1..).unwrap_or_default();
        let qps: u64 = laps.steps.iter().map(|s| u64::from(s.qps)).sum();
        let its: u64 = laps.steps.iter().map(|s| u64::from(s.qp_iterations)).sum();
        let resolves: u64 = laps.steps.iter().map(|s| u64::from(s.full_resolves)).sum();
        let n = laps.steps.len().max(1) as f64;
        let (mut failed, mut truncated) = (0, 0);
        let (mut spawn_steps_done, mut spawn_secs, mut spawn_its) = (0usize, 0.0, 0u64);
        for q in &spawn_states {
            let r = drive_from(m, &plant, *q, &spawn_opts);
            failed += r.failures;
            truncated += usize::from(matches!(r.end, DriveEnd::Truncated(_) | DriveEnd::Error(_)));
            spawn_steps_done += r.steps.len();
            spawn_secs += r.steps.iter().map(|s| s.step_time).sum::<f64>();
            spawn_its += r
                .steps
                .iter()
                .map(|s| u64::from(s.qp_iterations))
                .sum::<u64>();
        }
        let spawn_n = spawn_steps_done.max(1) as f64;
        rows.push(CandidateRow {
            name: c.name.into(),
            change: c.change.into(),
            step_ms_p50: stats::median(&mut p50s).unwrap_or(0.0),
            step_ratio: 0.0,
            solve_ms_p50: stats::median(&mut solves).unwrap_or(0.0),
            iterations_per_step: its as f64 / n,
            qps_per_step: qps as f64 / n,
            full_resolves_per_step: resolves as f64 / n,
            flying_lap_mean_s: stats::mean(flying),
            flying_laps: flying.len(),
            failures: laps.failures,
            spawn_episodes: spawn_states.len(),
            spawn_failed_steps: failed,
            spawn_truncated: truncated,
            spawn_step_ms_mean: spawn_secs * 1e3 / spawn_n,
            spawn_iterations_per_step: spawn_its as f64 / spawn_n,
        });
    }
    let reference = rows.first().map_or(1.0, |r| r.step_ms_p50);
    for r in &mut rows {
        r.step_ratio = r.step_ms_p50 / reference;
    }
    Ok(rows)
}

/// The rows of [`compare`] as a Markdown table.
pub fn candidates_table(rows: &[CandidateRow]) -> String {
    let mut t = String::from(
        "| candidate | change | step p50 | ratio | solve p50 | IPM it. / step | QPs / step | full re-solves / step | \
         flying lap | failures | random spawns: failed steps, truncated | random spawns: step mean, IPM it. / step |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let lap = r
            .flying_lap_mean_s
            .map_or("-".into(), |l| format!("{l:.3} s ({} laps)", r.flying_laps));
        t += &format!(
            "| {} | {} | {:.3} ms | {:.2} | {:.3} ms | {:.1} | {:.2} | {:.3} | {lap} | {} | {}, {} of {} | {:.3} ms, {:.1} |\n",
            r.name,
            r.change,
            r.step_ms_p50,
            r.step_ratio,
            r.solve_ms_p50,
            r.iterations_per_step,
            r.qps_per_step,
            r.full_resolves_per_step,
            r.failures,
            r.spawn_failed_steps,
            r.spawn_truncated,
            r.spawn_episodes,
            r.spawn_step_ms_mean,
            r.spawn_iterations_per_step
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The candidates are measured on the same drives as the reference, which comes first with ratio 1: one QP a step
    /// solves half the QPs, the reference never solves a QP again, and the table has a row per candidate.
    #[test]
    fn candidates_are_measured_beside_the_reference() {
        let picked = chosen(&["one-qp".into(), "lazy-boxes".into()]).unwrap();
        assert!(chosen(&["nonsense".into()])
            .unwrap_err()
            .to_string()
            .contains("lazy-boxes"));
        let track = cabc_sim::track::Track::l_track_barc();
        let rows = compare(&track, &picked, 30, 1, 2, 10).unwrap();
        let names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["reference", "lazy-boxes", "one-qp"]);
        assert_eq!(rows[0].step_ratio, 1.0);
        assert_eq!((rows[0].qps_per_step, rows[2].qps_per_step), (2.0, 1.0));
        assert_eq!(rows[0].full_resolves_per_step, 0.0);
        assert!(rows
            .iter()
            .all(|r| r.spawn_episodes == 2 && r.step_ms_p50 > 0.0));
        assert_eq!(candidates_table(&rows).lines().count(), 2 + rows.len());
    }
}
