//! One episode on a track (`L_track_barc` unless the configuration names another) under a simple policy (the PID lane follower or a constant action), summarised:
//! the library behind `cabc-sim rollout`.

use std::fmt;
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context, Result};

use crate::env::{Env, EnvConfig, Spawn, Truncation};
use crate::pid::PidLaneFollower;
use crate::trace::{Row, TraceWriter};
use crate::track::Track;
use crate::vehicle::Input;

/// What drives a rollout.
pub enum RolloutPolicy {
    Pid(Box<PidLaneFollower>),
    Const(Input),
}

impl RolloutPolicy {
    /// "pid", "zero" or "const:A,S" (acceleration m/s², steering rad).
    pub fn parse(s: &str) -> Result<RolloutPolicy> {
        match s {
            "pid" => Ok(RolloutPolicy::Pid(Box::default())),
            "zero" => Ok(RolloutPolicy::Const([0.0, 0.0])),
            _ => match s.strip_prefix("const:") {
                Some(rest) => {
                    let (a, d) = parse_pair(rest).with_context(|| format!("bad policy {s:?}"))?;
                    Ok(RolloutPolicy::Const([a, d]))
                }
                None => bail!("unknown policy {s:?}: expected pid, zero or const:A,S"),
            },
        }
    }

    fn action(&mut self, state: &[f64; 6]) -> Input {
        match self {
            RolloutPolicy::Pid(p) => p.action(state[0], state[4], state[5]),
            RolloutPolicy::Const(u) => *u,
        }
    }
}

/// An image size "WxH" (command-line arguments), each side within 1..=8192.
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("expected a size \"WxH\", got {s:?}"))?;
    let w: usize = w
        .trim()
        .parse()
        .with_context(|| format!("bad width {w:?}"))?;
    let h: usize = h
        .trim()
        .parse()
        .with_context(|| format!("bad height {h:?}"))?;
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        bail!("image size must be within 1..=8192 on each side, got {w}x{h}");
    }
    Ok((w, h))
}

/// Parses a sun direction "AZ,EL" in degrees (`cabc-sim render --sun`).
pub fn parse_sun(s: &str) -> Result<crate::camera::Sun> {
    let (az, el) = parse_pair(s).context("bad --sun (expected \"AZ,EL\" in degrees)")?;
    Ok(crate::camera::Sun {
        azimuth: az.to_radians(),
        elevation: el.to_radians(),
    })
}

/// Two finite numbers "A,B".
pub fn parse_pair(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once(',')
        .with_context(|| format!("expected two numbers \"A,B\", got {s:?}"))?;
    let num = |x: &str| -> Result<f64> {
        x.trim()
            .parse()
            .with_context(|| format!("not a number: {x:?}"))
    };
    let (a, b) = (num(a)?, num(b)?);
    if !a.is_finite() || !b.is_finite() {
        bail!("numbers must be finite, got {s:?}");
    }
    Ok((a, b))
}

/// How to roll out (also the `cabc-sim rollout` arguments).
#[derive(Clone, Debug, clap::Args)]
pub struct RolloutOptions {
    /// pid | zero | const:A,S (acceleration m/s², steering rad)
    #[arg(long, default_value = "pid")]
    pub policy: String,
    /// fixed | random
    #[arg(long, default_value = "fixed")]
    pub spawn: Spawn,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Maximum number of env steps (0.1 s each).
    #[arg(long, default_value_t = 1000)]
    pub steps: u64,
    /// Keep stepping after a truncation (the first one is still reported).
    #[arg(long)]
    pub no_truncate: bool,
    /// Truncate after this many laps.
    #[arg(long, default_value_t = crate::env::MAX_LAPS)]
    pub max_laps: u32,
}

/// What a rollout did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub policy: String,
    pub spawn: Spawn,
    pub seed: u64,
    pub steps: u64,
    pub laps: u32,
    pub lap_times: Vec<f64>,
    pub truncation: Option<Truncation>,
    pub truncation_step: Option<u64>,
    pub total_reward: f64,
    pub max_abs_x_tran: f64,
    pub initial_state: [f64; 6],
    pub final_state: [f64; 6],
    pub final_pose: [f64; 3],
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "steps {} laps {} lap times {:?}",
            self.steps, self.laps, self.lap_times
        )?;
        match (self.truncation, self.truncation_step) {
            (Some(t), Some(s)) => writeln!(f, "truncated: {t} at step {s}")?,
            _ => writeln!(f, "not truncated")?,
        }
        writeln!(
            f,
            "max |x_tran| {:.4}  total reward {:.4}",
            self.max_abs_x_tran, self.total_reward
        )?;
        writeln!(
            f,
            "final state {:?}\nfinal pose {:?}",
            self.final_state, self.final_pose
        )
    }
}

/// Runs one episode on `track` from `opts.spawn` (RNG stream (seed, 0)), writing every step to `trace` when given.
pub fn rollout(opts: &RolloutOptions, track: Arc<Track>, trace: Option<&Path>) -> Result<Summary> {
    let mut policy = RolloutPolicy::parse(&opts.policy)?;
    let config = EnvConfig {
        max_laps: opts.max_laps,
        ..EnvConfig::default()
    };
    let mut env = Env::new(track, Default::default(), config);
    let obs0 = env.reset(opts.spawn, &mut Env::rng(opts.seed, 0));
    let mut csv = trace.map(TraceWriter::create).transpose()?;
    if let Some(w) = csv.as_mut() {
        w.row(&Row {
            step: 0,
            t: 0.0,
            action: [0.0, 0.0],
            obs: &obs0,
            reward: 0.0,
            lap_no: 0,
            truncation: None,
        })?;
    }
    let mut obs = obs0;
    let (mut truncation, mut truncation_step) = (None, None);
    let mut total_reward = 0.0;
    let mut max_abs_x_tran = obs.state[4].abs();
    let mut k = 0;
    while k < opts.steps {
        let r = env.step(&policy.action(&obs.state));
        k += 1;
        obs = r.obs;
        total_reward += r.reward;
        max_abs_x_tran = max_abs_x_tran.max(obs.state[4].abs());
        if let Some(w) = csv.as_mut() {
            w.row(&Row {
                step: k,
                t: env.time(),
                action: env.last_action(),
                obs: &obs,
                reward: r.reward,
                lap_no: r.lap_no,
                truncation: r.truncation,
            })?;
        }
        if let Some(t) = r.truncation {
            if truncation.is_none() {
                truncation = Some(t);
                truncation_step = Some(k);
            }
            if !opts.no_truncate {
                break;
            }
        }
    }
    if let Some(w) = csv {
        w.finish()?;
    }
    Ok(Summary {
        policy: opts.policy.clone(),
        spawn: opts.spawn,
        seed: opts.seed,
        steps: k,
        laps: env.lap_no(),
        lap_times: env.lap_times().to_vec(),
        truncation,
        truncation_step,
        total_reward,
        max_abs_x_tran,
        initial_state: obs0.state,
        final_state: obs.state,
        final_pose: obs.pose,
    })
}
