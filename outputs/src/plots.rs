//! The run's plots (PNG, refreshed after every epoch): completed evaluation laps per policy version, imitation and
//! safety loss per epoch, lap-time mean and spread against the expert's ([`draw_tables`]: from what the run folder's
//! tables keep, so that `cabc plots` redraws them for a kept run folder, [`crate::redraw`]), and the last evaluated
//! line on the track (from the evaluation's report).

use cabc_learning::evaluations::EvalSummary;
use cabc_learning::record::Record;
use cabc_learning::sink::History;
use cabc_proto::messages::EvalReport;
use cabc_sim::track::Track;
use plotters::coord::types::{RangedCoordf64, RangedCoordu32, RangedCoordu64};
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

type PlotResult = Result<(), Box<dyn std::error::Error>>;

/// A chart on `root` in the figures' one style: `caption` at 22 px, a 12 px margin, 40 px for the x labels and
/// `y_label_px` for the y labels.
pub fn chart<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    caption: &str,
    y_label_px: u32,
) -> ChartBuilder<'a, 'static, BitMapBackend<'b>> {
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(caption, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(y_label_px);
    builder
}

/// The series' legend of a chart in the figures' one style (a black border, white behind), at `position`.
pub fn legend<'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, CT>,
    position: SeriesLabelPosition,
) -> PlotResult {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.filled())
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// A chart drawn into memory by `draw`, then written to `path` as an RGB PNG with the `png` crate: the one place that
/// writes the run's figures (plotters' own file encoder would pull in the `image` crate, ~11 s of a cold build).
pub fn png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> PlotResult,
) -> PlotResult {
    let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        draw(&root)?;
        root.present()?;
    }
    let file = std::io::BufWriter::new(
        std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?,
    );
    let mut encoder = png::Encoder::new(file, size.0, size.1);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // Per-row adaptive filters, as plotters' encoder had: a chart's flat areas then compress 3-4x better.
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(&rgb)?;
    writer.finish()?;
    Ok(())
}

const SIZE: (u32, u32) = (900, 500);

/// The plots drawn from a run's tables and summary alone ([`draw_tables`]), by file name: laps per version, the
/// losses, lap times against the expert's.
pub const TABLE_PLOTS: [&str; 3] = ["laps.png", "losses.png", "lap_times.png"];

/// The plot of the last evaluated line on the track: drawn from the evaluation's report (its line), which no table
/// keeps.
pub const LINE_PLOT: &str = "line.png";

/// The expert's lap time as the lap-time plot draws it: mean and standard deviation over `laps` laps (the run's
/// `summary.json` keeps it as `expert_lap_time`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExpertLaps {
    pub mean: f64,
    pub std: f64,
    pub laps: usize,
}

impl ExpertLaps {
    /// Over the expert's lap times; None without any.
    pub fn of(lap_times: &[f64]) -> Option<Self> {
        cabc_proto::stats::mean_std(lap_times).map(|(mean, std)| ExpertLaps {
            mean,
            std,
            laps: lap_times.len(),
        })
    }
}

/// Draws every plot into `dir`, the last evaluated line on `track`. Errors are returned, not fatal: a run goes on
/// without a picture.
pub fn draw_all(dir: &Path, run: &History, eval_laps: u32, track: &Track) -> PlotResult {
    let expert = ExpertLaps::of(&run.expert_lap_times);
    draw_tables(dir, &run.rows, &run.evals, expert, eval_laps)?;
    if let Some(report) = &run.last_eval {
        line(&dir.join(LINE_PLOT), track, report)?;
    }
    Ok(())
}

/// Draws the plots of [`TABLE_PLOTS`] into `dir`, from what `metrics.csv`, `evals.csv` and `summary.json` keep: the
/// epochs' records, the evaluations, the expert's lap time (None: no expert band) and `collection.eval_laps`. The
/// live run's ([`draw_all`]) and a kept run folder's (`cabc plots`, [`crate::redraw`]).
pub fn draw_tables(
    dir: &Path,
    rows: &[Record],
    evals: &[EvalSummary],
    expert: Option<ExpertLaps>,
    eval_laps: u32,
) -> PlotResult {
    let [laps_png, losses_png, lap_times_png] = TABLE_PLOTS;
    laps(&dir.join(laps_png), evals, eval_laps)?;
    losses(&dir.join(losses_png), rows)?;
    lap_times(&dir.join(lap_times_png), evals, expert)?;
    Ok(())
}

fn laps(path: &Path, evals: &[EvalSummary], eval_laps: u32) -> PlotResult {
    crate::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_v = evals.iter().map(|e| e.version).max().unwrap_or(1).max(1);
        let mut chart = laps_chart(
            root,
            "Completed laps at evaluation (fixed spawn, policy alone)",
            max_v,
            eval_laps,
        )?;
        chart.draw_series(evals.iter().map(|e| {
            let colour = if e.laps >= eval_laps { GREEN } else { BLUE };
            Rectangle::new(
                [(e.version, 0), (e.version + 1, e.laps)],
                colour.mix(0.7).filled(),
            )
        }))?;
        chart
            .draw_series(LineSeries::new(
                [(0, eval_laps), (max_v + 1, eval_laps)],
                RED.stroke_width(2),
            ))?
            .label(format!("{eval_laps} laps (early stop)"))
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
        legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

fn losses(path: &Path, rows: &[Record]) -> PlotResult {
    crate::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let max_e = rows.iter().map(Record::epoch).max().unwrap_or(1).max(1);
        let positive = |v: f64| {
            if v.is_finite() && v > 0.0 {
                Some(v)
            } else {
                None
            }
        };
        // The records' metrics drawn, by name.
        let series = [
            ("imitation (L_clone)", BLUE, "imitation_loss"),
            ("safety (L_safety)", RED, "safety_loss"),
        ];
        let values: Vec<f64> = rows
            .iter()
            .flat_map(|r| series.map(|(_, _, name)| r.f64(name)))
            .flatten()
            .filter_map(positive)
            .collect();
        let lo = values
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
            .min(1e-3);
        let hi = values.iter().copied().fold(0.0, f64::max).max(1e-2);
        let mut chart = chart(root, "Training losses per epoch", 60)
            .build_cartesian_2d(0u64..max_e + 1, (lo * 0.5..hi * 2.0).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("epoch")
            .y_desc("loss")
            .draw()?;
        for (label, colour, name) in series {
            let points: Vec<(u64, f64)> = rows
                .iter()
                .filter_map(|r| positive(r.f64(name)?).map(|v| (r.epoch(), v)))
                .collect();
            chart
                .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
                .label(label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour));
        }
        legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

fn lap_times(path: &Path, evals: &[EvalSummary], expert: Option<ExpertLaps>) -> PlotResult {
    crate::plots::png(path, SIZE, |root| {
        root.fill(&WHITE)?;
        let with_laps: Vec<&EvalSummary> = evals.iter().filter(|e| e.lap_mean.is_some()).collect();
        let max_v = evals.iter().map(|e| e.version).max().unwrap_or(1).max(1);
        let hi = with_laps
            .iter()
            .filter_map(|e| e.lap_max)
            .chain(expert.map(|e| e.mean + e.std))
            .fold(1.0, f64::max);
        let caption = "Lap time at evaluation: mean ± std, min–max";
        let mut chart = lap_time_chart(root, caption, max_v, hi)?;
        chart.draw_series(with_laps.iter().filter_map(|e| {
            let (lo, hi) = (e.lap_min?, e.lap_max?);
            let x = e.version as f64;
            Some(PathElement::new([(x, lo), (x, hi)], BLUE.mix(0.4)))
        }))?;
        chart
            .draw_series(with_laps.iter().filter_map(|e| {
                let (m, s) = (e.lap_mean?, e.lap_std?);
                Some(ErrorBar::new_vertical(
                    e.version as f64,
                    m - s,
                    m,
                    m + s,
                    BLUE.filled(),
                    6,
                ))
            }))?
            .label("policy")
            .legend(|(x, y)| Circle::new((x + 10, y), 4, BLUE.filled()));
        if let Some(ExpertLaps { mean, std, laps }) = expert {
            let label = format!("expert {mean:.2} ± {std:.2} s ({laps} laps)");
            expert_band(&mut chart, (mean, std), (max_v + 1) as f64, label)?;
        }
        legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

/// The lap-time charts' frame (the run's and `cabc compare`'s): policy versions 0..=`max_v` across, lap times
/// from 0 to 15 % over `hi` up, the mesh drawn.
pub fn lap_time_chart<'b, 'c>(
    root: &DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    caption: &str,
    max_v: u64,
    hi: f64,
) -> Result<
    ChartContext<'c, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    Box<dyn std::error::Error>,
> {
    let mut chart =
        chart(root, caption, 50).build_cartesian_2d(0f64..(max_v + 1) as f64, 0f64..hi * 1.15)?;
    chart
        .configure_mesh()
        .x_desc("policy version (epoch)")
        .y_desc("lap time (s)")
        .draw()?;
    Ok(chart)
}

/// The laps charts' frame (the run's and `cabc compare`'s): policy versions 0..=`max_v` across, 0 to
/// `eval_laps` + 2 laps up, the mesh drawn.
pub fn laps_chart<'b, 'c>(
    root: &DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    caption: &str,
    max_v: u64,
    eval_laps: u32,
) -> Result<
    ChartContext<'c, BitMapBackend<'b>, Cartesian2d<RangedCoordu64, RangedCoordu32>>,
    Box<dyn std::error::Error>,
> {
    let mut chart =
        chart(root, caption, 50).build_cartesian_2d(0u64..max_v + 1, 0u32..eval_laps + 2)?;
    chart
        .configure_mesh()
        .x_desc("policy version (epoch)")
        .y_desc("laps")
        .draw()?;
    Ok(chart)
}

/// The expert's lap time on a lap-time chart: its mean as a line over [0, `x1`], mean ± std as a band.
pub fn expert_band(
    chart: &mut ChartContext<'_, BitMapBackend<'_>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    (m, s): (f64, f64),
    x1: f64,
    label: String,
) -> PlotResult {
    chart.draw_series([Rectangle::new(
        [(0.0, m - s), (x1, m + s)],
        GREEN.mix(0.15).filled(),
    )])?;
    chart
        .draw_series(LineSeries::new([(0.0, m), (x1, m)], GREEN.stroke_width(2)))?
        .label(label)
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], GREEN));
    Ok(())
}

/// The track's centre line and its two edges as (X, Y) points, `n` + 1 each: for the track map and the videos.
pub fn track_edges(track: &Track, n: usize) -> [Vec<(f64, f64)>; 3] {
    let edge = |e: f64| -> Vec<(f64, f64)> {
        (0..=n)
            .map(|i| {
                let p = track.local_to_global(track.length() * i as f64 / n as f64, e, 0.0);
                (p.x, p.y)
            })
            .collect()
    };
    let half = track.half_width();
    [edge(0.0), edge(half), edge(-half)]
}

/// The X and Y ranges that show `lines` (a track's edges) with a 0.5 m margin on a drawing of `pixels`, the shorter
/// side widened so that a metre is as long on both axes.
pub fn view_of(lines: &[&[(f64, f64)]], pixels: (u32, u32)) -> (Range<f64>, Range<f64>) {
    let points = lines.iter().flat_map(|l| l.iter());
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in points {
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
        return (-1.0..1.0, -1.0..1.0);
    }
    let aspect = f64::from(pixels.0.max(1)) / f64::from(pixels.1.max(1));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (mut hx, mut hy) = (0.5 * (x1 - x0) + 0.5, 0.5 * (y1 - y0) + 0.5);
    if hx / hy < aspect {
        hx = hy * aspect;
    } else {
        hy = hx / aspect;
    }
    (cx - hx..cx + hx, cy - hy..cy + hy)
}

/// A chart of the track map: X and Y in metres over the run's track (`sim.track`) and its band.
pub type TrackMap<'a> =
    ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The track map on `area` under `caption`: its axes, its centre line (grey) and its two edges (black), for what a
/// figure draws on it (the evaluated line, the robustness study's spawns).
pub fn track_map<'a>(
    area: &DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>,
    track: &Track,
    caption: &str,
) -> Result<TrackMap<'a>, Box<dyn std::error::Error>> {
    let [centre, left, right] = track_edges(track, 400.max((track.length() / 0.1) as usize));
    let (xs, ys) = view_of(&[&centre, &left, &right], area.dim_in_pixel());
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(30)
        .y_label_area_size(40)
        .build_cartesian_2d(xs, ys)?;
    chart
        .configure_mesh()
        .x_desc("X (m)")
        .y_desc("Y (m)")
        .draw()?;
    chart.draw_series(LineSeries::new(centre, BLACK.mix(0.3)))?;
    for edge in [left, right] {
        chart.draw_series(LineSeries::new(edge, BLACK.stroke_width(2)))?;
    }
    Ok(chart)
}

fn line(path: &Path, track: &Track, report: &EvalReport) -> PlotResult {
    crate::plots::png(path, (760, 700), |root| {
        root.fill(&WHITE)?;
        let caption = format!(
            "Evaluation of policy {}: {} laps, ended by {}",
            report.version, report.laps, report.end_reason
        );
        let mut chart = track_map(root, track, &caption)?;
        chart
            .draw_series(LineSeries::new(
                report.line.iter().map(|p| (p[0] as f64, p[1] as f64)),
                RED.stroke_width(2),
            ))?
            .label("driven line")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
        legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::EndReason;

    #[test]
    fn plots_are_drawn() {
        let dir = tempfile::tempdir().unwrap();
        let report = EvalReport {
            actor: "e".into(),
            version: 1,
            laps: 1,
            lap_times: vec![5.1],
            end_reason: EndReason::OutOfTrack,
            steps: 60,
            line: (0..60).map(|i| [i as f32 * 0.05, 0.0]).collect(),
            spawn_episodes: 0,
            spawn_crashes: 0,
        };
        let run = History {
            rows: (0..3)
                .map(|e| {
                    let mut r = Record::new(e);
                    r.real("imitation_loss", 1.0 / (e + 1) as f64, 6)
                        .real("safety_loss", 0.3, 6);
                    r
                })
                .collect(),
            expert_lap_times: vec![4.8, 4.9],
            evals: vec![EvalSummary::of(&report)],
            last_eval: Some(report),
        };
        draw_all(dir.path(), &run, 50, &Track::l_track_barc()).unwrap();
        for f in TABLE_PLOTS.iter().chain([&LINE_PLOT]) {
            let len = std::fs::metadata(dir.path().join(f)).unwrap().len();
            assert!(len > 1000, "{f} is {len} bytes");
        }
    }

    #[test]
    fn png_writes_what_was_drawn() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chart.png");
        png(&path, (40, 30), |root| {
            root.fill(&WHITE)?;
            root.draw(&Rectangle::new([(0, 0), (9, 9)], RED.filled()))?;
            Ok(())
        })
        .unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut rgb = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut rgb).unwrap();
        assert_eq!(
            (info.width, info.height, info.color_type),
            (40, 30, png::ColorType::Rgb)
        );
        assert_eq!(&rgb[..3], &[255, 0, 0], "the rectangle's corner");
        let last = (30 * 40 - 1) * 3;
        assert_eq!(&rgb[last..last + 3], &[255, 255, 255], "the white fill");
        assert!(png(&dir.path().join("no/such/dir.png"), (4, 4), |_| Ok(())).is_err());
    }
}
