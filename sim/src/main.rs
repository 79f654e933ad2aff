//! `cabc-sim`: a thin command line over the simulator library (rollouts, camera frames, track maps, bench).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use cabc_sim::camera::{Camera, Sun, TrackLookup, REFERENCE_FOV_DEG};
use cabc_sim::env::{Env, EnvConfig, Spawn, Truncation};
use cabc_sim::map::render_track;
use cabc_sim::{Input, PidLaneFollower, Pose, Track};
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "cabc-sim",
    version,
    about = "The cabc racing simulator: rollouts, camera frames, track maps, benchmarks"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run one episode on L_track_barc and summarise it.
    Rollout {
        /// pid | zero | const:A,S (acceleration m/s², steering rad)
        #[arg(long, default_value = "pid")]
        policy: String,
        #[arg(long, value_enum, default_value = "fixed")]
        spawn: SpawnArg,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Maximum number of env steps (0.1 s each).
        #[arg(long, default_value_t = 1000)]
        steps: u64,
        /// Keep stepping after a truncation (the first one is still reported).
        #[arg(long)]
        no_truncate: bool,
        /// Truncate after this many laps.
        #[arg(long, default_value_t = 50)]
        max_laps: u32,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
        /// Write every step as CSV to this file.
        #[arg(long)]
        trace: Option<PathBuf>,
    },
    /// Render one camera frame at a Frenet pose of L_track_barc.
    Render {
        #[arg(long, default_value_t = 0.1)]
        s: f64,
        #[arg(long = "x-tran", default_value_t = 0.0, allow_negative_numbers = true)]
        x_tran: f64,
        #[arg(long = "e-psi", default_value_t = 0.0, allow_negative_numbers = true)]
        e_psi: f64,
        /// Sun azimuth and elevation in degrees, "AZ,EL".
        #[arg(long, allow_negative_numbers = true)]
        sun: Option<String>,
        /// Image size "WxH".
        #[arg(long, default_value = "224x224")]
        size: String,
        /// Horizontal field of view, degrees.
        #[arg(long, default_value_t = REFERENCE_FOV_DEG)]
        fov: f64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Draw L_track_barc from above, optionally with a rollout's driven line.
    Track {
        #[arg(long)]
        out: PathBuf,
        /// A CSV written by `rollout --trace` (columns X and Y are used).
        #[arg(long)]
        trace: Option<PathBuf>,
        /// Pixels per metre.
        #[arg(long, default_value_t = 100.0)]
        scale: f64,
    },
    /// Measure env steps/s and camera frames/s on one core.
    Bench {
        /// Seconds per measurement (at least 1).
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum SpawnArg {
    Fixed,
    Random,
}

enum Policy {
    Pid(Box<PidLaneFollower>),
    Const(Input),
}

impl Policy {
    fn parse(s: &str) -> Result<Policy> {
        match s {
            "pid" => Ok(Policy::Pid(Box::default())),
            "zero" => Ok(Policy::Const([0.0, 0.0])),
            _ => match s.strip_prefix("const:") {
                Some(rest) => {
                    let (a, d) = parse_pair(rest).with_context(|| format!("bad policy {s:?}"))?;
                    Ok(Policy::Const([a, d]))
                }
                None => bail!("unknown policy {s:?}: expected pid, zero or const:A,S"),
            },
        }
    }

    fn action(&mut self, state: &[f64; 6]) -> Input {
        match self {
            Policy::Pid(p) => p.action(state[0], state[4], state[5]),
            Policy::Const(u) => *u,
        }
    }
}

fn parse_pair(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once(',')
        .with_context(|| format!("expected two numbers \"A,B\", got {s:?}"))?;
    let a: f64 = a
        .trim()
        .parse()
        .with_context(|| format!("not a number: {a:?}"))?;
    let b: f64 = b
        .trim()
        .parse()
        .with_context(|| format!("not a number: {b:?}"))?;
    if !a.is_finite() || !b.is_finite() {
        bail!("numbers must be finite, got {s:?}");
    }
    Ok((a, b))
}

fn parse_size(s: &str) -> Result<(usize, usize)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("expected a size \"WxH\", got {s:?}"))?;
    let w: usize = w
        .trim()
        .parse()
        .with_context(|| format!("bad width {w:?}"))?;
    let h: usize = h
        .trim()
        .parse()
        .with_context(|| format!("bad height {h:?}"))?;
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        bail!("image size must be within 1..=8192 on each side, got {w}x{h}");
    }
    Ok((w, h))
}

#[derive(serde::Serialize)]
struct Summary {
    policy: String,
    spawn: Spawn,
    seed: u64,
    steps: u64,
    laps: u32,
    lap_times: Vec<f64>,
    truncation: Option<Truncation>,
    truncation_step: Option<u64>,
    total_reward: f64,
    max_abs_x_tran: f64,
    initial_state: [f64; 6],
    final_state: [f64; 6],
    final_pose: [f64; 3],
}

#[allow(clippy::too_many_arguments)]
fn rollout(
    policy_name: &str,
    spawn: Spawn,
    seed: u64,
    steps: u64,
    no_truncate: bool,
    max_laps: u32,
    json: bool,
    trace: Option<&Path>,
) -> Result<()> {
    let mut policy = Policy::parse(policy_name)?;
    let config = EnvConfig {
        max_laps,
        ..EnvConfig::default()
    };
    let mut env = Env::new(
        std::sync::Arc::new(Track::l_track_barc()),
        Default::default(),
        config,
    );
    let mut rng = Env::rng(seed, 0);
    let obs0 = env.reset(spawn, &mut rng);
    let mut csv = match trace {
        Some(p) => {
            let f = std::fs::File::create(p)
                .with_context(|| format!("creating trace file {}", p.display()))?;
            let mut w = std::io::BufWriter::new(f);
            writeln!(w, "step,t,a,delta,v_long,v_tran,omega,s,x_tran,e_psi,X,Y,psi,reward,lap_no,truncation")?;
            write_row(
                &mut w,
                0,
                0.0,
                &[0.0, 0.0],
                &obs0.state,
                &obs0.pose,
                0.0,
                0,
                None,
            )?;
            Some(w)
        }
        None => None,
    };
    let mut obs = obs0;
    let (mut truncation, mut truncation_step) = (None, None);
    let mut total_reward = 0.0;
    let mut max_abs_x_tran = obs.state[4].abs();
    let mut k = 0;
    while k < steps {
        let u = policy.action(&obs.state);
        let r = env.step(&u);
        k += 1;
        obs = r.obs;
        total_reward += r.reward;
        max_abs_x_tran = max_abs_x_tran.max(obs.state[4].abs());
        if let Some(w) = csv.as_mut() {
            write_row(
                w,
                k,
                env.time(),
                &env.last_action(),
                &obs.state,
                &obs.pose,
                r.reward,
                r.lap_no,
                r.truncation,
            )?;
        }
        if let Some(t) = r.truncation {
            if truncation.is_none() {
                truncation = Some(t);
                truncation_step = Some(k);
            }
            if !no_truncate {
                break;
            }
        }
    }
    if let Some(mut w) = csv {
        w.flush().context("writing the trace")?;
    }
    let summary = Summary {
        policy: policy_name.to_string(),
        spawn,
        seed,
        steps: k,
        laps: env.lap_no(),
        lap_times: env.lap_times().to_vec(),
        truncation,
        truncation_step,
        total_reward,
        max_abs_x_tran,
        initial_state: obs0.state,
        final_state: obs.state,
        final_pose: obs.pose,
    };
    // Write through a handle so a closed pipe is an error, not a panic.
    let mut out = std::io::stdout().lock();
    if json {
        writeln!(out, "{}", serde_json::to_string_pretty(&summary)?)?;
    } else {
        writeln!(
            out,
            "steps {} laps {} lap times {:?}",
            summary.steps, summary.laps, summary.lap_times
        )?;
        match (summary.truncation, summary.truncation_step) {
            (Some(t), Some(s)) => writeln!(out, "truncated: {t} at step {s}")?,
            _ => writeln!(out, "not truncated")?,
        }
        writeln!(
            out,
            "max |x_tran| {:.4}  total reward {:.4}",
            summary.max_abs_x_tran, summary.total_reward
        )?;
        writeln!(
            out,
            "final state {:?}\nfinal pose {:?}",
            summary.final_state, summary.final_pose
        )?;
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn write_row(
    w: &mut impl Write,
    k: u64,
    t: f64,
    u: &Input,
    state: &[f64; 6],
    pose: &[f64; 3],
    reward: f64,
    lap_no: u32,
    trunc: Option<Truncation>,
) -> Result<()> {
    write!(w, "{k},{t:.1},{},{}", u[0], u[1])?;
    for v in state.iter().chain(pose.iter()) {
        write!(w, ",{v}")?;
    }
    writeln!(
        w,
        ",{reward},{lap_no},{}",
        trunc.map(|t| t.to_string()).unwrap_or_default()
    )?;
    Ok(())
}

fn read_trace(path: &Path) -> Result<Vec<(f64, f64)>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading trace {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .context("empty trace file")?
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .with_context(|| format!("trace has no {name} column"))
    };
    let (ix, iy) = (col("X")?, col("Y")?);
    let mut pts = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let f: Vec<&str> = line.split(',').collect();
        let get = |i: usize| -> Result<f64> {
            f.get(i)
                .context("short row")?
                .trim()
                .parse::<f64>()
                .with_context(|| format!("trace line {}: bad number", n + 2))
        };
        pts.push((get(ix)?, get(iy)?));
    }
    Ok(pts)
}

fn bench(seconds: f64) -> Result<()> {
    let seconds = if seconds.is_finite() {
        seconds.max(1.0)
    } else {
        1.0
    };
    let mut env = Env::barc();
    let mut rng = Env::rng(0, 0);
    let mut pid = PidLaneFollower::default();
    let mut obs = env.reset(Spawn::Fixed, &mut rng);
    // Env steps per second, PID policy, reset on truncation.
    let (start, mut n) = (Instant::now(), 0u64);
    let mut poses = Vec::with_capacity(200);
    while start.elapsed().as_secs_f64() < seconds {
        for _ in 0..1000 {
            let r = env.step(&pid.action(obs.state[0], obs.state[4], obs.state[5]));
            obs = r.obs;
            if poses.len() < 200 {
                poses.push(Pose {
                    x: obs.pose[0],
                    y: obs.pose[1],
                    psi: obs.pose[2],
                });
            }
            if r.truncation.is_some() {
                obs = env.reset(Spawn::Random, &mut rng);
                pid.reset();
            }
        }
        n += 1000;
    }
    let env_rate = n as f64 / start.elapsed().as_secs_f64();
    println!("env: {env_rate:.0} steps/s (state only, PID, one core)");

    let track = Track::l_track_barc();
    let t0 = Instant::now();
    let lookup = TrackLookup::new(&track, 0.01);
    println!(
        "camera lookup grid build: {:.1} ms (once per track)",
        t0.elapsed().as_secs_f64() * 1e3
    );
    let sun = Sun::default();
    for size in [64usize, 224] {
        let mut cam = Camera::new(size, size, REFERENCE_FOV_DEG);
        let (start, mut n) = (Instant::now(), 0usize);
        let mut checksum = 0u64;
        while start.elapsed().as_secs_f64() < seconds {
            let img = cam.render(&lookup, poses[n % poses.len()], sun);
            checksum = checksum.wrapping_add(img.rgb[img.rgb.len() / 2] as u64);
            n += 1;
        }
        let rate = n as f64 / start.elapsed().as_secs_f64();
        println!("camera {size}x{size}: {rate:.0} frames/s (one core) [checksum {checksum}]");
    }
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Rollout {
            policy,
            spawn,
            seed,
            steps,
            no_truncate,
            max_laps,
            json,
            trace,
        } => {
            let spawn = match spawn {
                SpawnArg::Fixed => Spawn::Fixed,
                SpawnArg::Random => Spawn::Random,
            };
            rollout(
                &policy,
                spawn,
                seed,
                steps,
                no_truncate,
                max_laps,
                json,
                trace.as_deref(),
            )
        }
        Cmd::Render {
            s,
            x_tran,
            e_psi,
            sun,
            size,
            fov,
            out,
        } => {
            let (w, h) = parse_size(&size)?;
            if !(s.is_finite() && x_tran.is_finite() && e_psi.is_finite()) {
                bail!("--s, --x-tran and --e-psi must be finite");
            }
            let sun = match sun {
                Some(text) => {
                    let (az, el) =
                        parse_pair(&text).context("bad --sun (expected \"AZ,EL\" in degrees)")?;
                    Sun {
                        azimuth: az.to_radians(),
                        elevation: el.to_radians(),
                    }
                }
                None => Sun::default(),
            };
            let track = Track::l_track_barc();
            let lookup = TrackLookup::new(&track, 0.01);
            let mut cam = Camera::new(w, h, fov);
            let pose = track.local_to_global(s, x_tran, e_psi);
            cam.render(&lookup, pose, sun)
                .write_png(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            println!(
                "wrote {} ({w}x{h}) at pose {pose:?}, sun {sun:?}",
                out.display()
            );
            Ok(())
        }
        Cmd::Track { out, trace, scale } => {
            let pts = match &trace {
                Some(p) => read_trace(p)?,
                None => Vec::new(),
            };
            let img = render_track(&Track::l_track_barc(), scale, &pts);
            img.write_png(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            println!(
                "wrote {} ({}x{}, {} trace points)",
                out.display(),
                img.width,
                img.height,
                pts.len()
            );
            Ok(())
        }
        Cmd::Bench { seconds } => bench(seconds),
    }
}
