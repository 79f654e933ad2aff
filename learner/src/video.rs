//! Evaluation videos: an animated GIF of an evaluation's driven line, the track from above with the car and its
//! trail, drawn frame by frame with plotters into a pixel buffer and encoded with the `gif` crate. The learner writes
//! one for every evaluation that completes its laps (`plots/eval-v<version>.gif`).

use cabc_proto::messages::EvalReport;
use cabc_sim::track::Track;
use plotters::prelude::*;
use std::path::Path;

/// Frames of a video (the trail grows by 1/FRAMES of the line each frame).
pub const FRAMES: usize = 60;
const SIZE: (u32, u32) = (380, 350);
/// Hundredths of a second a frame stays on screen.
const DELAY: u16 = 8;

type Drawn = Result<(), Box<dyn std::error::Error>>;

/// One frame: the track, the trail of the first `upto` points of the line, the car at the last of them.
fn frame(buf: &mut [u8], edges: &[Vec<(f64, f64)>; 3], line: &[(f64, f64)], title: &str) -> Drawn {
    let root = BitMapBackend::with_buffer(buf, SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 14))
        .margin(6)
        .build_cartesian_2d(-3.2..4.4, -1.2..5.8)?;
    chart.draw_series(LineSeries::new(edges[0].iter().copied(), BLACK.mix(0.3)))?;
    for e in &edges[1..] {
        chart.draw_series(LineSeries::new(e.iter().copied(), BLACK.stroke_width(2)))?;
    }
    chart.draw_series(LineSeries::new(line.iter().copied(), RED.stroke_width(2)))?;
    if let Some(&car) = line.last() {
        chart.draw_series(std::iter::once(Circle::new(car, 5, BLUE.filled())))?;
    }
    root.present()?;
    Ok(())
}

/// Writes the GIF of `report`'s driven line to `path`: [`FRAMES`] frames of 380x350.
pub fn eval_gif(path: &Path, report: &EvalReport) -> Drawn {
    let track = Track::l_track_barc();
    let edges = crate::plots::track_edges(&track, 300);
    let line: Vec<(f64, f64)> = report
        .line
        .iter()
        .map(|p| (p[0] as f64, p[1] as f64))
        .collect();
    let file = std::fs::File::create(path)?;
    let (w, h) = (SIZE.0 as u16, SIZE.1 as u16);
    let mut encoder = gif::Encoder::new(std::io::BufWriter::new(file), w, h, &[])?;
    encoder.set_repeat(gif::Repeat::Infinite)?;
    let mut buf = vec![0u8; SIZE.0 as usize * SIZE.1 as usize * 3];
    for k in 1..=FRAMES {
        let upto = (line.len() * k).div_ceil(FRAMES);
        let title = format!(
            "policy {}: {} laps, ended by {}",
            report.version, report.laps, report.end_reason
        );
        frame(&mut buf, &edges, &line[..upto], &title)?;
        let mut f = gif::Frame::from_rgb_speed(w, h, &buf, 10);
        f.delay = DELAY;
        encoder.write_frame(&f)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::EndReason;

    #[test]
    fn a_video_decodes_with_its_frames() {
        let dir = tempfile::tempdir().unwrap();
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
        let report = EvalReport {
            actor: "e".into(),
            version: 7,
            laps: 2,
            lap_times: vec![5.0, 5.0],
            end_reason: EndReason::MaxLaps,
            steps: 100,
            line,
        };
        let path = dir.path().join("v.gif");
        eval_gif(&path, &report).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.len() < 3 << 20, "{} bytes", bytes.len());
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options.read_info(bytes.as_slice()).unwrap();
        assert_eq!((decoder.width(), decoder.height()), (380, 350));
        let mut frames = 0;
        let mut last = Vec::new();
        while let Some(f) = decoder.read_next_frame().unwrap() {
            frames += 1;
            last = f.buffer.to_vec();
        }
        assert_eq!(frames, FRAMES);
        // The last frame shows the trail: red pixels.
        let red = last
            .chunks_exact(4)
            .filter(|p| p[0] > 200 && p[1] < 80 && p[2] < 80)
            .count();
        assert!(red > 200, "{red} red pixels");
    }
}
