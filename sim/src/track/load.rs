//! Tracks from files (issue 76): an F1TENTH centre line (`*.csv`: `x_m, y_m, w_tr_right_m, w_tr_left_m`, closed,
//! `#` comments) or a list of pieces (`*.toml`: straights and arcs from the start pose, as the L-track is built),
//! and the tracks shipped in the repository's `tracks/` folder, by name.
//!
//! The constraint is one half-width for the whole track: the narrowest the file gives (the least of every
//! point's left and right widths). A centre line is not moved toward the wider side.

use super::fit::{fit, CentrePoint, Fitted};
use super::{Track, TrackError, TrackPiece, SLACK};
use crate::vehicle::{VehicleParams, ACTION_HIGH};
use cabc_proto::config::SimSection;
use serde::Deserialize;
use std::path::Path;
use std::sync::Arc;

/// The tracks made by this project, shipped as files (`tracks/`) and built into the binaries, by name.
pub const SHIPPED: &[(&str, &str, &str)] = &[
    (
        "oval",
        "oval.toml",
        include_str!("../../../tracks/oval.toml"),
    ),
    (
        "chicane",
        "chicane.toml",
        include_str!("../../../tracks/chicane.toml"),
    ),
    ("long", "long.csv", include_str!("../../../tracks/long.csv")),
];

/// The longest track a file may make (m): its checks and its grid grow with it.
pub const MAX_LENGTH: f64 = 10_000.0;

impl Track {
    /// The track a run's configuration names (`sim.track`, `sim.track_scale`): built once per process and shared.
    pub fn of(sim: &cabc_proto::config::SimSection) -> Result<Arc<Track>, TrackError> {
        type Built = std::sync::Mutex<Vec<((String, [u64; 2]), Arc<Track>)>>;
        static BUILT: std::sync::OnceLock<Built> = std::sync::OnceLock::new();
        let size = Size::of(sim);
        let key = (
            sim.track.clone(),
            [
                size.scale.to_bits(),
                size.half_width.map_or(0, f64::to_bits),
            ],
        );
        let built = BUILT.get_or_init(Default::default);
        if let Some((_, t)) = built
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .find(|(k, _)| *k == key)
        {
            return Ok(t.clone());
        }
        let track = Arc::new(load(&sim.track, size)?);
        built
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((key, track.clone()));
        Ok(track)
    }

    /// The half-width (m) of the run's constraint: `sim.track`'s, which every track of `sim.actor_tracks` must share
    /// (the safety labels use one constraint).
    pub fn constraint_of(sim: &SimSection) -> Result<f64, TrackError> {
        let half_width = Track::of(sim)?.half_width();
        for track in &sim.actor_tracks {
            let other = SimSection {
                track: track.clone(),
                actor_tracks: Vec::new(),
                ..sim.clone()
            };
            let width = Track::of(&other)?.half_width();
            if width != half_width {
                return Err(TrackError::OtherWidth {
                    track: track.clone(),
                    width,
                    half_width,
                });
            }
        }
        Ok(half_width)
    }

    /// The track in words: "the L-shaped BARC track", or its file and scale.
    pub fn describe(&self) -> &str {
        &self.description
    }

    pub(crate) fn described(mut self, description: String) -> Track {
        self.description = description;
        self
    }
}

/// The least slack a centre line's band keeps beyond its constraint (m); tighter curves are refused.
const MIN_BAND_MARGIN: f64 = 0.05;

/// The name of the paper's track, the default (`sim.track`).
pub const L_TRACK_BARC: &str = SimSection::L_TRACK_BARC;

/// How a track is sized: its lengths (and widths) multiplied by `scale`, and its constraint's half-width (m, after
/// the scale) when given instead of the file's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Size {
    pub scale: f64,
    pub half_width: Option<f64>,
}

impl Default for Size {
    fn default() -> Self {
        Size {
            scale: 1.0,
            half_width: None,
        }
    }
}

impl Size {
    /// `sim.track_scale` and `sim.track_half_width`.
    pub fn of(sim: &SimSection) -> Size {
        Size {
            scale: sim.track_scale,
            half_width: sim.track_half_width,
        }
    }
}

impl std::fmt::Display for Size {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "scale {}", self.scale)?;
        if let Some(h) = self.half_width {
            write!(f, ", half-width {h} m")?;
        }
        Ok(())
    }
}

fn file_error(file: &str, line: Option<usize>, why: impl Into<String>) -> TrackError {
    TrackError::File {
        file: file.to_string(),
        line,
        why: why.into(),
    }
}

/// The smallest radius the reference car turns (m): its wheelbase over the tangent of its largest steering angle.
pub fn car_min_radius() -> f64 {
    let p = VehicleParams::default();
    (p.lf + p.lr) / ACTION_HIGH[1].tan()
}

/// A track by name (`l-track-barc`, a shipped one) or from a file (`.csv` or `.toml`), its lengths and widths
/// sized by `size`.
pub fn load(name_or_path: &str, size: Size) -> Result<Track, TrackError> {
    let scale = size.scale;
    if !(scale.is_finite() && scale > 0.0) {
        return Err(file_error(
            name_or_path,
            None,
            format!("scale {scale} must be a positive number"),
        ));
    }
    if let Some(h) = size.half_width.filter(|h| !(h.is_finite() && *h > 0.0)) {
        return Err(file_error(
            name_or_path,
            None,
            format!("half-width {h} must be a positive number"),
        ));
    }
    if name_or_path == L_TRACK_BARC && size == Size::default() {
        return Ok(Track::l_track_barc());
    }
    if let Some((_, file, text)) = SHIPPED.iter().find(|s| s.0 == name_or_path) {
        return parse(text, &format!("tracks/{file}"), size);
    }
    let path = Path::new(name_or_path);
    let is_file = matches!(
        path.extension().and_then(|e| e.to_str()),
        Some("csv" | "toml")
    );
    if !is_file {
        if name_or_path == L_TRACK_BARC {
            let pieces = Track::l_track_barc().pieces().to_vec();
            let half_width = size
                .half_width
                .unwrap_or(super::L_TRACK_BARC_HALF_WIDTH * scale);
            return scaled(pieces, half_width, SLACK, scale)
                .map(|t| t.described(format!("the L-shaped BARC track, {size}")));
        }
        return Err(TrackError::UnknownTrack {
            name: name_or_path.to_string(),
            names: SimSection::NAMES.join(", "),
        });
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| file_error(name_or_path, None, e.to_string()))?;
    parse(&text, name_or_path, size)
}

/// A track file's text; `file` names it in errors and decides its format by its extension.
pub fn parse(text: &str, file: &str, size: Size) -> Result<Track, TrackError> {
    if file.ends_with(".csv") {
        centre_line(text, file, size)
    } else if file.ends_with(".toml") {
        pieces(text, file, size)
    } else {
        Err(file_error(
            file,
            None,
            "a track file is a centre line (.csv) or a list of pieces (.toml)",
        ))
    }
}

fn scaled(
    pieces: Vec<TrackPiece>,
    half_width: f64,
    slack: f64,
    scale: f64,
) -> Result<Track, TrackError> {
    let pieces = pieces
        .into_iter()
        .map(|p| TrackPiece {
            length: p.length * scale,
            radius: p.radius * scale,
        })
        .collect();
    Track::new(pieces, half_width, slack)
}

/// An F1TENTH centre line: `x_m, y_m, w_tr_right_m, w_tr_left_m` per line, `#` comments, closed.
fn centre_line(text: &str, file: &str, size: Size) -> Result<Track, TrackError> {
    let scale = size.scale;
    let mut points = Vec::new();
    let mut half_width = f64::INFINITY;
    let mut narrowest_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let fields: Vec<&str> = content.split([',', ';']).map(str::trim).collect();
        if fields.len() != 4 {
            return Err(file_error(
                file,
                Some(line),
                format!(
                    "{} fields where a centre line has 4: x_m, y_m, w_tr_right_m, w_tr_left_m",
                    fields.len()
                ),
            ));
        }
        let mut v = [0.0; 4];
        for (slot, (field, name)) in
            v.iter_mut().zip(
                fields
                    .iter()
                    .zip(["x_m", "y_m", "w_tr_right_m", "w_tr_left_m"]),
            )
        {
            *slot = field
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    file_error(
                        file,
                        Some(line),
                        format!("{name} `{field}` is not a number"),
                    )
                })?;
        }
        for (w, side) in [(v[2], "right"), (v[3], "left")] {
            if w.is_nan() || w <= 0.0 {
                return Err(file_error(
                    file,
                    Some(line),
                    format!("the width to the {side} is {w}: a track is wider than 0"),
                ));
            }
        }
        let narrowest = v[2].min(v[3]) * scale;
        if narrowest < half_width {
            (half_width, narrowest_line) = (narrowest, line);
        }
        points.push(CentrePoint {
            x: v[0] * scale,
            y: v[1] * scale,
            line,
        });
    }
    let fitted: Fitted = fit(&points).map_err(|e| file_error(file, e.line, e.why))?;
    let why_narrow = match size.half_width {
        Some(h) => {
            half_width = h;
            "the half-width asked for (sim.track_half_width)".to_string()
        }
        None => format!("the narrowest half-width (line {narrowest_line})"),
    };
    let line_at = |s: f64| Some(fitted.line_at(s));
    // The band beyond the constraint shrinks where a curve is tight: a real circuit's hairpin is about as tight as
    // the track is wide, and the band's inner edge must not fold.
    let tightest = fitted
        .pieces
        .iter()
        .filter(|p| p.radius != 0.0)
        .map(|p| p.radius.abs())
        .fold(f64::INFINITY, f64::min);
    let slack = SLACK.min(MIN_BAND_MARGIN.max(0.9 * (tightest - half_width)));
    checked(
        fitted.pieces.clone(),
        half_width,
        slack,
        file,
        line_at,
        &why_narrow,
    )
    .map(|t| t.described(format!("{file}, {size}")))
}

/// The pieces file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PiecesFile {
    half_width: f64,
    #[serde(default)]
    slack: Option<f64>,
    pieces: Vec<toml::Spanned<PieceToml>>,
}

/// One piece: `{ straight = L }`, `{ arc = L, radius = R }` (arc length L; R > 0 turns left), or `{ turn = D,
/// radius = R }` (D degrees, > 0 left; R > 0).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PieceToml {
    straight: Option<f64>,
    arc: Option<f64>,
    turn: Option<f64>,
    radius: Option<f64>,
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// A list of pieces: `half_width`, an optional `slack`, and `pieces` from the start pose (0, 0, heading +x).
fn pieces(text: &str, file: &str, size: Size) -> Result<Track, TrackError> {
    let scale = size.scale;
    let parsed: PiecesFile = toml::from_str(text).map_err(|e| {
        let line = e.span().map(|s| line_of(text, s.start));
        file_error(file, line, e.message().to_string())
    })?;
    if !(parsed.half_width.is_finite() && parsed.half_width > 0.0) {
        return Err(file_error(
            file,
            None,
            format!("half_width {} must be a positive number", parsed.half_width),
        ));
    }
    let mut out = Vec::with_capacity(parsed.pieces.len());
    let mut lines = Vec::with_capacity(parsed.pieces.len());
    for spanned in &parsed.pieces {
        let line = line_of(text, spanned.span().start);
        let p = spanned.get_ref();
        let bad = |why: &str| Err(file_error(file, Some(line), why.to_string()));
        let piece = match (p.straight, p.arc, p.turn, p.radius) {
            (Some(l), None, None, None) => TrackPiece {
                length: l,
                radius: 0.0,
            },
            (None, Some(l), None, Some(r)) => TrackPiece {
                length: l,
                radius: r,
            },
            (None, None, Some(deg), Some(r)) => {
                if r.is_nan() || r <= 0.0 {
                    return bad("a turn's radius is positive; the turn's sign says left (> 0) or right");
                }
                TrackPiece {
                    length: deg.abs().to_radians() * r,
                    radius: r * deg.signum(),
                }
            }
            _ => {
                return bad(
                    "a piece is { straight = L }, { arc = L, radius = R } or { turn = DEGREES, radius = R }",
                )
            }
        };
        if !(piece.length.is_finite() && piece.length > 0.0 && piece.radius.is_finite())
            || (p.arc.is_some() && piece.radius == 0.0)
        {
            return bad("a piece's length is positive and its radius a number other than 0");
        }
        out.push(TrackPiece {
            length: piece.length * scale,
            radius: piece.radius * scale,
        });
        lines.push(line);
    }
    if out.is_empty() {
        return Err(file_error(file, None, "no pieces"));
    }
    let slack = parsed.slack.unwrap_or(SLACK);
    if !(slack.is_finite() && slack >= 0.0) {
        return Err(file_error(
            file,
            None,
            format!("slack {slack} must be a number >= 0"),
        ));
    }
    let ends: Vec<f64> = out
        .iter()
        .scan(0.0, |s, p| {
            *s += p.length;
            Some(*s)
        })
        .collect();
    let line_at = |s: f64| {
        let i = ends.partition_point(|&e| e <= s).min(lines.len() - 1);
        Some(lines[i])
    };
    let (half_width, why) = match size.half_width {
        Some(h) => (h, "the half-width asked for (sim.track_half_width)"),
        None => (parsed.half_width * scale, "half_width"),
    };
    checked(out, half_width, slack, file, line_at, why)
        .map(|t| t.described(format!("{file}, {size}")))
}

/// The track of `pieces`, refused where the car cannot turn, where a curve is tighter than the Frenet band, or
/// where the track comes back within twice its band of itself (a crossing, or two parts too close to tell apart).
fn checked(
    pieces: Vec<TrackPiece>,
    half_width: f64,
    slack: f64,
    file: &str,
    line_at: impl Fn(f64) -> Option<usize>,
    why_width: &str,
) -> Result<Track, TrackError> {
    let band = half_width + slack;
    let length: f64 = pieces.iter().map(|p| p.length).sum();
    if length > MAX_LENGTH {
        return Err(file_error(
            file,
            None,
            format!(
                "a track of {length:.0} m: at most {MAX_LENGTH:.0} m (sim.track_scale shrinks it)"
            ),
        ));
    }
    let car = car_min_radius();
    let mut s = 0.0;
    for p in &pieces {
        let r = p.radius.abs();
        if p.radius != 0.0 && r <= car.max(band) {
            let why = if r <= car {
                format!("a radius of {r:.3} m near here, tighter than the car turns ({car:.3} m)")
            } else {
                format!(
                    "a radius of {r:.3} m near here, tighter than the track's band: {why_width} {half_width:.3} m \
                     + slack {slack} m (inside a curve the two edges' Frenet frames would fold)"
                )
            };
            return Err(file_error(file, line_at(s + 0.5 * p.length), why));
        }
        s += p.length;
    }
    let starts: Vec<f64> = pieces
        .iter()
        .scan(0.0, |s, p| {
            let start = *s;
            *s += p.length;
            Some(start)
        })
        .collect();
    let track = Track::new(pieces, half_width, slack).map_err(|e| match e {
        TrackError::InvalidPiece { index, reason } => {
            file_error(file, starts.get(index).and_then(|&s| line_at(s)), reason)
        }
        TrackError::NotClosed { gap } => file_error(
            file,
            None,
            format!(
                "the pieces do not close: they end {gap:.4} m from the start (closed is within 1 mm, and the heading \
                 within 1 mrad)"
            ),
        ),
        other => file_error(file, None, other.to_string()),
    })?;
    if let Some((a, b)) = track.comes_back_near() {
        return Err(file_error(
            file,
            line_at(b),
            format!(
                "the track comes back within {:.3} m (twice its band) of itself: here (s = {b:.2} m) and at s = \
                 {a:.2} m{}",
                2.0 * band,
                line_at(a).map(|l| format!(" (line {l})")).unwrap_or_default()
            ),
        ));
    }
    Ok(track)
}
