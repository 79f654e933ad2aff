//! The race track: a closed centreline of straights and circular arcs, with Frenet conversions.
//!
//! Frame: right-handed plane, ψ counter-clockwise from +x, metres and radians. A track is data: a list of
//! [`TrackPiece`]s (arc length, signed radius; radius 0 = straight, > 0 = left/CCW turn) starting at the pose
//! (0, 0, 0). The routines follow simulator.md §2 literally (the reference's `key_pts` recurrence,
//! `local_to_global` and the analytic first-match `global_to_local`), so a round trip is exact to rounding.

use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

mod fit;
mod geometry;
mod index;
pub mod load;
pub use fit::PIECE_LENGTH;
pub use load::{car_min_radius, L_TRACK_BARC};

/// The Frenet band's slack beyond the constraint (m): the L-track's, and a file's unless it says otherwise.
pub const SLACK: f64 = 0.3;

/// One piece of centreline: `length` of arc (m) and signed `radius` (m); 0 = straight, > 0 = left (CCW).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrackPiece {
    pub length: f64,
    pub radius: f64,
}

/// A global pose: position (m) and heading ψ (rad, CCW from +x).
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub psi: f64,
}

/// Frenet coordinates: arc length `s` along the centreline, lateral offset `x_tran` (> 0 = left) and
/// heading error `e_psi` relative to the centreline tangent.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Frenet {
    pub s: f64,
    pub x_tran: f64,
    pub e_psi: f64,
}

#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum TrackError {
    /// The reference's "Point is out of the track!": no track piece holds the point within the band.
    #[error(
        "point ({x:.4}, {y:.4}) is out of the track (farther than {band} m from the centreline)"
    )]
    OutOfBand { x: f64, y: f64, band: f64 },
    #[error("track piece {index} is invalid: {reason}")]
    InvalidPiece { index: usize, reason: String },
    #[error("invalid widths: half_width {half_width} and slack {slack} must be finite, half_width > 0, slack >= 0")]
    InvalidWidth { half_width: f64, slack: f64 },
    #[error("the centreline does not close: the end is {gap:.3e} m from the start")]
    NotClosed { gap: f64 },
    /// A track file that cannot be a track: the file, the line nearest the fault where there is one, and why.
    #[error("{file}{}: {why}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    File {
        file: String,
        line: Option<usize>,
        why: String,
    },
    #[error("no track named `{name}`: a track is one of {names}, or a file (.csv: an F1TENTH centre line; .toml: pieces)")]
    UnknownTrack { name: String, names: String },
    #[error(
        "sim.actor_tracks: {track}'s half-width is {width} m, sim.track's {half_width} m: the actors' tracks share the \
         constraint (sim.track_half_width sets it)"
    )]
    OtherWidth {
        track: String,
        width: f64,
        half_width: f64,
    },
}

/// One row of the reference's `key_pts`: the pose at the end of a track piece, its cumulative arc length and
/// the piece's length and curvature (row 0 is the start pose).
#[derive(Clone, Copy, Debug)]
struct KeyPoint {
    x: f64,
    y: f64,
    /// Wrapped into [-π, π] by a single ±2π.
    psi: f64,
    cum_s: f64,
    len: f64,
    curvature: f64,
}

/// The circle of an arc piece that starts at `start` with curvature `curvature` (non-zero): its centre, its
/// radius, its turning direction (1 left, -1 right) and the heading from the start to the centre (not wrapped).
struct Circle {
    centre: (f64, f64),
    radius: f64,
    dir: f64,
    normal: f64,
}

impl Circle {
    fn of(start: &KeyPoint, curvature: f64) -> Circle {
        let r = 1.0 / curvature;
        let dir = if r >= 0.0 { 1.0 } else { -1.0 };
        let radius = r.abs();
        let normal = start.psi + dir * FRAC_PI_2;
        Circle {
            centre: (
                start.x + radius * normal.cos(),
                start.y + radius * normal.sin(),
            ),
            radius,
            dir,
            normal,
        }
    }

    /// The signed angle the piece of length `len` turns through (positive left).
    fn span(&self, len: f64) -> f64 {
        self.dir * len / self.radius
    }
}

/// A closed track with a constant half-width (the constraint) and a slack band (Frenet validity).
#[derive(Clone, Debug)]
pub struct Track {
    pieces: Vec<TrackPiece>,
    half_width: f64,
    slack: f64,
    key: Vec<KeyPoint>,
    length: f64,
    start_line: [(f64, f64); 2],
    /// The track in words (reports, dataset descriptions).
    description: String,
    /// Which pieces may hold a point, by grid cell: for tracks of many pieces (a fitted centre line).
    index: Option<Arc<index::Grid>>,
}

/// The reference's `wrap_angle`: one ±2π correction into [-π, π].
#[inline]
fn wrap(a: f64) -> f64 {
    if a > PI {
        a - 2.0 * PI
    } else if a < -PI {
        a + 2.0 * PI
    } else {
        a
    }
}

/// `np.unwrap([a, b])[1] - a`: the difference b - a brought into [-π, π] (−π maps to +π when b > a).
#[inline]
fn unwrap_diff(a: f64, b: f64) -> f64 {
    let dd = b - a;
    if dd.abs() < PI {
        return dd;
    }
    let mut m = (dd + PI).rem_euclid(2.0 * PI) - PI;
    if m == -PI && dd > 0.0 {
        m = PI;
    }
    // numpy's order of operations: (b + (m - dd)) - a.
    (b + (m - dd)) - a
}

/// angle(O; A, B) = atan2(cross(A-O, B-O), dot(A-O, B-O)).
#[inline]
fn angle(o: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (ax, ay) = (a.0 - o.0, a.1 - o.1);
    let (bx, by) = (b.0 - o.0, b.1 - o.1);
    (ax * by - ay * bx).atan2(ax * bx + ay * by)
}

#[inline]
fn sign(v: f64) -> f64 {
    // np.sign: 0 for 0.
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// `L_track_barc`'s half-width (m): the constraint |x_tran| <= 0.55 m.
const L_TRACK_BARC_HALF_WIDTH: f64 = 0.55;

/// Tracks of more pieces than this find a point's piece through a grid ([`index::Grid`]); the L-track's nine are
/// searched in order, as the reference does.
const INDEXED_ABOVE: usize = 16;

impl Track {
    /// The paper's `L_track_barc` (simulator.md §2.1): nine pieces to the npz's full precision,
    /// half-width 0.55 m, slack 0.3 m.
    pub fn l_track_barc() -> Track {
        // The npz's `cl_segs` to full double precision, as `generate_LTrack_barc` computes them
        // (e.g. s2 = 1.051 - 0.15 = 0.9009999999999999, arcs = π r or π r / 2).
        let pieces = vec![
            TrackPiece {
                length: 2.251,
                radius: 0.0,
            },
            TrackPiece {
                length: 3.620685533262237,
                radius: 1.1525,
            },
            TrackPiece {
                length: 0.9009999999999999,
                radius: 0.0,
            },
            TrackPiece {
                length: 1.6024753617155325,
                radius: -1.0201675,
            },
            TrackPiece {
                length: 0.15000000000000002,
                radius: 0.0,
            },
            TrackPiece {
                length: 3.858449119267546,
                radius: 1.2281825,
            },
            TrackPiece {
                length: 2.25454,
                radius: 0.0,
            },
            TrackPiece {
                length: 1.9173571933848375,
                radius: 1.2206275,
            },
            TrackPiece {
                length: 0.9059049999999997,
                radius: 0.0,
            },
        ];
        Track::new(pieces, L_TRACK_BARC_HALF_WIDTH, SLACK)
            .expect("L_track_barc is a valid closed track")
            .described("the L-shaped BARC track".into())
    }

    /// Build a track from pieces starting at pose (0, 0, 0). Fails if a piece is degenerate, an arc is
    /// tighter than the band (the inner band edge would fold), or the centreline does not close (to 1 mm).
    pub fn new(pieces: Vec<TrackPiece>, half_width: f64, slack: f64) -> Result<Track, TrackError> {
        if !(half_width.is_finite() && slack.is_finite() && half_width > 0.0 && slack >= 0.0) {
            return Err(TrackError::InvalidWidth { half_width, slack });
        }
        if pieces.is_empty() {
            return Err(TrackError::InvalidPiece {
                index: 0,
                reason: "no pieces".into(),
            });
        }
        let band = half_width + slack;
        let mut key = Vec::with_capacity(pieces.len() + 1);
        key.push(KeyPoint {
            x: 0.0,
            y: 0.0,
            psi: 0.0,
            cum_s: 0.0,
            len: 0.0,
            curvature: 0.0,
        });
        for (i, seg) in pieces.iter().enumerate() {
            if !(seg.length.is_finite() && seg.length > 0.0 && seg.radius.is_finite()) {
                return Err(TrackError::InvalidPiece {
                    index: i,
                    reason: format!(
                        "length {} / radius {} must be finite with length > 0",
                        seg.length, seg.radius
                    ),
                });
            }
            if seg.radius != 0.0 && seg.radius.abs() <= band {
                return Err(TrackError::InvalidPiece {
                    index: i,
                    reason: format!("|radius| {} must exceed the band {band}", seg.radius.abs()),
                });
            }
            let p = key[i];
            let (x, y, psi, curvature) = if seg.radius == 0.0 {
                (
                    p.x + seg.length * p.psi.cos(),
                    p.y + seg.length * p.psi.sin(),
                    p.psi,
                    0.0,
                )
            } else {
                let r = seg.radius;
                let (cx, cy) = (p.x - r * p.psi.sin(), p.y + r * p.psi.cos());
                let theta = seg.length / r;
                let a = p.psi + theta;
                (cx + r * a.sin(), cy - r * a.cos(), wrap(a), 1.0 / r)
            };
            key.push(KeyPoint {
                x,
                y,
                psi,
                cum_s: p.cum_s + seg.length,
                len: seg.length,
                curvature,
            });
        }
        let last = key[key.len() - 1];
        let gap = last.x.hypot(last.y);
        if gap > 1e-3 || wrap(last.psi).abs() > 1e-3 {
            return Err(TrackError::NotClosed { gap });
        }
        let length = last.cum_s;
        let mut track = Track {
            pieces,
            half_width,
            slack,
            key,
            length,
            start_line: [(0.0, 0.0); 2],
            description: "a track of pieces".into(),
            index: None,
        };
        if track.pieces.len() > INDEXED_ABOVE {
            track.index = Some(Arc::new(index::Grid::new(&track)));
        }
        let a = track.local_to_global(0.0, half_width, 0.0);
        let b = track.local_to_global(0.0, -half_width, 0.0);
        track.start_line = [(a.x, a.y), (b.x, b.y)];
        Ok(track)
    }

    pub fn pieces(&self) -> &[TrackPiece] {
        &self.pieces
    }

    /// Centreline length L (m); 17.461412207630154 for `L_track_barc`.
    pub fn length(&self) -> f64 {
        self.length
    }

    /// The constraint half-width H (m): |x_tran| ≤ H is "on track".
    pub fn half_width(&self) -> f64 {
        self.half_width
    }

    pub fn slack(&self) -> f64 {
        self.slack
    }

    /// The Frenet validity band H + slack (m); beyond it `global_to_local` fails.
    pub fn band(&self) -> f64 {
        self.half_width + self.slack
    }

    /// The end poses of the pieces with their cumulative s: row 0 is the start pose, row i the end of
    /// piece i (simulator.md §2.2), as `(pose, cum_s)`.
    pub fn key_points(&self) -> Vec<(Pose, f64)> {
        self.key
            .iter()
            .map(|k| {
                (
                    Pose {
                        x: k.x,
                        y: k.y,
                        psi: k.psi,
                    },
                    k.cum_s,
                )
            })
            .collect()
    }

    /// The start/finish line: the segment across the track at s = 0 from x_tran = +H to −H.
    pub fn start_line(&self) -> [(f64, f64); 2] {
        self.start_line
    }

    /// Frenet → global (simulator.md §2.3). `s` is wrapped into [0, L); ψ is wrapped into [-π, π].
    pub fn local_to_global(&self, s: f64, x_tran: f64, e_psi: f64) -> Pose {
        let mut s = s;
        if !s.is_finite() {
            s = 0.0;
        }
        while s < 0.0 {
            s += self.length;
        }
        while s >= self.length {
            s -= self.length;
        }
        // Last key point with cum_s <= s (among the piece starts 0..n-1).
        let n = self.pieces.len();
        let i = self.key[1..n].partition_point(|k| k.cum_s <= s);
        let (ki, kf) = (self.key[i], self.key[i + 1]);
        let d = s - ki.cum_s;
        if kf.curvature == 0.0 {
            let t = d / kf.len;
            Pose {
                x: ki.x + (kf.x - ki.x) * t - x_tran * kf.psi.sin(),
                y: ki.y + (kf.y - ki.y) * t + x_tran * kf.psi.cos(),
                psi: wrap(kf.psi + e_psi),
            }
        } else {
            let arc = Circle::of(&ki, kf.curvature);
            let (dir, ar, (cx, cy)) = (arc.dir, arc.radius, arc.centre);
            let span = d / ar;
            let psi_d = wrap(ki.psi + dir * span);
            let ang_n = wrap(arc.normal);
            let sgn = if ang_n >= 0.0 { 1.0 } else { -1.0 };
            let ang = -sgn * (PI - ang_n.abs());
            let rr = ar - dir * x_tran;
            Pose {
                x: cx + rr * (ang + dir * span).cos(),
                y: cy + rr * (ang + dir * span).sin(),
                psi: wrap(psi_d + e_psi),
            }
        }
    }

    /// Global → Frenet (simulator.md §2.5): the first piece, in order, whose region holds the point within
    /// the band. ψ may be unwrapped (any multiple of 2π); `e_psi` comes back in [-π, π].
    pub fn global_to_local(&self, x: f64, y: f64, psi: f64) -> Result<Frenet, TrackError> {
        let band = self.band();
        let found = match &self.index {
            None => (1..self.key.len()).find_map(|i| self.in_piece(i, x, y, psi, band)),
            Some(grid) => grid
                .candidates(x, y)
                .iter()
                .find_map(|&i| self.in_piece(i as usize, x, y, psi, band)),
        };
        found.ok_or(TrackError::OutOfBand { x, y, band })
    }

    /// The Frenet coordinates of (x, y, ψ) in piece `i` (from key point i − 1 to i), if its region holds the
    /// point within `band`.
    fn in_piece(&self, i: usize, x: f64, y: f64, psi: f64, band: f64) -> Option<Frenet> {
        let p = (x, y);
        let (k0, k1) = (self.key[i - 1], self.key[i]);
        let p0 = (k0.x, k0.y);
        let p1 = (k1.x, k1.y);
        if p == p0 {
            return Some(Frenet {
                s: k0.cum_s,
                x_tran: 0.0,
                e_psi: unwrap_diff(k0.psi, psi),
            });
        }
        if p == p1 {
            return Some(Frenet {
                s: k1.cum_s,
                x_tran: 0.0,
                e_psi: unwrap_diff(k1.psi, psi),
            });
        }
        if k1.curvature == 0.0 {
            if angle(p0, p, p1).abs() > FRAC_PI_2 || angle(p1, p, p0).abs() > FRAC_PI_2 {
                return None;
            }
            let a = angle(p0, p1, p);
            let dist = (x - p0.0).hypot(y - p0.1);
            let e_y = dist * a.sin();
            (e_y.abs() <= band).then(|| Frenet {
                s: k0.cum_s + dist * a.cos(),
                x_tran: e_y,
                e_psi: unwrap_diff(k0.psi, psi),
            })
        } else {
            let arc = Circle::of(&k0, k1.curvature);
            let (dir, ar, c) = (arc.dir, arc.radius, arc.centre);
            let span = arc.span(k1.len);
            let cur = angle(c, p0, p);
            if sign(span) != sign(cur) || span.abs() < cur.abs() {
                return None;
            }
            let e_y = -dir * ((x - c.0).hypot(y - c.1) - ar);
            (e_y.abs() <= band).then(|| Frenet {
                s: k0.cum_s + cur.abs() * ar,
                x_tran: e_y,
                e_psi: unwrap_diff(k0.psi + cur, psi),
            })
        }
    }

    /// Whether the motion segment old → new intersects the start line (orientation test, collinear
    /// cases included; simulator.md §3.5). The env also requires s to decrease for a lap.
    pub fn crosses_start_line(&self, old: (f64, f64), new: (f64, f64)) -> bool {
        segments_intersect(new, old, self.start_line[0], self.start_line[1])
    }

    /// Euclidean distance from (x, y) to the centreline curve (exact, over all pieces). Inside the band it
    /// equals |x_tran|. Used to precompute the camera's lookup grid.
    pub fn distance_to_centreline(&self, x: f64, y: f64) -> f64 {
        let mut best = f64::INFINITY;
        for i in 1..self.key.len() {
            let (k0, k1) = (self.key[i - 1], self.key[i]);
            let d = if k1.curvature == 0.0 {
                let (dx, dy) = (k1.x - k0.x, k1.y - k0.y);
                let l2 = dx * dx + dy * dy;
                let t = (((x - k0.x) * dx + (y - k0.y) * dy) / l2).clamp(0.0, 1.0);
                (x - k0.x - t * dx).hypot(y - k0.y - t * dy)
            } else {
                let arc = Circle::of(&k0, k1.curvature);
                let (ar, c) = (arc.radius, arc.centre);
                let span = arc.span(k1.len);
                let cur = angle(c, (k0.x, k0.y), (x, y));
                let inside = if span > 0.0 {
                    cur >= 0.0 && cur <= span
                } else {
                    cur <= 0.0 && cur >= span
                };
                if inside {
                    ((x - c.0).hypot(y - c.1) - ar).abs()
                } else {
                    (x - k0.x).hypot(y - k0.y).min((x - k1.x).hypot(y - k1.y))
                }
            };
            best = best.min(d);
        }
        best
    }

    /// The centreline's mean curvature (1/m, > 0 turning left) over [s, s + ahead]: its heading's change over the
    /// distance (the observation's curvature preview, `observation.track_feature`).
    pub fn mean_curvature(&self, s: f64, ahead: f64) -> f64 {
        let (a, b) = (
            self.local_to_global(s, 0.0, 0.0),
            self.local_to_global(s + ahead, 0.0, 0.0),
        );
        wrap(b.psi - a.psi) / ahead
    }

    /// Axis-aligned bounding box of the centreline sampled every ~1 cm: (x_min, y_min, x_max, y_max).
    pub fn centreline_bounds(&self) -> (f64, f64, f64, f64) {
        let n = (self.length / 0.01).ceil() as usize;
        let mut b = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for k in 0..=n {
            let p = self.local_to_global(self.length * k as f64 / n as f64, 0.0, 0.0);
            b = (b.0.min(p.x), b.1.min(p.y), b.2.max(p.x), b.3.max(p.y));
        }
        b
    }
}

/// Orientation of the triple (p, q, r): 0 collinear, 1 clockwise, 2 counter-clockwise.
fn orientation(p: (f64, f64), q: (f64, f64), r: (f64, f64)) -> u8 {
    let v = (q.1 - p.1) * (r.0 - q.0) - (q.0 - p.0) * (r.1 - q.1);
    if v == 0.0 {
        0
    } else if v > 0.0 {
        1
    } else {
        2
    }
}

/// q lies on segment pr, given p, q, r collinear.
fn on_segment(p: (f64, f64), q: (f64, f64), r: (f64, f64)) -> bool {
    q.0 <= p.0.max(r.0) && q.0 >= p.0.min(r.0) && q.1 <= p.1.max(r.1) && q.1 >= p.1.min(r.1)
}

/// Standard segment intersection p1q1 vs p2q2, collinear cases included.
fn segments_intersect(p1: (f64, f64), q1: (f64, f64), p2: (f64, f64), q2: (f64, f64)) -> bool {
    let o1 = orientation(p1, q1, p2);
    let o2 = orientation(p1, q1, q2);
    let o3 = orientation(p2, q2, p1);
    let o4 = orientation(p2, q2, q1);
    (o1 != o2 && o3 != o4)
        || (o1 == 0 && on_segment(p1, p2, q1))
        || (o2 == 0 && on_segment(p1, q2, q1))
        || (o3 == 0 && on_segment(p2, p1, q2))
        || (o4 == 0 && on_segment(p2, q1, q2))
}

#[cfg(test)]
mod tests;
