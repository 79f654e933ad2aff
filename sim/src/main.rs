//! `cabc-sim`: a thin command line over the simulator library (rollouts, camera frames, track maps, bench).

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use cabc_proto::config::RunConfig;
use cabc_proto::config::SimSection;
use cabc_sim::camera::{Camera, Sun, REFERENCE_FOV_DEG};
use cabc_sim::rollout::{parse_size, parse_sun, rollout, RolloutOptions};
use cabc_sim::{bench, map, trace, Track};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "cabc-sim",
    version,
    about = "The cabc racing simulator: rollouts, camera frames, track maps, benchmarks"
)]
struct Cli {
    /// A run configuration (a preset or a TOML file) whose `sim.track` the rollout, the frame and the map use;
    /// without one, the default track (L_track_barc).
    #[arg(long, short, global = true)]
    config: Option<String>,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run one episode on the track and summarise it.
    Rollout {
        #[command(flatten)]
        opts: RolloutOptions,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
        /// Write every step as CSV to this file.
        #[arg(long)]
        trace: Option<PathBuf>,
    },
    /// Render one camera frame at a Frenet pose of the track.
    Render {
        #[arg(long, default_value_t = cabc_sim::FIXED_SPAWN.s)]
        s: f64,
        #[arg(long = "x-tran", default_value_t = 0.0, allow_negative_numbers = true)]
        x_tran: f64,
        #[arg(long = "e-psi", default_value_t = 0.0, allow_negative_numbers = true)]
        e_psi: f64,
        /// Sun azimuth and elevation in degrees, "AZ,EL".
        #[arg(long, allow_negative_numbers = true, value_parser = parse_sun)]
        sun: Option<Sun>,
        /// Image size "WxH".
        #[arg(long, default_value = "224x224", value_parser = parse_size)]
        size: (usize, usize),
        /// Horizontal field of view, degrees.
        #[arg(long, default_value_t = REFERENCE_FOV_DEG)]
        fov: f64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Draw the track from above, optionally with a rollout's driven line.
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
    /// Measure env steps/s on one core and camera frames/s on one core and on all.
    Bench {
        /// Seconds per measurement (at least 1).
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
    },
}

fn main() -> Result<()> {
    // Write through a handle so a closed pipe is an error, not a panic.
    let mut out = std::io::stdout().lock();
    let cli = Cli::parse();
    let sim = match &cli.config {
        Some(name) => {
            RunConfig::load(name)
                .with_context(|| format!("loading configuration {name}"))?
                .sim
        }
        None => SimSection::default(),
    };
    let track = Track::of(&sim)?.as_ref().clone();
    match cli.cmd {
        Cmd::Rollout { opts, json, trace } => {
            let summary = rollout(&opts, Arc::new(track), trace.as_deref())?;
            if json {
                writeln!(out, "{}", serde_json::to_string_pretty(&summary)?)?;
            } else {
                write!(out, "{summary}")?;
            }
        }
        Cmd::Render {
            s,
            x_tran,
            e_psi,
            sun,
            size: (w, h),
            fov,
            out: path,
        } => {
            let sun = sun.unwrap_or_default();
            let (frame, pose) = Camera::new(w, h, fov)
                .render_frenet(&track, (s, x_tran, e_psi), sun)
                .map_err(|e| anyhow::anyhow!("--s, --x-tran, --e-psi: {e}"))?;
            frame
                .write_png(&path)
                .with_context(|| format!("writing {}", path.display()))?;
            writeln!(
                out,
                "wrote {} ({w}x{h}) at pose {pose:?}, sun {sun:?}",
                path.display()
            )?;
        }
        Cmd::Track {
            out: path,
            trace,
            scale,
        } => {
            let pts = trace
                .as_deref()
                .map(trace::read_xy)
                .transpose()?
                .unwrap_or_default();
            let img = map::render_track(&track, scale, &pts);
            img.write_png(&path)
                .with_context(|| format!("writing {}", path.display()))?;
            let (w, h, n) = (img.width, img.height, pts.len());
            writeln!(out, "wrote {} ({w}x{h}, {n} trace points)", path.display())?;
        }
        Cmd::Bench { seconds } => write!(out, "{}", bench::run(seconds))?,
    }
    Ok(())
}
