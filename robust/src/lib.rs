//! cabc-robust, `cabc robust`: a policy's robustness, beyond the fixed spawn of its evaluation (issue 45 item 3). Its
//! own crate (issue 67): one job, the study and its report and figure ([`study_policy_file`] for a run folder's
//! policy), over the evaluator's loop of `cabc-actor`; not in the actor, which every machine of a run starts, because
//! of its figure (plotters) and intervals.
//!
//! A seeded draw of N spawns along the track ([`draw_spawns`], in `cabc-actor`, where the early stop's episodes
//! draw theirs too): arc length s ~ U(0, L), lateral offset x_tran ~ U(-f H, f H) for a fraction f of the half width
//! H, heading error e_psi ~ U(-h, h), speed v_long ~ U(v0, v1).
//!
//! Each spawn is driven at each noise level by the evaluator's own loop ([`cabc_actor::evaluate::drive`]): the policy
//! alone, the run's observation and sensor, plus Gaussian noise on the action before the plant clips it and on the
//! state the policy observes, `level` times the given deviations. Every level drives the same spawns under the same
//! suns, and the noise of spawn i is the same draws scaled by the level, so levels compare pairwise.
//!
//! An episode wants `laps` full laps after its out-lap (the stretch from the spawn to the start line, counted by the
//! env as its first lap and left out of the laps and lap times reported here): it ends when they are done, at the
//! env's truncation, or at the evaluator's step limit. A crash is an end by the env's truncation (out of track, out of
//! the band, stall, spin); the report counts every end reason.

pub mod figure;

use cabc_actor::collect::Observations;
use cabc_actor::evaluate::{drive, Disturbance, Episode, Start};
pub use cabc_actor::spawns::{draw_spawns, SpawnPoint, SpawnRanges};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EndReason, EvalReport};
use cabc_sim::env::Env;
use cabc_sim::track::{Frenet, Track};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Mixed into the seed for the noise's streams (stream i: spawn i).
const NOISE_SEED: u64 = 0x4e_0153;
/// Laps wanted when the run's configuration asks for none.
const DEFAULT_LAPS: u32 = 2;

/// `cabc robust`'s options of the study (the run folder and the policy are the caller's).
#[derive(Clone, Debug, clap::Args)]
pub struct RobustOptions {
    /// Random spawns along the track; each is driven at every level.
    #[arg(long, default_value_t = 100)]
    pub spawns: usize,
    /// The seed of the spawns, the suns, the sensor's and the added noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Standard deviation of the Gaussian noise added to the action [a (m/s^2), delta (rad)] before clipping: one
    /// value for both, or two.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0",
        allow_negative_numbers = true
    )]
    pub action_noise: Vec<f64>,
    /// Standard deviation of the Gaussian noise added to the observed state [v_long, v_tran, omega, s, x_tran,
    /// e_psi]: one value for every dimension, or six.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0",
        allow_negative_numbers = true
    )]
    pub state_noise: Vec<f64>,
    /// Full laps wanted after the out-lap (default: the run's collection.eval_laps, or 2 when it is 0).
    #[arg(long)]
    pub laps: Option<u32>,
    /// The noise levels, multiples of --action-noise and --state-noise: one row of the report each (0: none).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,1",
        allow_negative_numbers = true
    )]
    pub levels: Vec<f64>,
    /// Lateral offset of the spawns: uniform within this fraction of the half width.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub lateral: f64,
    /// Heading error of the spawns (rad): uniform within plus or minus this.
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    pub heading: f64,
    /// Speed of the spawns, v_long (m/s): one value, or MIN,MAX (uniform; the training spawn's range by default).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.5,2",
        allow_negative_numbers = true
    )]
    pub speed: Vec<f64>,
}

impl Default for RobustOptions {
    fn default() -> Self {
        RobustOptions {
            spawns: 100,
            seed: 1,
            action_noise: vec![0.0],
            state_noise: vec![0.0],
            laps: None,
            levels: vec![0.0, 1.0],
            lateral: 0.5,
            heading: 0.1,
            speed: vec![0.5, 2.0],
        }
    }
}

#[derive(thiserror::Error, Debug)]
pub enum RobustError {
    #[error("the track (sim.track): {0}")]
    Track(#[from] cabc_sim::TrackError),
    #[error("--{flag}: {message}")]
    Flag { flag: &'static str, message: String },
    #[error("spawn {spawn} at noise level {level}: {message}")]
    Drive {
        spawn: usize,
        level: f64,
        message: String,
    },
    #[error("drawing {path}: {message}")]
    Figure { path: String, message: String },
    #[error(
        "no policy file {path} (--policy is best, final or a .safetensors file; a run writes best-policy.safetensors \
         at its first evaluation and final-policy.safetensors at its end)", path = .path.display()
    )]
    NoPolicyFile { path: PathBuf },
    #[error("the policy {path}: {message}", path = .path.display())]
    Policy { path: PathBuf, message: String },
    #[error("writing {path}: {source}", path = .path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

fn flag(flag: &'static str, message: impl Into<String>) -> RobustError {
    RobustError::Flag {
        flag,
        message: message.into(),
    }
}

/// How one spawn's episode ended at one level.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    pub end: String,
    pub crashed: bool,
    /// Full laps (the out-lap left out).
    pub laps: u32,
    pub steps: u64,
}

/// Lap times (s) of the full laps of a level's episodes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LapTimes {
    pub laps: usize,
    pub mean: f64,
    pub std: f64,
    pub min: f64,
    pub max: f64,
}

/// One noise level's episodes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LevelReport {
    /// The multiple of the given deviations.
    pub level: f64,
    pub action_std: [f64; 2],
    pub state_std: [f64; 6],
    pub episodes: usize,
    /// Episodes ended by the env's truncation (out of track, out of the band, stall, spin).
    pub crashes: usize,
    pub crash_share: f64,
    /// The Wilson score 95 % interval of the crash share.
    pub crash_share_95: [f64; 2],
    /// Episodes that drove every lap wanted.
    pub completed: usize,
    /// Episodes by end reason.
    pub end_reasons: BTreeMap<String, usize>,
    /// Full laps per episode, and over all.
    pub laps_mean: f64,
    pub laps_total: u64,
    /// Over every full lap of the level's episodes; null without one.
    pub lap_time: Option<LapTimes>,
    /// Mean steps (0.1 s each) of the crashed episodes; null without a crash.
    pub steps_before_crash_mean: Option<f64>,
    /// Per spawn, in the order of [`RobustReport::spawn_points`] (robust.json only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub outcomes: Vec<Outcome>,
}

/// What `cabc robust` measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobustReport {
    /// The policy driven (its file).
    pub policy: String,
    /// The track driven, in words (`cabc robust --track`: another than the run's).
    #[serde(default)]
    pub track: String,
    pub seed: u64,
    pub spawns: usize,
    /// Full laps wanted per episode.
    pub laps: u32,
    pub spawn: SpawnRanges,
    /// The deviations at level 1.
    pub action_noise: [f64; 2],
    pub state_noise: [f64; 6],
    pub levels: Vec<LevelReport>,
    /// The spawns drawn (robust.json only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub spawn_points: Vec<SpawnPoint>,
}

impl RobustReport {
    /// The report without its per-spawn lists (spawn points, outcomes): what `cabc robust` prints.
    pub fn summary(&self) -> RobustReport {
        let mut summary = self.clone();
        summary.spawn_points.clear();
        for level in &mut summary.levels {
            level.outcomes.clear();
        }
        summary
    }
}

/// The options checked and resolved against the run's configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub spawns: usize,
    pub seed: u64,
    pub laps: u32,
    pub spawn: SpawnRanges,
    pub action_noise: [f64; 2],
    pub state_noise: [f64; 6],
    pub levels: Vec<f64>,
}

impl RobustOptions {
    /// Checks every value (finite, not negative, the right counts) and resolves the defaults from `config`.
    pub fn settings(&self, config: &RunConfig) -> Result<Settings, RobustError> {
        if self.spawns == 0 {
            return Err(flag("spawns", "at least one spawn is needed"));
        }
        let action_noise: [f64; 2] = widen("action-noise", &self.action_noise)?;
        let state_noise: [f64; 6] = widen("state-noise", &self.state_noise)?;
        if self.levels.is_empty() {
            return Err(flag("levels", "at least one level is needed"));
        }
        for &level in &self.levels {
            non_negative("levels", level)?;
        }
        let lateral = non_negative("lateral", self.lateral)?;
        if lateral > 1.0 {
            return Err(flag(
                "lateral",
                format!("{lateral} is beyond the track's edge (a fraction of the half width, at most 1)"),
            ));
        }
        let heading = non_negative("heading", self.heading)?;
        if heading >= cabc_sim::env::MAX_HEADING_ERROR {
            return Err(flag(
                "heading",
                format!("{heading} rad spawns a car the env counts as spun (|e_psi| > pi/2)"),
            ));
        }
        let speed = match self.speed[..] {
            [v] => [v, v],
            [v0, v1] => [v0, v1],
            _ => return Err(flag("speed", "one speed, or MIN,MAX")),
        };
        for v in speed {
            non_negative("speed", v)?;
            if v < cabc_sim::env::MIN_SPEED {
                return Err(flag(
                    "speed",
                    format!(
                        "{v} m/s is below the stall limit {} m/s",
                        cabc_sim::env::MIN_SPEED
                    ),
                ));
            }
        }
        if speed[0] > speed[1] {
            return Err(flag(
                "speed",
                format!("MIN {} above MAX {}", speed[0], speed[1]),
            ));
        }
        let laps = match self.laps {
            Some(0) => return Err(flag("laps", "at least one lap is needed")),
            Some(laps) => laps,
            None if config.collection.eval_laps == 0 => DEFAULT_LAPS,
            None => config.collection.eval_laps,
        };
        Ok(Settings {
            spawns: self.spawns,
            seed: self.seed,
            laps,
            spawn: SpawnRanges {
                lateral_fraction: lateral,
                heading_error: heading,
                speed,
            },
            action_noise,
            state_noise,
            levels: self.levels.clone(),
        })
    }
}

fn non_negative(name: &'static str, x: f64) -> Result<f64, RobustError> {
    if !x.is_finite() || x < 0.0 {
        return Err(flag(name, format!("{x} is not a finite number >= 0")));
    }
    Ok(x)
}

/// One value for every entry, or one per entry.
fn widen<const N: usize>(name: &'static str, values: &[f64]) -> Result<[f64; N], RobustError> {
    for &x in values {
        non_negative(name, x)?;
    }
    match values {
        [x] => Ok([*x; N]),
        v if v.len() == N => Ok(std::array::from_fn(|i| v[i])),
        v => Err(flag(
            name,
            format!("{} values given: one for every entry, or {N}", v.len()),
        )),
    }
}

/// Whether an episode that ended so crashed: an end by the env's truncation other than its lap limit.
pub fn is_crash(end: EndReason) -> bool {
    matches!(
        end,
        EndReason::OutOfTrack | EndReason::LeftBand | EndReason::Stall | EndReason::Spin
    )
}

/// Drives every spawn at every level with `act` (the policy, or any driver of the same observations) under `config`'s
/// observation and sensor; `policy` names it in the report.
pub fn study(
    config: &RunConfig,
    settings: &Settings,
    policy: &str,
    mut act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
) -> Result<RobustReport, RobustError> {
    let track = Track::of(&config.sim)?;
    let spawns = draw_spawns(&track, settings.spawns, settings.seed, &settings.spawn);
    let mut levels = Vec::with_capacity(settings.levels.len());
    for &level in &settings.levels {
        let action_std = settings.action_noise.map(|s| s * level);
        let state_std = settings.state_noise.map(|s| s * level);
        let noisy = action_std.iter().chain(&state_std).any(|&s| s > 0.0);
        let mut reports = Vec::with_capacity(spawns.len());
        for (i, spawn) in spawns.iter().enumerate() {
            let episode = Episode {
                // The out-lap, then the laps wanted.
                laps: settings.laps + 1,
                start: Start::At {
                    pose: Frenet {
                        s: spawn.s,
                        x_tran: spawn.x_tran,
                        e_psi: spawn.e_psi,
                    },
                    v_long: spawn.v_long,
                },
                seed: settings.seed,
                stream: i as u64,
                disturbance: noisy.then(|| Disturbance {
                    action_std,
                    state_std,
                    rng: Env::rng(settings.seed ^ NOISE_SEED, i as u64),
                }),
            };
            let report = drive("robust", 0, config, episode, &mut act, |_| {}).map_err(|e| {
                RobustError::Drive {
                    spawn: i,
                    level,
                    message: format!("{e:#}"),
                }
            })?;
            reports.push(report);
        }
        levels.push(level_report(level, action_std, state_std, &reports));
    }
    Ok(RobustReport {
        policy: policy.to_string(),
        track: track.describe().to_string(),
        seed: settings.seed,
        spawns: settings.spawns,
        laps: settings.laps,
        spawn: settings.spawn.clone(),
        action_noise: settings.action_noise,
        state_noise: settings.state_noise,
        levels,
        spawn_points: spawns,
    })
}

/// A level's summary of its episodes' reports (their first lap is the out-lap).
fn level_report(
    level: f64,
    action_std: [f64; 2],
    state_std: [f64; 6],
    reports: &[EvalReport],
) -> LevelReport {
    let outcomes: Vec<Outcome> = reports
        .iter()
        .map(|r| Outcome {
            end: r.end_reason.to_string(),
            crashed: is_crash(r.end_reason),
            laps: r.laps.saturating_sub(1),
            steps: r.steps,
        })
        .collect();
    let episodes = outcomes.len();
    let crashes = outcomes.iter().filter(|o| o.crashed).count();
    let mut end_reasons = BTreeMap::new();
    for o in &outcomes {
        *end_reasons.entry(o.end.clone()).or_insert(0) += 1;
    }
    let laps_total: u64 = outcomes.iter().map(|o| o.laps as u64).sum();
    let lap_times: Vec<f64> = reports
        .iter()
        .flat_map(|r| r.lap_times.iter().skip(1).copied())
        .collect();
    let lap_time = cabc_proto::stats::mean_std(&lap_times).map(|(mean, std)| LapTimes {
        laps: lap_times.len(),
        mean,
        std,
        min: lap_times.iter().copied().fold(f64::INFINITY, f64::min),
        max: lap_times.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    });
    let crash_steps: Vec<f64> = outcomes
        .iter()
        .filter(|o| o.crashed)
        .map(|o| o.steps as f64)
        .collect();
    let (lo, hi) = cabc_analysis::stats::wilson_95(crashes, episodes).unwrap_or((0.0, 1.0));
    LevelReport {
        level,
        action_std,
        state_std,
        episodes,
        crashes,
        crash_share: if episodes == 0 {
            0.0
        } else {
            crashes as f64 / episodes as f64
        },
        crash_share_95: [lo, hi],
        completed: reports
            .iter()
            .filter(|r| r.end_reason == EndReason::MaxLaps)
            .count(),
        end_reasons,
        laps_mean: if episodes == 0 {
            0.0
        } else {
            laps_total as f64 / episodes as f64
        },
        laps_total,
        lap_time,
        steps_before_crash_mean: cabc_proto::stats::mean(&crash_steps),
        outcomes,
    }
}

/// The policy file `which` names for the run folder `run`: `best` (RUN/best-policy.safetensors), `final`
/// (RUN/final-policy.safetensors), or a file's path.
pub fn policy_path(run: &Path, which: &str) -> PathBuf {
    use cabc_outputs::rundir::{KeptPolicy, RunDir};
    match KeptPolicy::named(which) {
        Some(kept) => run.join(RunDir::policy_file(kept)),
        None => PathBuf::from(which),
    }
}

/// What [`study_policy_file`] wrote: the report (every spawn and its outcome per level) and its figure.
pub struct Written {
    pub report: RobustReport,
    pub json: PathBuf,
    pub png: PathBuf,
}

/// The policy in the safetensors file `policy` (of `config`'s architecture) driven on the CPU as [`study`] says;
/// the report written to `out/robust.json`, its figure to `out/robust.png`.
pub fn study_policy_file(
    config: &RunConfig,
    settings: &Settings,
    policy: &Path,
    out: &Path,
) -> Result<Written, RobustError> {
    let refused = |message: String| RobustError::Policy {
        path: policy.to_path_buf(),
        message,
    };
    if !policy.is_file() {
        return Err(RobustError::NoPolicyFile {
            path: policy.to_path_buf(),
        });
    }
    let net = cabc_outputs::rundir::load_policy(policy).map_err(|e| refused(e.to_string()))?;
    let report = study(config, settings, &policy.display().to_string(), |input| {
        Ok(cabc_actor::run::act(&net, input)?)
    })?;
    let write = |path: PathBuf, bytes: Vec<u8>| {
        std::fs::write(&path, bytes)
            .map(|()| path.clone())
            .map_err(|source| RobustError::Write { path, source })
    };
    std::fs::create_dir_all(out).map_err(|source| RobustError::Write {
        path: out.to_path_buf(),
        source,
    })?;
    let text = serde_json::to_string_pretty(&report).map_err(|e| RobustError::Write {
        path: out.join("robust.json"),
        source: std::io::Error::other(e),
    })?;
    let json = write(out.join("robust.json"), (text + "\n").into_bytes())?;
    let png = out.join("robust.png");
    figure::draw(&png, Track::of(&config.sim)?.as_ref(), &report)?;
    Ok(Written { report, json, png })
}
