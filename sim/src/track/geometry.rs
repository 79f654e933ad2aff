//! What a track's shape implies beyond its Frenet frame: whether it comes back near itself (a file's check) and the
//! distance to its centre line over a grid (the camera's and the map's field).

use super::{Pose, Track};
use std::f64::consts::PI;

impl Track {
    /// Where the track comes back near itself: two points of the centreline, at least π·band apart along it,
    /// closer than twice the band (their bands would overlap, and a point there would have two Frenet frames), as
    /// their arc lengths; None for a track whose parts keep apart. A curve of radius above the band never brings
    /// two of its own points that close.
    pub fn comes_back_near(&self) -> Option<(f64, f64)> {
        let band = self.band();
        let n = ((self.length / (0.25 * band)).ceil() as usize).max(8);
        let s: Vec<f64> = (0..n).map(|i| self.length * i as f64 / n as f64).collect();
        let p: Vec<Pose> = s
            .iter()
            .map(|&si| self.local_to_global(si, 0.0, 0.0))
            .collect();
        let (apart, near) = (PI * band, 2.0 * band * (1.0 - 1e-9));
        // Samples bucketed by cells of twice the band: a close pair lies in the same or neighbouring cells.
        let cell = 2.0 * band;
        let key = |q: &Pose| ((q.x / cell).floor() as i64, (q.y / cell).floor() as i64);
        let mut buckets: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
        for (i, q) in p.iter().enumerate() {
            buckets.entry(key(q)).or_default().push(i);
        }
        for i in 0..n {
            let (cx, cy) = key(&p[i]);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for &j in buckets.get(&(cx + dx, cy + dy)).map_or(&[][..], |v| &v[..]) {
                        if j <= i {
                            continue;
                        }
                        let along = (s[j] - s[i]).min(self.length - (s[j] - s[i]));
                        if along >= apart && (p[i].x - p[j].x).hypot(p[i].y - p[j].y) < near {
                            return Some((s[i], s[j]));
                        }
                    }
                }
            }
        }
        None
    }

    /// The distance to the centreline at the centres of `nx` x `ny` cells of side `res` from (x0, y0) (row-major,
    /// rows along y), at most `cap`. Exact for a track of a few pieces (the L-track); for one of many pieces, exact
    /// within the band (|x_tran|) and beyond it the band plus the distance to the nearest cell inside, to within
    /// a cell.
    pub fn distance_field(
        &self,
        x0: f64,
        y0: f64,
        res: f64,
        nx: usize,
        ny: usize,
        cap: f64,
    ) -> Vec<f32> {
        use rayon::prelude::*;
        let centre =
            |ix: usize, iy: usize| (x0 + (ix as f64 + 0.5) * res, y0 + (iy as f64 + 0.5) * res);
        if self.index.is_none() {
            let mut dist = Vec::with_capacity(nx * ny);
            for iy in 0..ny {
                for ix in 0..nx {
                    let (x, y) = centre(ix, iy);
                    dist.push(self.distance_to_centreline(x, y).min(cap) as f32);
                }
            }
            return dist;
        }
        let inside: Vec<Option<f64>> = (0..nx * ny)
            .into_par_iter()
            .map(|k| {
                let (x, y) = centre(k % nx, k / nx);
                self.global_to_local(x, y, 0.0).ok().map(|f| f.x_tran.abs())
            })
            .collect();
        let squared: Vec<f64> = inside
            .iter()
            .map(|d| if d.is_some() { 0.0 } else { f64::INFINITY })
            .collect();
        let cells = squared_distance_transform(squared, nx, ny);
        let band = self.band();
        inside
            .iter()
            .zip(&cells)
            .map(|(d, c)| match d {
                Some(d) => d.min(cap) as f32,
                None => (band + (c.sqrt() - 0.5).max(0.0) * res).min(cap) as f32,
            })
            .collect()
    }
}

/// The squared Euclidean distance (in cells) from each cell to the nearest cell of value 0 (Felzenszwalb and
/// Huttenlocher's transform: columns, then rows).
fn squared_distance_transform(mut f: Vec<f64>, nx: usize, ny: usize) -> Vec<f64> {
    let mut line = Vec::new();
    for ix in 0..nx {
        line.clear();
        line.extend((0..ny).map(|iy| f[iy * nx + ix]));
        let out = transform_1d(&line);
        for (iy, v) in out.into_iter().enumerate() {
            f[iy * nx + ix] = v;
        }
    }
    for iy in 0..ny {
        let out = transform_1d(&f[iy * nx..(iy + 1) * nx]);
        f[iy * nx..(iy + 1) * nx].copy_from_slice(&out);
    }
    f
}

/// The 1-D squared distance transform of a sampled function (lower envelope of parabolas).
fn transform_1d(f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let mut d = vec![f64::INFINITY; n];
    let finite: Vec<usize> = (0..n).filter(|&q| f[q].is_finite()).collect();
    if finite.is_empty() {
        return d;
    }
    let (mut v, mut z) = (Vec::with_capacity(n), Vec::with_capacity(n + 1));
    v.push(finite[0]);
    z.push(f64::NEG_INFINITY);
    z.push(f64::INFINITY);
    for &q in &finite[1..] {
        loop {
            let p = v[v.len() - 1];
            let s =
                ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            if s <= z[z.len() - 2] && v.len() > 1 {
                v.pop();
                z.pop();
                continue;
            }
            if s <= z[z.len() - 2] {
                // One parabola left and it is dominated: replace it.
                v[0] = q;
                let last = z.len() - 1;
                z[last] = f64::INFINITY;
                break;
            }
            let last = z.len() - 1;
            z[last] = s;
            v.push(q);
            z.push(f64::INFINITY);
            break;
        }
    }
    let mut k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        *dq = (q as f64 - p as f64).powi(2) + f[p];
    }
    d
}
