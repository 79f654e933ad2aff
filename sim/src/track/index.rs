//! Which pieces of a track may hold a point: a grid over the track whose cells list, in order, the pieces whose
//! region (the piece's points within the band) meets the cell. A track of a fitted centre line has thousands of
//! pieces; a point's Frenet coordinates then test the few dozen of its cell instead of every piece, and the first
//! piece in order that holds the point is the same as in a search of all of them.

use super::{Circle, Track};

/// The most cells a grid holds (each a list of pieces).
const MAX_CELLS: f64 = 4e6;

#[derive(Debug)]
pub(super) struct Grid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    /// Per cell (row-major), the 1-based piece indices in ascending order.
    cells: Vec<Vec<u32>>,
}

impl Grid {
    pub(super) fn new(track: &Track) -> Grid {
        let band = track.band();
        let cell = (0.5 * band).max(0.05);
        let reach = band + 1e-6;
        // Each piece's bounding box, from its points (arcs every 0.05 rad) widened by the band.
        let boxes: Vec<(f64, f64, f64, f64)> = (1..track.key.len())
            .map(|i| {
                let (k0, k1) = (track.key[i - 1], track.key[i]);
                let mut b = (
                    k0.x.min(k1.x),
                    k0.y.min(k1.y),
                    k0.x.max(k1.x),
                    k0.y.max(k1.y),
                );
                if k1.curvature != 0.0 {
                    let arc = Circle::of(&k0, k1.curvature);
                    let span = arc.span(k1.len);
                    let n = ((span.abs() / 0.05).ceil() as usize).max(1);
                    let start = arc.normal + std::f64::consts::PI;
                    for j in 0..=n {
                        let a = start + span * j as f64 / n as f64;
                        let (x, y) = (
                            arc.centre.0 + arc.radius * a.cos(),
                            arc.centre.1 + arc.radius * a.sin(),
                        );
                        b = (b.0.min(x), b.1.min(y), b.2.max(x), b.3.max(y));
                    }
                }
                (b.0 - reach, b.1 - reach, b.2 + reach, b.3 + reach)
            })
            .collect();
        let x0 = boxes.iter().map(|b| b.0).fold(f64::INFINITY, f64::min);
        let y0 = boxes.iter().map(|b| b.1).fold(f64::INFINITY, f64::min);
        let x1 = boxes.iter().map(|b| b.2).fold(f64::NEG_INFINITY, f64::max);
        let y1 = boxes.iter().map(|b| b.3).fold(f64::NEG_INFINITY, f64::max);
        // At most MAX_CELLS cells: a larger track gets larger cells (and longer lists in each).
        let cell = cell.max(((x1 - x0) * (y1 - y0) / MAX_CELLS).sqrt());
        let nx = ((x1 - x0) / cell).ceil() as usize + 1;
        let ny = ((y1 - y0) / cell).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); nx * ny];
        for (i, b) in boxes.iter().enumerate() {
            let (ix0, iy0) = (((b.0 - x0) / cell) as usize, ((b.1 - y0) / cell) as usize);
            let (ix1, iy1) = (
                (((b.2 - x0) / cell) as usize).min(nx - 1),
                (((b.3 - y0) / cell) as usize).min(ny - 1),
            );
            for iy in iy0..=iy1 {
                for ix in ix0..=ix1 {
                    cells[iy * nx + ix].push((i + 1) as u32);
                }
            }
        }
        Grid {
            x0,
            y0,
            cell,
            nx,
            ny,
            cells,
        }
    }

    /// The pieces that may hold (x, y), in order; none outside the grid.
    pub(super) fn candidates(&self, x: f64, y: f64) -> &[u32] {
        let (fx, fy) = ((x - self.x0) / self.cell, (y - self.y0) / self.cell);
        if !(fx >= 0.0 && fy >= 0.0) {
            return &[];
        }
        let (ix, iy) = (fx as usize, fy as usize);
        if ix >= self.nx || iy >= self.ny {
            return &[];
        }
        &self.cells[iy * self.nx + ix]
    }
}
