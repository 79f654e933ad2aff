//! The gym-like racing environment (`BarcEnv`, simulator.md §3), state observations only.
//!
//! Each step clips the action, holds it for [`DT`] = 0.1 s as [`SUBSTEPS`] = 10 sub-steps of 0.01 s (each sub-step
//! `rk4_per_substep` classic RK4 steps, default 1), recomputes the Frenet state after every sub-step, then
//! computes reward, lap trigger and truncation in the reference's order. The camera is separate
//! ([`crate::camera`]); the env only draws the per-reset [`Sun`] so images are reproducible from the seed.
//!
//! Reference quirks (simulator.md §8), matched (M) or fixed (F):
//! 1. (F, documented) Integration: the reference uses adaptive RK45 (rtol 1e-3) per sub-step; we use classic
//!    RK4 (one h = 0.01 step per sub-step by default), within 3e-4 of the check values over 50 steps.
//! 2. (M) The band check (Frenet conversion) runs after every sub-step, the |x_tran| > 0.55 check only at
//!    the 0.1 s step: an excursion beyond 0.55 that returns within a step is not caught.
//! 3. (M) Random spawns cover |x_tran| ≤ 0.85, beyond the 0.55 constraint (≈ 35 % start out of track).
//! 4. (M) On the step whose Frenet conversion fails, integration stops at the failing sub-step (the
//!    reference's exception aborts the sub-step loop); the pose, v and ω are fresh but (s, x_tran, e_psi)
//!    are those of the last successful conversion, and the reward uses the stale s.
//! 5. (F) The reference sets no sun; we draw a random sun per reset as the paper describes (camera only).
//! 6. (F) `info['lap_no']` lags by one on a lap step: [`StepResult::lap_no`] already counts the lap.
//!    Lap time: the reference reports (n + 1)·0.1 s for a lap of n steps (eps_len starts at 1); we record
//!    the true n·0.1 s. The reference's `fastest_lap` (np.max) is not reproduced.
//! 7. (M) ψ in the pose is never wrapped (grows 2π per lap).
//! 8. (F) `reset(options=None)` crashing has no analogue: [`Spawn`] is an enum.
//!
//! The numbers of the plant (dt, sub-steps, truncation limits, the fixed spawn) are the constants below, read by
//! the PID, the MPCC and the actor from here.

use std::fmt;
use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use cabc_proto::messages::EndReason;

use crate::camera::Sun;
use crate::track::{Frenet, Track, TrackError};
use crate::vehicle::{clip_action, Input, State, VehicleParams};
use cabc_proto::config::TrackFeature;

/// Where an episode starts: the run configuration's type, re-exported.
pub use cabc_proto::config::Spawn;

/// The control period (s): one env step, the PID's sampling time and the MPCC's stage length.
pub const DT: f64 = 0.1;
/// Frenet-checked sub-steps per control period (0.01 s each).
pub const SUBSTEPS: usize = 10;
/// Stall: truncate when v_long falls below this (m/s).
pub const MIN_SPEED: f64 = 0.25;
/// Spin: truncate when |e_psi| exceeds this (rad).
pub const MAX_HEADING_ERROR: f64 = std::f64::consts::FRAC_PI_2;
/// Laps after which an episode is truncated (the trainer's 50).
pub const MAX_LAPS: u32 = 50;
/// The evaluation spawn (simulator.md §3.2) in the track frame: s = 0.1, x_tran = 0, e_psi = 0 ...
pub const FIXED_SPAWN: Frenet = Frenet {
    s: 0.1,
    x_tran: 0.0,
    e_psi: 0.0,
};
/// ... at v_long = 0.5 m/s (v_tran = ω = 0).
pub const FIXED_SPAWN_SPEED: f64 = 0.5;

/// The vehicle state q = [v_long, 0, 0, X, Y, ψ] of a car placed at Frenet pose `at` with forward speed `v_long`.
pub fn spawn_state(track: &Track, at: Frenet, v_long: f64) -> State {
    let p = track.local_to_global(at.s, at.x_tran, at.e_psi);
    [v_long, 0.0, 0.0, p.x, p.y, p.psi]
}

/// The vehicle state at the evaluation spawn ([`FIXED_SPAWN`], [`FIXED_SPAWN_SPEED`]).
pub fn fixed_spawn_state(track: &Track) -> State {
    spawn_state(track, FIXED_SPAWN, FIXED_SPAWN_SPEED)
}

/// Why an episode ended (simulator.md §3.6). When several hold, the first of LeftBand, OutOfTrack,
/// MaxLaps, Stall, Spin is reported. Displayed as the protocol's [`EndReason`] ("out-of-track", ...).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Truncation {
    /// |x_tran| > H: the constraint violation ("collision").
    OutOfTrack,
    /// The Frenet conversion failed during the step: the car left the band H + slack.
    LeftBand,
    /// v_long < [`MIN_SPEED`].
    Stall,
    /// |e_psi| > [`MAX_HEADING_ERROR`].
    Spin,
    /// lap_no ≥ max_laps before this step.
    MaxLaps,
}

impl From<Truncation> for EndReason {
    fn from(t: Truncation) -> EndReason {
        match t {
            Truncation::OutOfTrack => EndReason::OutOfTrack,
            Truncation::LeftBand => EndReason::LeftBand,
            Truncation::Stall => EndReason::Stall,
            Truncation::Spin => EndReason::Spin,
            Truncation::MaxLaps => EndReason::MaxLaps,
        }
    }
}

impl fmt::Display for Truncation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        EndReason::from(*self).fmt(f)
    }
}

/// Env constants (simulator.md §3); the defaults are the constants above.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvConfig {
    /// Control period (s).
    pub dt: f64,
    /// Frenet-checked sub-steps per control period.
    pub substeps: usize,
    /// RK4 steps per sub-step (1 → h = 0.01 s).
    pub rk4_per_substep: usize,
    /// Truncate once this many laps are done.
    pub max_laps: u32,
    /// Stall threshold on v_long (m/s).
    pub min_speed: f64,
    /// Spin threshold on |e_psi| (rad).
    pub max_heading_error: f64,
    /// The observed state's fourth entry: s, or the curvature preview over `preview_m` metres.
    pub track_feature: TrackFeature,
    pub preview_m: f64,
}

impl Default for EnvConfig {
    fn default() -> Self {
        EnvConfig {
            dt: DT,
            substeps: SUBSTEPS,
            rk4_per_substep: 1,
            max_laps: MAX_LAPS,
            min_speed: MIN_SPEED,
            max_heading_error: MAX_HEADING_ERROR,
            track_feature: TrackFeature::S,
            preview_m: 1.0,
        }
    }
}

/// What the env reports after a reset or a step (simulator.md §3.1), in f64; the policy's input is built from it.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvObservation {
    /// [v_long, v_tran, ω, s, x_tran, e_psi].
    pub state: [f64; 6],
    /// [X, Y, ψ] with ψ unwrapped.
    pub pose: [f64; 3],
}

#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StepResult {
    pub obs: EnvObservation,
    /// Progress s_new − s_old (m), plus L on the lap step.
    pub reward: f64,
    /// The reference's `terminated`: a lap was just completed (the episode goes on).
    pub lap_completed: bool,
    pub truncation: Option<Truncation>,
    /// Laps completed, including one finished on this step.
    pub lap_no: u32,
    /// The time of the lap finished on this step (n·dt for n steps), if any.
    pub lap_time: Option<f64>,
}

/// One environment. Stepping does not allocate (lap times are pushed only on lap steps).
#[derive(Clone, Debug)]
pub struct Env {
    track: Arc<Track>,
    params: VehicleParams,
    config: EnvConfig,
    q: State,
    frenet: Frenet,
    u: Input,
    t: f64,
    lap_no: u32,
    steps_in_lap: u32,
    steps: u64,
    lap_times: Vec<f64>,
    sun: Sun,
}

impl Env {
    /// A new env, reset to the fixed spawn (call [`Env::reset`] to choose).
    pub fn new(track: Arc<Track>, params: VehicleParams, config: EnvConfig) -> Env {
        let mut env = Env {
            track,
            params,
            config,
            q: [0.0; 6],
            frenet: Frenet::default(),
            u: [0.0; 2],
            t: 0.0,
            lap_no: 0,
            steps_in_lap: 0,
            steps: 0,
            lap_times: Vec::with_capacity(64),
            sun: Sun::default(),
        };
        env.reset_fixed();
        env
    }

    /// The reference setup: `L_track_barc`, default vehicle, default config.
    pub fn barc() -> Env {
        Env::new(
            Arc::new(Track::l_track_barc()),
            VehicleParams::default(),
            EnvConfig::default(),
        )
    }

    /// The RNG stream for env `index` of a run seeded with `seed`.
    pub fn rng(seed: u64, index: u64) -> ChaCha8Rng {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        rng
    }

    /// Start an episode. Random draws: s, x_tran, e_psi, v_long (simulator.md §3.2), then the sun
    /// (azimuth U(0, 2π), elevation U(15°, 75°)); the fixed spawn still draws the sun.
    pub fn reset<R: Rng + ?Sized>(&mut self, spawn: Spawn, rng: &mut R) -> EnvObservation {
        match spawn {
            Spawn::Fixed => self.reset_fixed(),
            Spawn::Random => {
                let band = self.track.band();
                let s = uniform(rng, 0.1, self.track.length() - 2.0);
                let x_tran = uniform(rng, -band, band);
                let e_psi = uniform(
                    rng,
                    -std::f64::consts::FRAC_PI_6,
                    std::f64::consts::FRAC_PI_6,
                );
                let v = uniform(rng, 0.5, 2.0);
                self.set_spawn(s, x_tran, e_psi, v);
            }
        }
        self.sun = Sun::random(rng);
        self.observation()
    }

    fn reset_fixed(&mut self) {
        let at = FIXED_SPAWN;
        self.set_spawn(at.s, at.x_tran, at.e_psi, FIXED_SPAWN_SPEED);
    }

    /// Place the car at a Frenet pose with speed `v_long` (v_tran = ω = 0) and clear the episode counters.
    pub fn set_spawn(&mut self, s: f64, x_tran: f64, e_psi: f64, v_long: f64) {
        let at = Frenet { s, x_tran, e_psi };
        let q = spawn_state(&self.track, at, v_long);
        // Within the band the conversion succeeds; fall back to the requested values otherwise.
        let frenet = self.track.global_to_local(q[3], q[4], q[5]).unwrap_or(at);
        self.place(q, frenet);
    }

    /// Place the car at vehicle state `q` (global frame) and clear the episode counters; outside the band this is
    /// the conversion's error and the env is unchanged.
    pub fn set_state(&mut self, q: State) -> Result<(), TrackError> {
        let frenet = self.track.global_to_local(q[3], q[4], q[5])?;
        self.place(q, frenet);
        Ok(())
    }

    fn place(&mut self, q: State, frenet: Frenet) {
        self.q = q;
        self.frenet = frenet;
        self.u = [0.0; 2];
        self.t = 0.0;
        self.lap_no = 0;
        self.steps_in_lap = 0;
        self.steps = 0;
        self.lap_times.clear();
    }

    /// Advance one control period with `action` (clipped to the box).
    pub fn step(&mut self, action: &Input) -> StepResult {
        let u = clip_action(action);
        self.u = u;
        let (q_old, f_old) = (self.q, self.frenet);
        let h = self.config.dt / self.config.substeps.max(1) as f64;
        let mut left_band = false;
        for _ in 0..self.config.substeps.max(1) {
            self.q = self
                .params
                .step(&self.q, &u, h, self.config.rk4_per_substep);
            match self.track.global_to_local(self.q[3], self.q[4], self.q[5]) {
                Ok(f) => self.frenet = f,
                Err(_) => {
                    // Quirk 4: the reference's exception aborts the sub-step loop here.
                    left_band = true;
                    break;
                }
            }
        }
        self.t += self.config.dt;
        self.steps += 1;
        self.steps_in_lap += 1;

        let f = self.frenet;
        let lap_completed = f.s < f_old.s
            && self
                .track
                .crosses_start_line((q_old[3], q_old[4]), (self.q[3], self.q[4]));
        let mut reward = f.s - f_old.s;
        if lap_completed {
            reward += self.track.length();
        }
        let truncation = if left_band {
            Some(Truncation::LeftBand)
        } else if f.x_tran.abs() > self.track.half_width() {
            Some(Truncation::OutOfTrack)
        } else if self.lap_no >= self.config.max_laps {
            Some(Truncation::MaxLaps)
        } else if self.q[0] < self.config.min_speed {
            Some(Truncation::Stall)
        } else if f.e_psi.abs() > self.config.max_heading_error {
            Some(Truncation::Spin)
        } else {
            None
        };
        let mut lap_time = None;
        if lap_completed {
            let lt = self.steps_in_lap as f64 * self.config.dt;
            self.lap_no += 1;
            self.lap_times.push(lt);
            self.steps_in_lap = 0;
            lap_time = Some(lt);
        }
        StepResult {
            obs: self.observation(),
            reward,
            lap_completed,
            truncation,
            lap_no: self.lap_no,
            lap_time,
        }
    }

    pub fn observation(&self) -> EnvObservation {
        let (q, f) = (&self.q, &self.frenet);
        let fourth = match self.config.track_feature {
            TrackFeature::S => f.s,
            TrackFeature::CurvaturePreview => self.track.mean_curvature(f.s, self.config.preview_m),
        };
        EnvObservation {
            state: [q[0], q[1], q[2], fourth, f.x_tran, f.e_psi],
            pose: [q[3], q[4], q[5]],
        }
    }

    /// The full ground-truth vehicle state q = [v_x, v_y, ω, X, Y, ψ] (the reference's `info['vehicle_state']`).
    pub fn vehicle_state(&self) -> State {
        self.q
    }

    pub fn frenet(&self) -> Frenet {
        self.frenet
    }

    /// The last applied (clipped) action.
    pub fn last_action(&self) -> Input {
        self.u
    }

    /// Simulated time since reset (s).
    pub fn time(&self) -> f64 {
        self.t
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    pub fn lap_no(&self) -> u32 {
        self.lap_no
    }

    /// Completed lap times (s), the first measured from the spawn.
    pub fn lap_times(&self) -> &[f64] {
        &self.lap_times
    }

    /// The sun drawn at the last reset (for the camera).
    pub fn sun(&self) -> Sun {
        self.sun
    }

    pub fn track(&self) -> &Arc<Track> {
        &self.track
    }

    pub fn params(&self) -> &VehicleParams {
        &self.params
    }

    pub fn config(&self) -> &EnvConfig {
        &self.config
    }
}

/// numpy's `np.random.uniform(a, b)` form: a + (b − a)·U[0, 1).
fn uniform<R: Rng + ?Sized>(rng: &mut R, a: f64, b: f64) -> f64 {
    a + (b - a) * rng.gen::<f64>()
}

#[derive(thiserror::Error, Debug, Clone, PartialEq, Eq)]
pub enum EnvError {
    #[error("expected at most {expected} actions (one per env), got {got}")]
    BatchSize { expected: usize, got: usize },
    #[error("env index {index} out of range (batch of {len})")]
    Index { index: usize, len: usize },
}

/// K environments sharing one track, env i drawing from RNG stream (seed, first_stream + i). Resetting after a
/// truncation is the caller's choice ([`EnvBatch::reset_one`]).
#[derive(Clone, Debug)]
pub struct EnvBatch {
    envs: Vec<Env>,
    rngs: Vec<ChaCha8Rng>,
    results: Vec<StepResult>,
}

impl EnvBatch {
    /// K envs on streams 0..K of `seed`.
    pub fn new(
        track: Arc<Track>,
        params: VehicleParams,
        config: EnvConfig,
        k: usize,
        seed: u64,
    ) -> EnvBatch {
        EnvBatch::with_streams(track, params, config, seed, 0..k as u64)
    }

    /// One env per stream of `seed` in `streams` (so that several batches of one run draw distinct spawns).
    pub fn with_streams(
        track: Arc<Track>,
        params: VehicleParams,
        config: EnvConfig,
        seed: u64,
        streams: std::ops::Range<u64>,
    ) -> EnvBatch {
        let rngs: Vec<ChaCha8Rng> = streams.map(|i| Env::rng(seed, i)).collect();
        let envs = rngs
            .iter()
            .map(|_| Env::new(track.clone(), params.clone(), config.clone()))
            .collect();
        EnvBatch {
            envs,
            results: vec![StepResult::default(); rngs.len()],
            rngs,
        }
    }

    pub fn len(&self) -> usize {
        self.envs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.envs.is_empty()
    }

    pub fn envs(&self) -> &[Env] {
        &self.envs
    }

    pub fn env(&self, i: usize) -> Option<&Env> {
        self.envs.get(i)
    }

    pub fn reset_all(&mut self, spawn: Spawn) -> Vec<EnvObservation> {
        self.envs
            .iter_mut()
            .zip(self.rngs.iter_mut())
            .map(|(e, r)| e.reset(spawn, r))
            .collect()
    }

    pub fn reset_one(&mut self, i: usize, spawn: Spawn) -> Result<EnvObservation, EnvError> {
        let len = self.envs.len();
        match (self.envs.get_mut(i), self.rngs.get_mut(i)) {
            (Some(e), Some(r)) => Ok(e.reset(spawn, r)),
            _ => Err(EnvError::Index { index: i, len }),
        }
    }

    /// Step env i with `actions[i]` for the first `actions.len()` envs (the rest wait: a step budget can end
    /// mid-batch); the results live in a buffer reused across calls.
    pub fn step(&mut self, actions: &[Input]) -> Result<&[StepResult], EnvError> {
        self.step_from(0, actions)
    }

    /// Step env `first + i` with `actions[i]` (the others wait: the actor steps its environments in halves); the
    /// results, in that order, live in a buffer reused across calls.
    pub fn step_from(
        &mut self,
        first: usize,
        actions: &[Input],
    ) -> Result<&[StepResult], EnvError> {
        let len = self.envs.len();
        if first > len || actions.len() > len - first {
            return Err(EnvError::BatchSize {
                expected: len.saturating_sub(first),
                got: actions.len(),
            });
        }
        for ((env, a), out) in self.envs[first..]
            .iter_mut()
            .zip(actions)
            .zip(self.results.iter_mut())
        {
            *out = env.step(a);
        }
        Ok(&self.results[..actions.len()])
    }
}
