//! `expert-server tracks`: the MPCC expert driven alone on each track from the fixed spawn (issue 76): laps, lap
//! time, solver failures and the solve time per track, as a table. The shipped tracks and the L-track by default;
//! any F1TENTH centre line or pieces file besides.

use crate::drive::{drive, DriveOptions};
use crate::mpcc::{Mpcc, MpccConfig};
use anyhow::Context;
use cabc_proto::config::SimSection;
use cabc_sim::track::Track;
use cabc_sim::vehicle::VehicleParams;
use serde::Serialize;

/// `expert-server tracks`'s options.
#[derive(clap::Args, Debug, Clone)]
pub struct TracksArgs {
    /// A track by name (l-track-barc, oval, chicane, long) or a file (.csv, .toml); repeatable.
    #[arg(long = "track")]
    pub tracks: Vec<String>,
    /// Multiply the named tracks' lengths and widths by this.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// The constraint's half-width (m) instead of each file's narrowest.
    #[arg(long)]
    pub half_width: Option<f64>,
    /// Laps to drive on each.
    #[arg(long, default_value_t = 2)]
    pub laps: usize,
    /// Step limit per track.
    #[arg(long, default_value_t = 20_000)]
    pub max_steps: usize,
    /// Write the rows as JSON here too.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
}

/// Drives every track `args` names (the L-track and the shipped ones without `--track`) and returns the table; a
/// track refused (on stderr, with its file and line) does not stop the others, and fails the command at the end.
pub fn run(args: &TracksArgs) -> anyhow::Result<String> {
    let names: Vec<String> = if args.tracks.is_empty() {
        SimSection::NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        args.tracks.clone()
    };
    let (mut rows, mut refused) = (Vec::new(), Vec::new());
    for name in names {
        let sim = SimSection {
            track: name.clone(),
            track_scale: args.scale,
            track_half_width: args.half_width,
            actor_tracks: Vec::new(),
        };
        eprintln!("[tracks] driving {name}");
        match laps_on(&sim, args.laps, args.max_steps) {
            Ok(row) => rows.push(row),
            Err(e) => {
                eprintln!("[tracks] {name}: {e:#}");
                refused.push(name);
            }
        }
    }
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let table = table(&rows);
    if !refused.is_empty() {
        print!("{table}");
        anyhow::bail!("tracks refused: {}", refused.join(", "));
    }
    Ok(table)
}

/// One track's drive.
#[derive(Debug, Clone, Serialize)]
pub struct TrackLaps {
    pub track: String,
    pub length_m: f64,
    pub half_width_m: f64,
    pub pieces: usize,
    pub laps: usize,
    pub lap_times_s: Vec<f64>,
    pub failures: usize,
    pub steps: usize,
    pub max_abs_x_tran_m: f64,
    pub solve_ms_p50: f64,
    pub end: String,
}

/// Drives the MPCC `laps` laps (at most `max_steps` steps) on the track of `sim`, from the fixed spawn.
pub fn laps_on(sim: &SimSection, laps: usize, max_steps: usize) -> anyhow::Result<TrackLaps> {
    let track: Track = Track::of(sim)?.as_ref().clone();
    let mpcc = Mpcc::new(
        track.clone(),
        VehicleParams::default(),
        MpccConfig::default(),
    )?;
    let opts = DriveOptions {
        laps,
        max_steps,
        stop_on_failure: false,
    };
    let report = drive(&mpcc, &VehicleParams::default(), &opts);
    let mut solve_ms: Vec<f64> = report.steps.iter().map(|s| s.solve_time * 1e3).collect();
    solve_ms.sort_by(f64::total_cmp);
    Ok(TrackLaps {
        track: match sim.track_half_width {
            Some(h) => format!("{} (half-width {h} m)", sim.track),
            None => sim.track.clone(),
        },
        length_m: track.length(),
        half_width_m: track.half_width(),
        pieces: track.pieces().len(),
        laps: report.lap_times.len(),
        lap_times_s: report.lap_times.clone(),
        failures: report.failures,
        steps: report.steps.len(),
        max_abs_x_tran_m: report
            .steps
            .iter()
            .map(|s| s.frenet.x_tran.abs())
            .fold(0.0, f64::max),
        solve_ms_p50: solve_ms
            .get(solve_ms.len() / 2)
            .copied()
            .unwrap_or(f64::NAN),
        end: format!("{:?}", report.end),
    })
}

/// The rows as a Markdown table.
pub fn table(rows: &[TrackLaps]) -> String {
    let mut out = String::from(
        "| track | length (m) | half-width (m) | pieces | laps | lap times (s) | MPCC failures | max abs x_tran (m) | solve p50 (ms) |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let laps: Vec<String> = r.lap_times_s.iter().map(|t| format!("{t:.1}")).collect();
        out += &format!(
            "| {} | {:.2} | {:.3} | {} | {} | {} | {} | {:.3} | {:.2} |\n",
            r.track,
            r.length_m,
            r.half_width_m,
            r.pieces,
            r.laps,
            laps.join(", "),
            r.failures,
            r.max_abs_x_tran_m,
            r.solve_ms_p50
        );
    }
    out
}
