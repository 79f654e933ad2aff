//! One environment as Gymnasium sees it: the simulator's [`Env`] with its own random stream, the spawn, an optional
//! step limit, and the simulator's end of an episode split into Gymnasium's `terminated` and `truncated`.

use std::str::FromStr;
use std::sync::{Arc, Mutex, OnceLock};

use cabc_proto::config::SimSection;
use cabc_proto::messages::{image_bytes, EndReason};
use cabc_sim::camera::{Camera, TrackLookup, REFERENCE_FOV_DEG, REFERENCE_SIZE};
use cabc_sim::track::Pose;
use cabc_sim::{Env, EnvConfig, EnvObservation, Input, Spawn, Track, Truncation};
use pyo3::exceptions::PyValueError;
use pyo3::PyResult;
use rand_chacha::ChaCha8Rng;

/// The `sim` section of the keyword arguments `track`, `track_scale`, `track_half_width` (the L-track, scale 1, its
/// own half-width when not given). A relative file is taken from the working directory now, so that the
/// per-process cache of tracks ([`Track::of`], by name) does not mistake it for another file after a `chdir`.
pub fn sim_section(
    track: Option<&str>,
    track_scale: Option<f64>,
    track_half_width: Option<f64>,
) -> SimSection {
    let mut sim = SimSection {
        track: track.unwrap_or(SimSection::L_TRACK_BARC).to_string(),
        track_scale: track_scale.unwrap_or(1.0),
        track_half_width,
        actor_tracks: Vec::new(),
    };
    if let Ok(cwd) = std::env::current_dir() {
        sim.resolve(&cwd);
    }
    sim
}

/// The track `sim` names, built once per process ([`Track::of`]); a bad one is a `ValueError` with the track's
/// error (the file and line of a bad file).
pub fn track_of(sim: &SimSection) -> PyResult<Arc<Track>> {
    Track::of(sim).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// A track and the camera's distance grid of it, built on the first frame of a camera on that track and shared by
/// every environment on the same track (one grid per track and process).
#[derive(Clone, Debug)]
pub struct Road {
    pub track: Arc<Track>,
    lookup: Arc<OnceLock<TrackLookup>>,
}

impl Road {
    /// The road of the track `sim` names.
    pub fn of(sim: &SimSection) -> PyResult<Road> {
        type Lookups = Mutex<Vec<(Arc<Track>, Arc<OnceLock<TrackLookup>>)>>;
        static LOOKUPS: OnceLock<Lookups> = OnceLock::new();
        let track = track_of(sim)?;
        let mut lookups = LOOKUPS
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        // Track::of hands out one Arc per track and keeps it for the process, so the pointer names the track.
        let lookup = match lookups.iter().find(|(t, _)| Arc::ptr_eq(t, &track)) {
            Some((_, l)) => l.clone(),
            None => {
                let l = Arc::new(OnceLock::new());
                lookups.push((track.clone(), l.clone()));
                l
            }
        };
        Ok(Road { track, lookup })
    }

    /// The camera's distance grid (built here on the first call for this track).
    pub fn lookup(&self) -> &TrackLookup {
        /// Grid resolution (m): the actor's.
        const LOOKUP_RESOLUTION: f64 = 0.01;
        self.lookup
            .get_or_init(|| TrackLookup::new(&self.track, LOOKUP_RESOLUTION))
    }
}

/// The bounds of the state observation [v_long, v_tran, ω, s, x_tran, e_psi] on `track`: the velocities are
/// unbounded; s lies on the centreline [0, L]; x_tran within the Frenet band (the simulator keeps the last value
/// inside it); e_psi in [-π, π].
pub fn state_bounds(track: &Track) -> ([f64; 6], [f64; 6]) {
    let (inf, pi) = (f64::INFINITY, std::f64::consts::PI);
    let (band, length) = (track.band(), track.length());
    (
        [-inf, -inf, -inf, 0.0, -band, -pi],
        [inf, inf, inf, length, band, pi],
    )
}

/// What the environment observes: the 6-d state, or a camera image with the three velocities.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    State,
    Camera,
}

impl FromStr for Kind {
    type Err = pyo3::PyErr;

    fn from_str(s: &str) -> PyResult<Kind> {
        match s {
            "state" => Ok(Kind::State),
            "camera" => Ok(Kind::Camera),
            _ => Err(PyValueError::new_err(format!(
                "unknown observation {s:?}: expected \"state\" or \"camera\""
            ))),
        }
    }
}

pub fn parse_spawn(s: &str) -> PyResult<Spawn> {
    Spawn::from_str(s).map_err(PyValueError::new_err)
}

/// The camera's size and field of view.
#[derive(Clone, Copy, Debug)]
pub struct Lens {
    pub width: usize,
    pub height: usize,
    pub fov_deg: f64,
}

impl Lens {
    /// `width` x `height` (each 1..=1024, the reference's 224 when not given), `fov_deg` (the reference's 110°).
    pub fn new(
        width: Option<usize>,
        height: Option<usize>,
        fov_deg: Option<f64>,
    ) -> PyResult<Lens> {
        let side = |v: Option<usize>, name: &str| match v.unwrap_or(REFERENCE_SIZE) {
            v @ 1..=1024 => Ok(v),
            v => Err(PyValueError::new_err(format!(
                "{name} must be within 1..=1024 pixels, got {v}"
            ))),
        };
        let fov_deg = fov_deg.unwrap_or(REFERENCE_FOV_DEG);
        if !(fov_deg.is_finite() && (1.0..=179.0).contains(&fov_deg)) {
            return Err(PyValueError::new_err(format!(
                "fov must be within 1..=179 degrees, got {fov_deg}"
            )));
        }
        Ok(Lens {
            width: side(width, "width")?,
            height: side(height, "height")?,
            fov_deg,
        })
    }

    pub fn camera(&self) -> Camera {
        Camera::new(self.width, self.height, self.fov_deg)
    }

    /// Bytes of one RGB image.
    pub fn image_len(&self) -> usize {
        image_bytes(self.width, self.height)
    }
}

/// Renders `env`'s first-person view of `road` into `out` (`lens.image_len()` bytes, HWC RGB).
pub fn see(camera: &mut Camera, road: &Road, env: &Env, out: &mut [u8]) {
    let [x, y, psi] = env.observation().pose;
    let frame = camera.render(road.lookup(), Pose { x, y, psi }, env.sun());
    out.copy_from_slice(&frame.rgb);
}

/// How the environments of one Python object are made.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The track the environments drive, and its camera grid.
    pub road: Road,
    pub spawn: Spawn,
    pub max_laps: u32,
    /// Truncate after this many steps (Gymnasium's time limit; the simulator has none).
    pub max_episode_steps: Option<u64>,
}

impl Setup {
    /// `sim`: the track (see [`sim_section`]).
    pub fn new(
        sim: &SimSection,
        spawn: &str,
        max_laps: Option<u32>,
        max_episode_steps: Option<u64>,
    ) -> PyResult<Setup> {
        if max_episode_steps == Some(0) {
            return Err(PyValueError::new_err(
                "max_episode_steps must be at least 1",
            ));
        }
        Ok(Setup {
            road: Road::of(sim)?,
            spawn: parse_spawn(spawn)?,
            max_laps: max_laps.unwrap_or(cabc_sim::env::MAX_LAPS),
            max_episode_steps,
        })
    }

    pub fn env(&self) -> Env {
        let config = EnvConfig {
            max_laps: self.max_laps,
            ..EnvConfig::default()
        };
        Env::new(self.road.track.clone(), Default::default(), config)
    }
}

/// One step as Gymnasium reports it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Transition {
    /// Progress along the centreline (m), the simulator's reward.
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    /// Why the episode ended, when it did.
    pub end: Option<EndReason>,
    /// The time of a lap completed on this step (s).
    pub lap_time: Option<f64>,
    /// Laps of the episode, including one completed on this step.
    pub laps: u32,
}

/// Gymnasium's split of the simulator's end of an episode: leaving the track (the constraint, |x_tran| > 0.55, or
/// the Frenet band) is a terminal state of the task, *terminated*; the simulator's other limits (stall, spin, the
/// lap count) and the optional step limit cut an episode that could go on, *truncated*.
pub fn classify(
    truncation: Option<Truncation>,
    steps: u64,
    limit: Option<u64>,
) -> (bool, bool, Option<EndReason>) {
    match truncation {
        Some(t @ (Truncation::OutOfTrack | Truncation::LeftBand)) => (true, false, Some(t.into())),
        Some(t) => (false, true, Some(t.into())),
        None if limit.is_some_and(|l| steps >= l) => (false, true, Some(EndReason::Budget)),
        None => (false, false, None),
    }
}

/// One environment with its random stream.
#[derive(Clone, Debug)]
pub struct Car {
    pub env: Env,
    rng: ChaCha8Rng,
}

impl Car {
    /// An environment drawing from stream `stream` of `seed` (as `cabc-sim rollout --seed` and the actors' batches).
    pub fn new(setup: &Setup, seed: u64, stream: u64) -> Car {
        Car {
            env: setup.env(),
            rng: Env::rng(seed, stream),
        }
    }

    /// Starts drawing from stream `stream` of `seed`.
    pub fn reseed(&mut self, seed: u64, stream: u64) {
        self.rng = Env::rng(seed, stream);
    }

    pub fn reset(&mut self, spawn: Spawn) -> EnvObservation {
        self.env.reset(spawn, &mut self.rng)
    }

    /// Steps with a finite action (the caller checks; the simulator clips it to the box).
    pub fn step(&mut self, action: &Input, setup: &Setup) -> Transition {
        let r = self.env.step(action);
        let (terminated, truncated, end) =
            classify(r.truncation, self.env.steps(), setup.max_episode_steps);
        Transition {
            reward: r.reward,
            terminated,
            truncated,
            end,
            lap_time: r.lap_time,
            laps: r.lap_no,
        }
    }
}
