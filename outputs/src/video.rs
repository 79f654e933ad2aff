//! Evaluation videos: an animated GIF of an evaluation, the track from above with the car and its trail, and for a
//! camera run the camera's view beside it, drawn frame by frame with plotters into a pixel buffer and encoded with
//! the `gif` crate.
//!
//! The learner writes one for every evaluation that completes its laps (`plots/eval-v<version>.gif`) from the
//! report alone: its line is the car's positions, the car's heading is the line's direction there
//! ([`poses_of_line`]), and the camera's view is lit by the default sun (a report does not carry the evaluation's).
//! `cabc video` and `cabc show RUN --gif` evaluate a policy anew and draw the car's own poses under the
//! evaluation's sun ([`Watched`], [`gif`]). Either way the view is rendered without the sensor's pixel noise.

use cabc_proto::config::{ObservationKind, ObservationSection, RunConfig};
use cabc_proto::messages::EvalReport;
use cabc_sim::camera::{Camera, Sun, TrackLookup};
use cabc_sim::env::Env;
use cabc_sim::track::{Pose, Track};
use plotters::prelude::*;
use std::path::Path;

/// Frames of a video (the trail grows by 1/FRAMES of the line each frame).
pub const FRAMES: usize = 60;
/// The track panel, pixels.
const TRACK: (u32, u32) = (380, 350);
/// The camera panel's width (its height is the track panel's): the view scaled to fit below its caption.
const VIEW: u32 = 350;
const CAPTION: u32 = 24;
/// Hundredths of a second a frame stays on screen.
const DELAY: u16 = 8;
/// The camera's distance grid, m (as the actors': `cabc_actor::eyes`).
const LOOKUP_RESOLUTION: f64 = 0.01;

type Drawn = Result<(), Box<dyn std::error::Error>>;

/// An episode driven anew, as its video needs it: the car's pose before every step and the sun of the episode's
/// camera. [`Watched::watch`] is the `watch` of the evaluator's `evaluate_watched`; [`Watched::gif`] draws the
/// video once the episode is over.
#[derive(Debug, Default)]
pub struct Watched {
    poses: Vec<Pose>,
    sun: Option<Sun>,
}

impl Watched {
    /// Records the environment before a step.
    pub fn watch(&mut self, env: &Env) {
        let [x, y, psi] = env.observation().pose;
        self.poses.push(Pose { x, y, psi });
        self.sun.get_or_insert(env.sun());
    }

    /// The episode's video at `path` (`report` its evaluation, `config` its run's): the car's recorded poses on the
    /// run's track and, in a camera run, the camera's view under the episode's sun.
    pub fn gif(&self, path: &Path, config: &RunConfig, report: &EvalReport) -> Drawn {
        let track = Track::of(&config.sim)?;
        let mut view = CameraView::of(&config.observation, &track).map(|v| match self.sun {
            Some(sun) => v.under(sun),
            None => v,
        });
        gif(path, track.as_ref(), report, &self.poses, view.as_mut())
    }
}

/// A camera run's camera, to draw its view beside the track: the run's image size and field of view, the track's
/// distance grid and a sun.
pub struct CameraView {
    camera: Camera,
    lookup: TrackLookup,
    sun: Sun,
}

impl CameraView {
    /// The camera of a run's observation section on `track` (the run's `sim.track`) under the default sun; None for a
    /// full-state run.
    pub fn of(observation: &ObservationSection, track: &Track) -> Option<Self> {
        (observation.kind == ObservationKind::Camera).then(|| CameraView {
            camera: Camera::new(
                observation.width as usize,
                observation.height as usize,
                observation.fov_deg,
            ),
            lookup: TrackLookup::new(track, LOOKUP_RESOLUTION),
            sun: Sun::default(),
        })
    }

    /// The same camera under `sun` (the evaluation's).
    pub fn under(self, sun: Sun) -> Self {
        CameraView { sun, ..self }
    }

    /// Renders the view from `pose` into `buf` (`width` pixels a row, RGB) at `(x0, y0)`, scaled to fit a
    /// `side` x `side` square, centred.
    fn blit(
        &mut self,
        pose: Pose,
        buf: &mut [u8],
        width: usize,
        (x0, y0): (usize, usize),
        side: usize,
    ) {
        let frame = self.camera.render(&self.lookup, pose, self.sun);
        let scale = (side as f64 / frame.width as f64).min(side as f64 / frame.height as f64);
        let (w, h) = (
            (frame.width as f64 * scale) as usize,
            (frame.height as f64 * scale) as usize,
        );
        let (x0, y0) = (x0 + (side - w) / 2, y0 + (side - h) / 2);
        for y in 0..h {
            let sy = ((y as f64 / scale) as usize).min(frame.height - 1);
            for x in 0..w {
                let sx = ((x as f64 / scale) as usize).min(frame.width - 1);
                let i = ((y0 + y) * width + x0 + x) * 3;
                if let Some(px) = buf.get_mut(i..i + 3) {
                    px.copy_from_slice(&frame.pixel(sx, sy));
                }
            }
        }
    }
}

/// The car's poses along `line` ([X, Y] per point), each heading along the line's direction there (from the point
/// before to the point after); where the car did not move it keeps the heading before.
pub fn poses_of_line(line: &[[f32; 2]]) -> Vec<Pose> {
    let mut psi = 0.0;
    (0..line.len())
        .map(|i| {
            let (a, b) = (line[i.saturating_sub(1)], line[(i + 1).min(line.len() - 1)]);
            let (dx, dy) = ((b[0] - a[0]) as f64, (b[1] - a[1]) as f64);
            if dx.hypot(dy) > 1e-9 {
                psi = dy.atan2(dx);
            }
            Pose {
                x: line[i][0] as f64,
                y: line[i][1] as f64,
                psi,
            }
        })
        .collect()
}

/// Writes the GIF of `report` on `track` from its line alone (see the module doc): [`FRAMES`] frames of 380x350,
/// 730x350 with a camera `view`.
pub fn eval_gif(
    path: &Path,
    track: &Track,
    report: &EvalReport,
    view: Option<&mut CameraView>,
) -> Drawn {
    gif(path, track, report, &poses_of_line(&report.line), view)
}

/// Writes the GIF of an evaluation on `track` whose car poses are known (`poses`, in order; `report` gives the title
/// and the trail): [`FRAMES`] frames, the car and its view at the pose 1/FRAMES further each frame.
pub fn gif(
    path: &Path,
    track: &Track,
    report: &EvalReport,
    poses: &[Pose],
    mut view: Option<&mut CameraView>,
) -> Drawn {
    let edges = crate::plots::track_edges(track, 300);
    let line: Vec<(f64, f64)> = report
        .line
        .iter()
        .map(|p| (p[0] as f64, p[1] as f64))
        .collect();
    let size = (TRACK.0 + view.as_ref().map_or(0, |_| VIEW), TRACK.1);
    let (w, h) = (u16::try_from(size.0)?, u16::try_from(size.1)?);
    let file = std::fs::File::create(path)?;
    let mut encoder = gif::Encoder::new(std::io::BufWriter::new(file), w, h, &[])?;
    encoder.set_repeat(gif::Repeat::Infinite)?;
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    let title = format!(
        "policy {}: {} laps, ended by {}",
        report.version, report.laps, report.end_reason
    );
    for k in 1..=FRAMES {
        let upto = (line.len() * k).div_ceil(FRAMES);
        let car = (poses.len() * k)
            .div_ceil(FRAMES)
            .checked_sub(1)
            .map(|i| poses[i]);
        frame(
            &mut buf,
            size,
            &edges,
            &line[..upto],
            car,
            &title,
            view.is_some(),
        )?;
        if let (Some(view), Some(car)) = (view.as_mut(), car) {
            let side = (VIEW - CAPTION) as usize;
            view.blit(
                car,
                &mut buf,
                size.0 as usize,
                (TRACK.0 as usize, CAPTION as usize),
                side,
            );
        }
        let mut f = gif::Frame::from_rgb_speed(w, h, &buf, 10);
        f.delay = DELAY;
        encoder.write_frame(&f)?;
    }
    Ok(())
}

/// One frame's drawing: the track, the trail, the car (a dot and its heading); the camera panel's caption.
fn frame(
    buf: &mut [u8],
    size: (u32, u32),
    edges: &[Vec<(f64, f64)>; 3],
    trail: &[(f64, f64)],
    car: Option<Pose>,
    title: &str,
    camera: bool,
) -> Drawn {
    let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(TRACK.0);
    let (xs, ys) = crate::plots::view_of(&[&edges[1], &edges[2]], left.dim_in_pixel());
    let mut chart = ChartBuilder::on(&left)
        .caption(title, ("sans-serif", 14))
        .margin(6)
        .build_cartesian_2d(xs, ys)?;
    chart.draw_series(LineSeries::new(edges[0].iter().copied(), BLACK.mix(0.3)))?;
    for e in &edges[1..] {
        chart.draw_series(LineSeries::new(e.iter().copied(), BLACK.stroke_width(2)))?;
    }
    chart.draw_series(LineSeries::new(trail.iter().copied(), RED.stroke_width(2)))?;
    if let Some(car) = car {
        let ahead = (car.x + 0.35 * car.psi.cos(), car.y + 0.35 * car.psi.sin());
        chart.draw_series(LineSeries::new(
            [(car.x, car.y), ahead],
            BLUE.stroke_width(3),
        ))?;
        chart.draw_series(std::iter::once(Circle::new(
            (car.x, car.y),
            5,
            BLUE.filled(),
        )))?;
    }
    if camera {
        right.draw_text(
            "camera (the policy's view)",
            &("sans-serif", 14).into_text_style(&right),
            (8, 5),
        )?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::config::RunConfig;
    use cabc_proto::messages::EndReason;

    /// Two laps' line along the track, 0.1 m left of the centre line.
    fn report() -> EvalReport {
        let track = Track::l_track_barc();
        let line = (0..500)
            .map(|i| {
                let p = track.local_to_global(
                    track.length() * i as f64 / 250.0 % track.length(),
                    0.1,
                    0.0,
                );
                [p.x as f32, p.y as f32]
            })
            .collect();
        EvalReport {
            actor: "e".into(),
            version: 7,
            laps: 2,
            lap_times: vec![5.0, 5.0],
            end_reason: EndReason::MaxLaps,
            steps: 100,
            line,
            spawn_episodes: 0,
            spawn_crashes: 0,
        }
    }

    /// The GIF's size, frame count and last frame (RGBA); its file under 3 MB.
    fn decode(path: &Path) -> ((u16, u16), usize, Vec<u8>) {
        let bytes = std::fs::read(path).unwrap();
        assert!(bytes.len() < 3 << 20, "{} bytes", bytes.len());
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options.read_info(bytes.as_slice()).unwrap();
        let size = (decoder.width(), decoder.height());
        let mut frames = 0;
        let mut last = Vec::new();
        while let Some(f) = decoder.read_next_frame().unwrap() {
            frames += 1;
            last = f.buffer.to_vec();
        }
        (size, frames, last)
    }

    #[test]
    fn a_video_decodes_with_its_frames() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v.gif");
        eval_gif(&path, &Track::l_track_barc(), &report(), None).unwrap();
        let (size, frames, last) = decode(&path);
        assert_eq!((size, frames), ((380, 350), FRAMES));
        // The last frame shows the trail: red pixels.
        let red = last
            .chunks_exact(4)
            .filter(|p| p[0] > 200 && p[1] < 80 && p[2] < 80)
            .count();
        assert!(red > 200, "{red} red pixels");
    }

    #[test]
    fn a_camera_runs_video_shows_the_view_beside_the_track() {
        let config = RunConfig::load("smoke-camera").unwrap();
        let track = Track::of(&config.sim).unwrap();
        let view = CameraView::of(&config.observation, &track).expect("a camera run");
        let smoke = RunConfig::load("smoke").unwrap();
        assert!(CameraView::of(&smoke.observation, &track).is_none());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera.gif");
        eval_gif(&path, &track, &report(), Some(&mut { view })).unwrap();
        let (size, frames, last) = decode(&path);
        assert_eq!((size, frames), ((380 + 350, 350), FRAMES));
        // The camera panel shows the sky (blue over red) and the road (grey) where a plot would be white.
        let panel: Vec<&[u8]> = last
            .chunks_exact(4)
            .enumerate()
            .filter(|(i, _)| i % 730 >= 380 && i / 730 >= CAPTION as usize)
            .map(|(_, p)| p)
            .collect();
        let sky = panel
            .iter()
            .filter(|p| p[2] > 180 && p[2] > p[0].saturating_add(30))
            .count();
        let road = panel
            .iter()
            .filter(|p| p[0] < 110 && p[0].abs_diff(p[2]) < 20 && p[0].abs_diff(p[1]) < 20)
            .count();
        assert!(
            sky > panel.len() / 10 && road > panel.len() / 20,
            "sky {sky}, road {road} of {}",
            panel.len()
        );
    }

    #[test]
    fn headings_follow_the_line() {
        let line = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0]];
        let psi: Vec<f64> = poses_of_line(&line).iter().map(|p| p.psi).collect();
        let up = std::f64::consts::FRAC_PI_2;
        // Where the car stood (the point before and after alike), the heading before stays.
        assert_eq!(psi, [0.0, 0.0, 0.0, up, up]);
        assert!(poses_of_line(&[]).is_empty());
    }
}
