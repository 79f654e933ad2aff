//! A top-down picture of a track: centreline, constraint boundary (±H), Frenet band (±(H + slack)), start
//! line, and optionally a driven line. A tiny rasteriser into an [`Frame`]; no plotting crate.

use crate::camera::Frame;
use crate::track::Track;

const BACKGROUND: [u8; 3] = [250, 250, 250];
const BAND_FILL: [u8; 3] = [252, 228, 200];
const ROAD_FILL: [u8; 3] = [210, 210, 214];
const CENTRELINE: [u8; 3] = [90, 90, 90];
const CONSTRAINT: [u8; 3] = [200, 30, 30];
const BAND_EDGE: [u8; 3] = [240, 140, 40];
const START_LINE: [u8; 3] = [0, 0, 0];
const TRACE: [u8; 3] = [20, 70, 220];

/// Maps world metres to pixels (y up in the world, down in the image).
#[derive(Clone, Copy, Debug)]
struct View {
    x0: f64,
    y1: f64,
    px_per_m: f64,
}

impl View {
    fn to_px(self, x: f64, y: f64) -> (f64, f64) {
        ((x - self.x0) * self.px_per_m, (self.y1 - y) * self.px_per_m)
    }
}

/// Render the track at `px_per_m` pixels per metre with the optional driven line `trace` of (X, Y) points.
pub fn render_track(track: &Track, px_per_m: f64, trace: &[(f64, f64)]) -> Frame {
    let px_per_m = if px_per_m.is_finite() {
        px_per_m.clamp(10.0, 1000.0)
    } else {
        100.0
    };
    let (bx0, by0, bx1, by1) = track.centreline_bounds();
    let margin = track.band() + 0.3;
    let view = View {
        x0: bx0 - margin,
        y1: by1 + margin,
        px_per_m,
    };
    let width = ((bx1 - bx0 + 2.0 * margin) * px_per_m).ceil() as usize;
    let height = ((by1 - by0 + 2.0 * margin) * px_per_m).ceil() as usize;
    let mut img = Frame::new(width, height);
    let (h, band) = (track.half_width(), track.band());
    let line = 0.8 / px_per_m; // half line width, m
                               // Rows from the bottom (y0 up), as the field holds them; the image's row j is the field's row height-1-j.
    let res = 1.0 / px_per_m;
    let y0 = view.y1 - height as f64 * res;
    let field = track.distance_field(view.x0, y0, res, width, height, f64::INFINITY);
    for j in 0..height {
        for i in 0..width {
            let d = field[(height - 1 - j) * width + i] as f64;
            let c = if d < line {
                CENTRELINE
            } else if (d - h).abs() < line {
                CONSTRAINT
            } else if (d - band).abs() < line {
                BAND_EDGE
            } else if d < h {
                ROAD_FILL
            } else if d < band {
                BAND_FILL
            } else {
                BACKGROUND
            };
            img.set(i, j, c);
        }
    }
    let [a, b] = track.start_line();
    draw_line(
        &mut img,
        view.to_px(a.0, a.1),
        view.to_px(b.0, b.1),
        START_LINE,
    );
    for w in trace.windows(2) {
        draw_line(
            &mut img,
            view.to_px(w[0].0, w[0].1),
            view.to_px(w[1].0, w[1].1),
            TRACE,
        );
    }
    img
}

/// A one-pixel line by uniform sampling (clipped to the image).
fn draw_line(img: &mut Frame, p: (f64, f64), q: (f64, f64), c: [u8; 3]) {
    let n = ((q.0 - p.0).abs().max((q.1 - p.1).abs()).ceil() as usize).clamp(1, 100_000);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (p.0 + (q.0 - p.0) * t, p.1 + (q.1 - p.1) * t);
        if x >= 0.0 && y >= 0.0 && (x as usize) < img.width && (y as usize) < img.height {
            img.set(x as usize, y as usize, c);
        }
    }
}
