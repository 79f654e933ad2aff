//! A deterministic CPU renderer of the first-person camera (simulator.md §4).
//!
//! Scene (the reference's CARLA world, minus CARLA): a road surface 0.15 m wider than the constraint on each side
//! (|x_tran| ≤ 0.70 on the L-track), walls
//! 0.2 m high and [`WALL_THICKNESS`] thick at its edges, a flat ground plane outside and a sky. No road
//! marks, no texture, nothing that localises the car. The camera sits 0.2 m above the CoM at (X, Y, ψ),
//! looks horizontally forward, horizontal FOV (110° in the reference), pinhole, one ray per pixel centre.
//!
//! Deliberate difference from the reference code (which sets no weather): a [`Sun`] drawn per reset
//! changes the Lambertian shading and casts the walls' shadows on the road and ground, as the paper says.
//!
//! How it is fast: a [`TrackLookup`] grid (1 cm) holds the distance to the centreline, built once per
//! track and shared. Because the camera height equals the wall height, every ray below the horizon that
//! meets a wall does so at the first wall crossing of its column's ground projection, so each column is
//! sphere-traced once (the distance field is 1-Lipschitz); each row then compares its ground-hit distance
//! with the column's wall distance. Wall shadows are a short sphere trace from the ground point towards
//! the sun over the horizontal distance in which the sun ray stays below the wall top.

use std::f64::consts::PI;
use std::path::Path;

use cabc_proto::messages::image_bytes;
use rand::Rng;
use rayon::prelude::*;

use crate::track::{Pose, Track};

/// The road as rendered is wider than the constraint by this much on each side (m): 0.70 m on the L-track's 0.55.
pub const ROAD_MARGIN: f64 = 0.15;
/// The most cells a [`TrackLookup`] holds (160 MB); a larger track's grid is coarser.
const LOOKUP_MAX_CELLS: f64 = 40e6;
/// Wall height (CARLA `wall_height`), m.
pub const WALL_HEIGHT: f64 = 0.2;
/// Wall thickness, m (not given by the reference; CARLA's walls are thin).
pub const WALL_THICKNESS: f64 = 0.10;
/// Camera height above the ground (the CoM is on the ground plane), m.
pub const CAMERA_HEIGHT: f64 = 0.2;
/// Reference resolution and field of view.
pub const REFERENCE_SIZE: usize = 224;
pub const REFERENCE_FOV_DEG: f64 = 110.0;

const AMBIENT: f64 = 0.4;
const DIFFUSE: f64 = 0.6;
const ROAD_RGB: [f64; 3] = [0.26, 0.26, 0.28];
const GROUND_RGB: [f64; 3] = [0.36, 0.46, 0.26];
const WALL_RGB: [f64; 3] = [0.95, 0.88, 0.78];
const SKY_HORIZON_RGB: [f64; 3] = [0.78, 0.86, 0.95];
const SKY_ZENITH_RGB: [f64; 3] = [0.32, 0.52, 0.86];

/// Sun direction: azimuth CCW from +x (rad) and elevation above the horizon (rad).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sun {
    pub azimuth: f64,
    pub elevation: f64,
}

impl Default for Sun {
    fn default() -> Self {
        Sun {
            azimuth: 0.8,
            elevation: 45f64.to_radians(),
        }
    }
}

impl Sun {
    /// Azimuth ~ U(0, 2π), elevation ~ U(15°, 75°), in that order.
    pub fn random<R: Rng + ?Sized>(rng: &mut R) -> Sun {
        let azimuth = 2.0 * PI * rng.gen::<f64>();
        let (lo, hi) = (15f64.to_radians(), 75f64.to_radians());
        let elevation = lo + (hi - lo) * rng.gen::<f64>();
        Sun { azimuth, elevation }
    }

    /// Unit vector towards the sun (x, y, z).
    fn direction(&self) -> [f64; 3] {
        let (se, ce) = self.elevation.sin_cos();
        let (sa, ca) = self.azimuth.sin_cos();
        [ce * ca, ce * sa, se]
    }
}

/// An 8-bit RGB image, rows top to bottom, HWC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

impl Frame {
    pub fn new(width: usize, height: usize) -> Frame {
        Frame {
            width,
            height,
            rgb: vec![0; image_bytes(width, height)],
        }
    }

    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = (y * self.width + x) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    #[inline]
    pub fn set(&mut self, x: usize, y: usize, c: [u8; 3]) {
        let i = (y * self.width + x) * 3;
        self.rgb[i..i + 3].copy_from_slice(&c);
    }

    pub fn write_png(&self, path: impl AsRef<Path>) -> std::io::Result<()> {
        let file = std::fs::File::create(path.as_ref())?;
        let w = std::io::BufWriter::new(file);
        let mut enc = png::Encoder::new(w, self.width as u32, self.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        writer
            .write_image_data(&self.rgb)
            .map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    }
}

/// The protocol's image (what a segment carries): the pixels move, they are not copied.
impl From<Frame> for cabc_proto::messages::Image {
    fn from(image: Frame) -> Self {
        cabc_proto::messages::Image {
            width: image.width as u16,
            height: image.height as u16,
            rgb: image.rgb,
        }
    }
}

/// A grid over the track's surroundings holding the distance to the centreline (m, f32), built once per
/// track; share it with `Arc`. Outside the grid everything is ground.
#[derive(Clone, Debug)]
pub struct TrackLookup {
    x0: f64,
    y0: f64,
    res: f64,
    nx: usize,
    ny: usize,
    dist: Vec<f32>,
    /// The road's half-width as rendered: the track's constraint plus [`ROAD_MARGIN`].
    road: f64,
}

impl TrackLookup {
    /// Grid with cell size `res` (m) covering the centreline bounds plus a margin of the road and 0.5 m (1.2 m on
    /// the L-track); coarser where that would be more than [`LOOKUP_MAX_CELLS`] cells.
    pub fn new(track: &Track, res: f64) -> TrackLookup {
        let res = if res.is_finite() && res > 1e-3 {
            res
        } else {
            0.01
        };
        let (bx0, by0, bx1, by1) = track.centreline_bounds();
        let road = track.half_width() + ROAD_MARGIN;
        // The L-track's 1.2 m, or the road and 0.5 m where that is more.
        let margin = if road + 0.5 > 1.2 + 1e-9 {
            road + 0.5
        } else {
            1.2
        };
        let cells = (bx1 - bx0 + 2.0 * margin) * (by1 - by0 + 2.0 * margin) / (res * res);
        let res = res * (cells / LOOKUP_MAX_CELLS).sqrt().max(1.0);
        // Origin on a multiple of `res` so that the grid is symmetric about the axes through the start.
        let x0 = ((bx0 - margin) / res).floor() * res;
        let y0 = ((by0 - margin) / res).floor() * res;
        let nx = ((bx1 + margin - x0) / res).ceil() as usize + 1;
        let ny = ((by1 + margin - y0) / res).ceil() as usize + 1;
        let dist = track.distance_field(x0, y0, res, nx, ny, 10.0);
        TrackLookup {
            x0,
            y0,
            res,
            nx,
            ny,
            dist,
            road,
        }
    }

    /// Distance to the centreline at (x, y) (nearest cell); +∞ outside the grid.
    #[inline]
    pub fn distance(&self, x: f64, y: f64) -> f64 {
        let fx = (x - self.x0) / self.res;
        let fy = (y - self.y0) / self.res;
        if !(fx >= 0.0 && fy >= 0.0) {
            return f64::INFINITY;
        }
        let (ix, iy) = (fx as usize, fy as usize);
        if ix >= self.nx || iy >= self.ny {
            return f64::INFINITY;
        }
        self.dist[iy * self.nx + ix] as f64
    }

    pub fn resolution(&self) -> f64 {
        self.res
    }

    /// March from (x, y) along the unit direction (dx, dy) up to `max_t` metres; the distance at which
    /// the ray first enters a wall, if it does.
    #[inline]
    fn trace_wall(&self, x: f64, y: f64, dx: f64, dy: f64, max_t: f64) -> Option<f64> {
        let (inner, outer) = (self.road, self.road + WALL_THICKNESS);
        let min_step = 0.5 * self.res;
        let mut t = 0.0;
        while t <= max_t {
            let d = self.distance(x + t * dx, y + t * dy);
            if !d.is_finite() {
                return None;
            }
            if (inner..=outer).contains(&d) {
                return Some(t);
            }
            let safe = if d < inner { inner - d } else { d - outer };
            t += (safe - self.res).max(min_step);
        }
        None
    }

    /// Unit gradient of the distance field at (x, y) (central differences over two cells).
    fn gradient(&self, x: f64, y: f64) -> (f64, f64) {
        let h = 2.0 * self.res;
        let gx = self.distance(x + h, y) - self.distance(x - h, y);
        let gy = self.distance(x, y + h) - self.distance(x, y - h);
        let n = gx.hypot(gy);
        if n.is_finite() && n > 0.0 {
            (gx / n, gy / n)
        } else {
            (0.0, 0.0)
        }
    }
}

/// A pinhole camera with its per-column and per-row ray tables and a reusable output image.
#[derive(Clone, Debug)]
pub struct Camera {
    width: usize,
    height: usize,
    fov_deg: f64,
    /// Per column: leftward ray slope (positive = left of the optical axis).
    col_left: Vec<f64>,
    /// Per row: upward ray slope (positive = above the horizon).
    row_up: Vec<f64>,
    sky: Vec<[u8; 3]>,
    image: Frame,
}

impl Camera {
    /// A `width` × `height` camera with horizontal field of view `fov_deg` (clamped to [1°, 179°]).
    pub fn new(width: usize, height: usize, fov_deg: f64) -> Camera {
        let (width, height) = (width.max(1), height.max(1));
        let fov_deg = if fov_deg.is_finite() {
            fov_deg.clamp(1.0, 179.0)
        } else {
            REFERENCE_FOV_DEG
        };
        let f = (width as f64 / 2.0) / (fov_deg.to_radians() / 2.0).tan();
        let col_left = (0..width)
            .map(|i| -((i as f64 + 0.5) - width as f64 / 2.0) / f)
            .collect();
        let row_up: Vec<f64> = (0..height)
            .map(|j| -((j as f64 + 0.5) - height as f64 / 2.0) / f)
            .collect();
        let sky = row_up
            .iter()
            .map(|&u| {
                let k = (u.atan() / (PI / 2.0)).clamp(0.0, 1.0).sqrt();
                to_u8(std::array::from_fn(|c| {
                    SKY_HORIZON_RGB[c] * (1.0 - k) + SKY_ZENITH_RGB[c] * k
                }))
            })
            .collect();
        Camera {
            width,
            height,
            fov_deg,
            col_left,
            row_up,
            sky,
            image: Frame::new(width, height),
        }
    }

    /// The reference camera: 224 × 224, 110°.
    pub fn reference() -> Camera {
        Camera::new(REFERENCE_SIZE, REFERENCE_SIZE, REFERENCE_FOV_DEG)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn fov_deg(&self) -> f64 {
        self.fov_deg
    }

    /// Render the view from `pose` under `sun` into the camera's buffer and return it.
    pub fn render(&mut self, lookup: &TrackLookup, pose: Pose, sun: Sun) -> &Frame {
        let mut image = std::mem::replace(&mut self.image, Frame::new(0, 0));
        self.render_into(lookup, pose, sun, &mut image);
        self.image = image;
        &self.image
    }

    /// Render the view from `pose` under `sun` into `frame` (resized to the camera's). Frames of at least
    /// [`PARALLEL_PIXELS`] pixels are drawn on all cores (rayon): the columns' wall traces, then the rows; each pixel
    /// is the same function of the pose whichever thread draws it, so the image is the same bits as on one core.
    pub fn render_into(&self, lookup: &TrackLookup, pose: Pose, sun: Sun, frame: &mut Frame) {
        let (w, h) = (self.width, self.height);
        if (frame.width, frame.height) != (w, h) {
            *frame = Frame::new(w, h);
        }
        let scene = Scene::new(pose, sun);
        // One task for a small frame: rayon's hand-offs would cost more than its pixels.
        let (columns_per_task, rows_per_task) = if w * h >= PARALLEL_PIXELS {
            (8, 4)
        } else {
            (w, h)
        };
        let columns: Vec<Column> = (0..w)
            .into_par_iter()
            .with_min_len(columns_per_task)
            .map(|i| scene.column(lookup, self.col_left[i]))
            .collect();
        frame
            .rgb
            .par_chunks_mut(w * 3)
            .with_min_len(rows_per_task)
            .enumerate()
            .for_each(|(j, row)| {
                let (u, sky) = (self.row_up[j], self.sky[j]);
                for (pixel, column) in row.chunks_exact_mut(3).zip(&columns) {
                    let c = if u >= 0.0 {
                        sky
                    } else {
                        scene.ground(lookup, column, u)
                    };
                    pixel.copy_from_slice(&c);
                }
            });
    }

    /// Render like [`Camera::render`] and hand the image over (moved, not copied; the camera takes a fresh
    /// buffer), for callers that keep every frame.
    pub fn render_owned(&mut self, lookup: &TrackLookup, pose: Pose, sun: Sun) -> Frame {
        self.render(lookup, pose, sun);
        std::mem::replace(&mut self.image, Frame::new(self.width, self.height))
    }

    /// The last rendered image.
    pub fn image(&self) -> &Frame {
        &self.image
    }

    /// Renders the view from the Frenet pose (s, x_tran, e_psi) of `track` (`cabc-sim render`); returns the global
    /// pose with the frame. A non-finite coordinate is refused.
    pub fn render_frenet(
        &mut self,
        track: &Track,
        (s, x_tran, e_psi): (f64, f64, f64),
        sun: Sun,
    ) -> Result<(Frame, Pose), String> {
        if !(s.is_finite() && x_tran.is_finite() && e_psi.is_finite()) {
            return Err("s, x_tran and e_psi must be finite".into());
        }
        let pose = track.local_to_global(s, x_tran, e_psi);
        Ok((
            self.render_owned(&TrackLookup::new(track, 0.01), pose, sun),
            pose,
        ))
    }
}

/// Frames of this many pixels or more are rendered on all cores ([`Camera::render_into`]): 128 x 128.
pub const PARALLEL_PIXELS: usize = 128 * 128;

/// What every pixel of one render shares: the pose and the sun's light.
struct Scene {
    pose: Pose,
    cos_psi: f64,
    sin_psi: f64,
    sun: [f64; 3],
    sun_dx: f64,
    sun_dy: f64,
    /// Horizontal distance over which a ray towards the sun stays below the wall top.
    shadow_len: f64,
    road_lit: [u8; 3],
    road_dark: [u8; 3],
    ground_lit: [u8; 3],
    ground_dark: [u8; 3],
    wall_top: [u8; 3],
}

/// One image column: its ray's horizontal direction and the wall it meets, if any, with the wall's colour.
struct Column {
    dx: f64,
    dy: f64,
    hlen: f64,
    wall: Option<(f64, [u8; 3])>,
}

impl Scene {
    /// Farthest distance a column's ray is traced, m.
    const MAX_VIEW: f64 = 30.0;

    fn new(pose: Pose, sun: Sun) -> Scene {
        let (sin_psi, cos_psi) = pose.psi.sin_cos();
        let s = sun.direction();
        let shadow_len = if s[2] > 1e-6 {
            WALL_HEIGHT * (1.0 - s[2] * s[2]).sqrt() / s[2]
        } else {
            1e3
        };
        let flat_lit = AMBIENT + DIFFUSE * s[2].max(0.0);
        Scene {
            pose,
            cos_psi,
            sin_psi,
            sun: s,
            sun_dx: sun.azimuth.cos(),
            sun_dy: sun.azimuth.sin(),
            shadow_len,
            road_lit: to_u8(ROAD_RGB.map(|c| c * flat_lit)),
            road_dark: to_u8(ROAD_RGB.map(|c| c * AMBIENT)),
            ground_lit: to_u8(GROUND_RGB.map(|c| c * flat_lit)),
            ground_dark: to_u8(GROUND_RGB.map(|c| c * AMBIENT)),
            wall_top: to_u8(WALL_RGB.map(|c| c * flat_lit)),
        }
    }

    /// The column whose ray leaves `l` to the left of the optical axis (a slope).
    fn column(&self, lookup: &TrackLookup, l: f64) -> Column {
        let (cp, sp, pose, s) = (self.cos_psi, self.sin_psi, self.pose, self.sun);
        let hlen = (1.0 + l * l).sqrt();
        let (dx, dy) = ((cp - l * sp) / hlen, (sp + l * cp) / hlen);
        let wall = lookup
            .trace_wall(pose.x, pose.y, dx, dy, Self::MAX_VIEW)
            .map(|t| {
                let (hx, hy) = (pose.x + t * dx, pose.y + t * dy);
                let (mut nx, mut ny) = lookup.gradient(hx, hy);
                // The visible face looks back at the camera.
                if nx * dx + ny * dy > 0.0 {
                    nx = -nx;
                    ny = -ny;
                }
                let lambert = (nx * s[0] + ny * s[1]).max(0.0);
                (
                    t,
                    to_u8(WALL_RGB.map(|c| c * (AMBIENT + DIFFUSE * lambert))),
                )
            });
        Column { dx, dy, hlen, wall }
    }

    /// The colour of `column`'s pixel in a row below the horizon (`u` < 0, the row's slope).
    fn ground(&self, lookup: &TrackLookup, column: &Column, u: f64) -> [u8; 3] {
        let g = CAMERA_HEIGHT * column.hlen / (-u); // horizontal distance to the ground hit
        if let Some((t, rgb)) = column.wall {
            if t < g {
                return rgb;
            }
        }
        let (gx, gy) = (self.pose.x + g * column.dx, self.pose.y + g * column.dy);
        let d = lookup.distance(gx, gy);
        let road = lookup.road;
        let on_wall_top = !(d <= road || d > road + WALL_THICKNESS);
        if on_wall_top {
            return self.wall_top;
        }
        let near_wall = d <= road + WALL_THICKNESS + self.shadow_len;
        let shadowed = near_wall
            && (self.sun[2] <= 0.0
                || lookup
                    .trace_wall(gx, gy, self.sun_dx, self.sun_dy, self.shadow_len)
                    .is_some());
        match (d <= road, shadowed) {
            (true, false) => self.road_lit,
            (true, true) => self.road_dark,
            (false, false) => self.ground_lit,
            (false, true) => self.ground_dark,
        }
    }
}

#[inline]
fn to_u8(c: [f64; 3]) -> [u8; 3] {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}
