//! `cabc compare`'s figures: laps, imitation loss, lap times and evaluation steps per policy version, and the share
//! of the collection that failed per epoch, the proposed runs in blues and the baselines in oranges, a shade per seed.

use crate::runs::{CompareError, RunRecord};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Draws the five figures to `<out>-laps.png`, `<out>-imitation.png`, `<out>-lap-times.png`, `<out>-steps.png`,
/// `<out>-crashed.png`; returns their paths.
pub fn draw(runs: &[RunRecord], out: &Path) -> Result<Vec<PathBuf>, CompareError> {
    let path = |suffix: &str| {
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_default();
        out.with_file_name(format!("{name}-{suffix}.png"))
    };
    let figures = [
        path("laps"),
        path("imitation"),
        path("lap-times"),
        path("steps"),
        path("crashed"),
    ];
    let drawn = [
        laps(&figures[0], runs),
        imitation(&figures[1], runs),
        lap_times(&figures[2], runs),
        steps(&figures[3], runs),
        crashed(&figures[4], runs),
    ];
    for (result, path) in drawn.into_iter().zip(&figures) {
        result.map_err(|e| CompareError::Draw {
            path: path.clone(),
            why: e.to_string(),
        })?;
    }
    Ok(figures.to_vec())
}

type Drawn = Result<(), Box<dyn std::error::Error>>;

/// The newest version any run evaluated (at least 1: the x axis of the per-version figures).
fn max_version(runs: &[RunRecord]) -> u64 {
    runs.iter()
        .flat_map(|r| r.evals.iter().map(|e| e.version))
        .max()
        .unwrap_or(1)
        .max(1)
}

const SIZE: (u32, u32) = (1000, 560);

/// Two hues, blue for the proposed runs and orange for the baselines, and within each a shade per run from dark to
/// light, spread over the runs of that method (seeds are shades of their method's colour).
fn colour(runs: &[RunRecord], i: usize) -> RGBColor {
    let baseline = runs[i].is_baseline();
    let same = |r: &&RunRecord| r.is_baseline() == baseline;
    let k = runs[..i].iter().filter(same).count();
    let n = runs.iter().filter(same).count();
    // 0 (darkest) .. 1 (lightest).
    let t = if n > 1 {
        k as f64 / (n - 1) as f64
    } else {
        0.0
    };
    let (dark, light) = if baseline {
        ([166.0, 54.0, 3.0], [253.0, 174.0, 107.0])
    } else {
        ([8.0, 48.0, 107.0], [107.0, 174.0, 214.0])
    };
    let mix = |c: usize| (dark[c] + (light[c] - dark[c]) * t).round() as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

/// Baselines dashed in the per-version figures, so that they show where they lie on a proposed run (at 0 laps).
fn series_style(r: &RunRecord, c: RGBColor) -> ShapeStyle {
    c.stroke_width(if r.is_baseline() { 3 } else { 2 })
}

fn label(r: &RunRecord) -> String {
    format!("{} (λ = {})", r.name, r.lambda)
}

fn laps(path: &Path, runs: &[RunRecord]) -> Drawn {
    cabc_outputs::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_v = max_version(runs);
        let eval_laps = runs.iter().map(|r| r.eval_laps).max().unwrap_or(50);
        let mut chart = cabc_outputs::plots::laps_chart(
            root,
            "Completed laps at evaluation, per policy version",
            max_v,
            eval_laps,
        )?;
        // Baselines last, on top: at 0 laps they would hide under the proposed runs' early versions.
        let order = (0..runs.len()).filter(|&i| !runs[i].is_baseline());
        for i in order.chain((0..runs.len()).filter(|&i| runs[i].is_baseline())) {
            let (r, c) = (&runs[i], colour(runs, i));
            let style = series_style(r, c);
            chart
                .draw_series(LineSeries::new(
                    r.evals.iter().map(|e| (e.version, e.laps)),
                    style,
                ))?
                .label(label(r))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
            if r.is_baseline() {
                chart.draw_series(
                    r.evals
                        .iter()
                        .filter(|e| e.version % 5 == 0)
                        .map(|e| Circle::new((e.version, e.laps), 3, c.filled())),
                )?;
            }
        }
        cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    })
}

fn imitation(path: &Path, runs: &[RunRecord]) -> Drawn {
    cabc_outputs::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let values = runs.iter().flat_map(|r| r.imitation.iter().map(|p| p.1));
        let (lo, hi) = values.fold((f64::INFINITY, 0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
        let (lo, hi) = if hi > 0.0 {
            (lo * 0.5, hi * 2.0)
        } else {
            (1e-4, 1.0)
        };
        let max_e = runs.iter().map(|r| r.epochs).max().unwrap_or(1).max(1);
        let mut chart =
            cabc_outputs::plots::chart(root, "Imitation loss per epoch (o: early stop)", 60)
                .build_cartesian_2d(0u64..max_e, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("epoch")
            .y_desc("L_clone")
            .y_label_formatter(&|v| format!("{v:.1e}"))
            .draw()?;
        for (i, r) in runs.iter().enumerate() {
            let c = colour(runs, i);
            chart
                .draw_series(LineSeries::new(
                    r.imitation.iter().copied(),
                    c.stroke_width(2),
                ))?
                .label(label(r))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c.stroke_width(2)));
            let stop = r
                .early_stop
                .and_then(|v| r.imitation.iter().find(|p| p.0 == v));
            chart.draw_series(stop.map(|&(e, v)| Circle::new((e, v), 7, c.stroke_width(3))))?;
        }
        cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

fn lap_times(path: &Path, runs: &[RunRecord]) -> Drawn {
    cabc_outputs::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_v = max_version(runs);
        let hi = runs
            .iter()
            .flat_map(|r| {
                r.full()
                    .filter_map(|e| Some(e.lap_mean? + e.lap_std.unwrap_or(0.0)))
            })
            .chain(
                runs.iter()
                    .filter_map(|r| r.expert_lap_time.map(|(m, s)| m + s)),
            )
            .fold(1.0, f64::max);
        let caption = "Lap time of the full evaluations: mean ± std";
        let mut chart = cabc_outputs::plots::lap_time_chart(root, caption, max_v, hi)?;
        for (i, r) in runs.iter().enumerate() {
            let c = colour(runs, i);
            chart
                .draw_series(r.full().filter_map(|e| {
                    let (m, s) = (e.lap_mean?, e.lap_std.unwrap_or(0.0));
                    Some(ErrorBar::new_vertical(
                        e.version as f64,
                        m - s,
                        m,
                        m + s,
                        c.filled(),
                        6,
                    ))
                }))?
                .label(label(r))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
        }
        if let Some((m, s)) = runs.iter().find_map(|r| r.expert_lap_time) {
            let label = format!("expert {m:.2} ± {s:.2} s");
            cabc_outputs::plots::expert_band(&mut chart, (m, s), (max_v + 1) as f64, label)?;
        }
        cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

/// The running median of each run's evaluation steps over `STEPS_WINDOW` versions, on a log axis: policies that
/// never complete a lap still differ in how long they stay on the track.
fn steps(path: &Path, runs: &[RunRecord]) -> Drawn {
    const STEPS_WINDOW: usize = 9;
    cabc_outputs::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_v = max_version(runs);
        let series: Vec<Vec<(u64, f64)>> = runs
            .iter()
            .map(|r| {
                let points: Vec<(u64, f64)> = r
                    .evals
                    .iter()
                    .filter_map(|e| Some((e.version, e.steps? as f64)))
                    .collect();
                (0..points.len())
                    .filter_map(|i| {
                        let window = &points[i.saturating_sub(STEPS_WINDOW - 1)..=i];
                        let values: Vec<f64> = window.iter().map(|p| p.1.max(1.0)).collect();
                        Some((points[i].0, crate::stats::median(&values)?))
                    })
                    .collect()
            })
            .collect();
        let values = series.iter().flatten().map(|p| p.1);
        let (lo, hi) = values.fold((f64::INFINITY, 1f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
        // Room above the lines for the legend.
        let (lo, hi) = (lo.min(hi) / 1.3, hi * 4.0);
        let caption = format!("Evaluation steps on the track (median of {STEPS_WINDOW} versions)");
        let mut chart = cabc_outputs::plots::chart(root, &caption, 60)
            .build_cartesian_2d(0u64..max_v + 1, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("policy version (epoch)")
            .y_desc("steps")
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        for (i, (r, points)) in runs.iter().zip(&series).enumerate() {
            let style = series_style(r, colour(runs, i));
            chart
                .draw_series(LineSeries::new(points.iter().copied(), style))?
                .label(label(r))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
        }
        cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    })
}

/// Per epoch, the share of the collected steps that belonged to an episode which failed, over the last
/// `CRASHED_WINDOW` epochs ([`RunRecord::crashed_share`]'s numbers): how much of the training-time driving ended in
/// a violation. Runs without the columns draw no line.
fn crashed(path: &Path, runs: &[RunRecord]) -> Drawn {
    const CRASHED_WINDOW: usize = 9;
    cabc_outputs::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_e = runs
            .iter()
            .map(|r| r.collection.len() as u64)
            .max()
            .unwrap_or(1)
            .max(1);
        let caption =
            format!("Collected steps in failed episodes, % (over {CRASHED_WINDOW} epochs)");
        // Many runs: one legend entry per method, not one per run over the lines.
        let compact = runs.len() > 10;
        // Room above 100 % for the legend.
        let top = if compact { 115.0 } else { 140.0 };
        let mut chart = cabc_outputs::plots::chart(root, &caption, 60)
            .build_cartesian_2d(0u64..max_e, 0f64..top)?;
        chart
            .configure_mesh()
            .x_desc("epoch")
            .y_desc("% of the steps collected")
            .y_label_formatter(&|v| match *v {
                v if v <= 100.0 => format!("{v:.0}"),
                _ => String::new(),
            })
            .draw()?;
        for (i, r) in runs.iter().enumerate() {
            let points = (0..r.collection.len()).filter_map(|e| {
                let share = r.crashed_share_over(e.saturating_sub(CRASHED_WINDOW - 1)..e + 1)?;
                Some((e as u64, 100.0 * share))
            });
            let style = series_style(r, colour(runs, i));
            let drawn = chart.draw_series(LineSeries::new(points, style))?;
            let first_of_method = !runs[..i].iter().any(|o| o.is_baseline() == r.is_baseline());
            if !compact || first_of_method {
                let text = match (compact, r.is_baseline()) {
                    (false, _) => label(r),
                    (true, true) => format!("baselines (λ = {}), a shade per seed", r.lambda),
                    (true, false) => format!("proposed (λ = {}), a shade per seed", r.lambda),
                };
                drawn
                    .label(text)
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
            }
        }
        cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    })
}
