//! `cabc robust`'s figure (robust.png): the crash share per noise level with its Wilson 95 % interval, and the
//! track with the spawns coloured by the first level at which they crash (green: none).

use super::{RobustError, RobustReport};
use cabc_outputs::plots::{chart, legend, png, track_map};
use cabc_sim::track::Track;
use plotters::prelude::*;
use std::path::Path;

const PANEL: (u32, u32) = (640, 600);
/// The colour of a spawn that first crashes at level k (cycled).
const FIRST_CRASH: [RGBColor; 5] = [
    RGBColor(210, 30, 30),
    RGBColor(245, 140, 20),
    RGBColor(170, 60, 200),
    RGBColor(40, 90, 220),
    RGBColor(120, 80, 40),
];
const NO_CRASH: RGBColor = RGBColor(30, 160, 60);

/// Draws the report's figure into `path`, the spawns on `track` (the run's, `sim.track`).
pub fn draw(path: &Path, track: &Track, report: &RobustReport) -> Result<(), RobustError> {
    png(path, (2 * PANEL.0, PANEL.1), |root| {
        root.fill(&WHITE)?;
        let (left, right) = root.split_horizontally(PANEL.0);
        shares(&left, report)?;
        map(&right, track, report)
    })
    .map_err(|e| RobustError::Figure {
        path: path.display().to_string(),
        message: e.to_string(),
    })
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type PlotResult = Result<(), Box<dyn std::error::Error>>;

fn shares(area: &Area<'_>, report: &RobustReport) -> PlotResult {
    let levels = &report.levels;
    let x_max = levels.iter().map(|l| l.level).fold(0.0, f64::max);
    let pad = if x_max > 0.0 { 0.05 * x_max } else { 0.5 };
    let caption = format!(
        "Crash share from {} spawns, {} laps",
        report.spawns, report.laps
    );
    let mut chart = chart(area, &caption, 50).build_cartesian_2d(-pad..x_max + pad, 0.0..1.0)?;
    chart
        .configure_mesh()
        .x_desc(format!(
            "noise level (x action std {:?}, state std {:?})",
            report.action_noise, report.state_noise
        ))
        .y_desc("crash share (Wilson 95 %)")
        .x_label_style(("sans-serif", 13))
        .draw()?;
    chart.draw_series(levels.iter().map(|l| {
        let [lo, hi] = l.crash_share_95;
        ErrorBar::new_vertical(l.level, lo, l.crash_share, hi, RED.filled(), 8)
    }))?;
    let mut points: Vec<(f64, f64)> = levels.iter().map(|l| (l.level, l.crash_share)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart
        .draw_series(LineSeries::new(points.clone(), RED.stroke_width(2)))?
        .label("crash share")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
    chart.draw_series(points.into_iter().map(|p| Circle::new(p, 4, RED.filled())))?;
    legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

fn map(area: &Area<'_>, track: &Track, report: &RobustReport) -> PlotResult {
    let mut chart = track_map(area, track, "Spawns by the first level that crashes")?;
    let first_crash = |i: usize| {
        report
            .levels
            .iter()
            .position(|l| l.outcomes.get(i).is_some_and(|o| o.crashed))
    };
    let colour = |k: Option<usize>| k.map_or(NO_CRASH, |k| FIRST_CRASH[k % FIRST_CRASH.len()]);
    let keys: Vec<Option<usize>> = (0..report.spawn_points.len()).map(first_crash).collect();
    for key in std::iter::once(None).chain((0..report.levels.len()).map(Some)) {
        let points: Vec<(f64, f64)> = report
            .spawn_points
            .iter()
            .zip(&keys)
            .filter(|(_, k)| **k == key)
            .map(|(p, _)| (p.x, p.y))
            .collect();
        if points.is_empty() {
            continue;
        }
        let c = colour(key);
        let label = match key {
            None => format!("no crash ({})", points.len()),
            Some(k) => format!(
                "first crash at level {} ({})",
                report.levels[k].level,
                points.len()
            ),
        };
        chart
            .draw_series(points.into_iter().map(|p| Circle::new(p, 4, c.filled())))?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}
