//! `expert-server`: answers relabelling queries on `cabc/<run>/expert/<kind>` (serve), drives the simulator with an
//! expert alone (drive), and measures solve rates (bench). A thin shell over the `cabc_expert` library.

mod server;

use anyhow::{bail, Context, Result};
use cabc_expert::drive::{bench, drive, DriveOptions, DriveReport};
use cabc_expert::relabel::{Expert, Relabeller};
use cabc_expert::{Mpcc, MpccConfig};
use cabc_proto::config::{ExpertKind, RunConfig};
use cabc_sim::track::Track;
use cabc_sim::vehicle::VehicleParams;
use clap::{Parser, Subcommand};
use serde_json::json;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "expert-server",
    version,
    about = "The cabc expert: MPCC-conv on Clarabel or the PID lane follower"
)]
struct Cli {
    /// Run configuration: a preset (v-a, v-b, v-c, smoke) or a TOML file.
    #[arg(long, short, global = true, default_value = "v-b")]
    config: String,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Serve relabelling queries over zenoh (the default).
    Serve(server::ServeArgs),
    /// Drive the simulator with the MPCC alone from the fixed spawn and print a JSON summary.
    Drive {
        /// Laps to drive.
        #[arg(long, default_value_t = 3)]
        laps: usize,
        /// Step limit.
        #[arg(long, default_value_t = 5000)]
        max_steps: usize,
        /// Write every step as CSV.
        #[arg(long)]
        trace: Option<std::path::PathBuf>,
        /// Draw the driven line on the track (PNG).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
    },
    /// Print MPCC solves per second per core and step-time percentiles.
    Bench {
        /// Closed-loop steps to time.
        #[arg(long, default_value_t = 300)]
        steps: usize,
        /// Time the closed-loop drive this many times and report the median of the runs' medians (a shared
        /// machine's speed drifts by ±20 % over minutes; one run is one sample of it).
        #[arg(long, default_value_t = 1)]
        repeat: usize,
    },
}

fn main() -> Result<()> {
    cabc_proto::telemetry::init();
    let cli = Cli::parse();
    let config = RunConfig::load(&cli.config)
        .with_context(|| format!("loading configuration {}", cli.config))?;
    match cli
        .command
        .unwrap_or(Command::Serve(server::ServeArgs::default()))
    {
        Command::Serve(args) => {
            let expert = match config.expert.kind {
                ExpertKind::Mpcc => Expert::Mpcc(Arc::new(mpcc()?)),
                ExpertKind::Pid => Expert::Pid(config.expert.pid_target_speed),
            };
            server::serve(config, expert, args)
        }
        Command::Drive {
            laps,
            max_steps,
            trace,
            plot,
        } => {
            let mpcc = mpcc()?;
            let report = drive(
                &mpcc,
                &VehicleParams::default(),
                &DriveOptions {
                    laps,
                    max_steps,
                    stop_on_failure: false,
                },
            );
            if let Some(path) = &trace {
                write_trace(&report, path)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            if let Some(path) = &plot {
                let line: Vec<(f64, f64)> = report
                    .steps
                    .iter()
                    .map(|s| (s.state[3], s.state[4]))
                    .collect();
                cabc_sim::map::render_track(mpcc.track(), 100.0, &line)
                    .write_png(path)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            println!("{}", serde_json::to_string_pretty(&summary(&report))?);
            Ok(())
        }
        Command::Bench { steps, repeat } => {
            if steps < 10 {
                bail!("--steps must be at least 10");
            }
            if repeat == 0 {
                bail!("--repeat must be at least 1");
            }
            let mpcc = Arc::new(mpcc()?);
            let mut runs = (0..repeat)
                .map(|_| bench(&mpcc, &VehicleParams::default(), steps))
                .collect::<Result<Vec<_>, _>>()?;
            let run_p50s: Vec<f64> = runs.iter().map(|r| ms(r.p50)).collect();
            // The run whose median is the median of the runs' medians stands for them all.
            runs.sort_by_key(|r| r.p50);
            let report = runs.swap_remove(repeat / 2);
            let scaling = batch_throughput(&mpcc, steps)?;
            println!(
                "{}",
                serde_json::to_string_pretty(&json!({
                    "single_stream": {
                        "steps": report.steps,
                        "failures": report.failures,
                        "step_ms_p50": ms(report.p50),
                        "step_ms_p99": ms(report.p99),
                        "step_ms_mean": ms(report.mean),
                        "step_ms_max": ms(report.max),
                        "solve_ms_p50": ms(report.solve_p50),
                        "clarabel_iterations_p50": report.iterations_p50,
                        "runs": repeat,
                        "step_ms_p50_of_each_run": run_p50s,
                    },
                    "batch_throughput": scaling
                }))?
            );
            Ok(())
        }
    }
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Solves per second of the relabelling service on batches of 8 streams replaying a closed-loop drive, with 1 thread
/// and with every core: the server's scaling with its cores.
fn batch_throughput(mpcc: &Arc<Mpcc>, steps: usize) -> Result<serde_json::Value> {
    use cabc_proto::messages::{ExpertQuery, ExpertRequest, StreamId};
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
        let started = std::time::Instant::now();
        let mut solved = 0usize;
        for (k, _) in states.iter().enumerate() {
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

/// The JSON summary of a drive: laps, lap times, failures, truncation, max |x_tran|, solve-time percentiles.
fn summary(report: &DriveReport) -> serde_json::Value {
    let mut solve_ms: Vec<f64> = report.steps.iter().map(|s| s.solve_time * 1e3).collect();
    solve_ms.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        (!solve_ms.is_empty()).then(|| solve_ms[((solve_ms.len() - 1) as f64 * p).round() as usize])
    };
    let n = report.lap_times.len() as f64;
    let mean = (n > 0.0).then(|| report.lap_times.iter().sum::<f64>() / n);
    let std = mean.map(|m| {
        (report
            .lap_times
            .iter()
            .map(|t| (t - m).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    });
    json!({
        "steps": report.steps.len(),
        "laps": report.lap_times.len(),
        "lap_times": report.lap_times,
        "lap_time_mean": mean,
        "lap_time_std": std,
        "failures": report.failures,
        "end": format!("{:?}", report.end),
        "max_abs_x_tran": report.steps.iter().map(|s| s.frenet.x_tran.abs()).fold(0.0, f64::max),
        "solve_ms_p50": pct(0.5),
        "solve_ms_p99": pct(0.99),
    })
}

/// Every step of a drive as CSV.
fn write_trace(report: &DriveReport, path: &std::path::Path) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(f, "t,v_x,v_y,omega,X,Y,psi,s,x_tran,e_psi,a,delta,success,status,qp_iterations,solve_ms,step_ms")?;
    for s in &report.steps {
        let q = s.state;
        writeln!(
            f,
            "{:.2},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.4},{:.4}",
            s.t,
            q[0],
            q[1],
            q[2],
            q[3],
            q[4],
            q[5],
            s.frenet.s,
            s.frenet.x_tran,
            s.frenet.e_psi,
            s.action[0],
            s.action[1],
            s.success,
            s.status,
            s.qp_iterations,
            s.solve_time * 1e3,
            s.step_time * 1e3
        )?;
    }
    f.flush()
}

fn mpcc() -> Result<Mpcc> {
    Mpcc::new(
        Track::l_track_barc(),
        VehicleParams::default(),
        MpccConfig::default(),
    )
    .context("building the MPCC")
}
