//! Evaluation (algorithm.md 5): the policy drives alone (beta = 0) from the fixed spawn until truncation or
//! `eval_laps` completed laps; under `collection.early_stop_spawns` (ours, issue 59), a version that completes them
//! drives that many episodes more from random spawns under noise, which the early stop judges it on too
//! ([`judged_episodes`]).
//!
//! One loop drives every evaluation episode ([`drive`]): the evaluator's (the fixed spawn, no disturbance:
//! [`Episode::evaluation`]), the early stop's from random spawns, and the robustness study's (`cabc robust`: a given
//! spawn pose and speed, Gaussian noise on the policy's action and on the state it observes, [`Disturbance`]).

use crate::collect::{end_reason, make_env, Observations};
use crate::eyes::Eyes;
use crate::sensor::Sensor;
use crate::spawns::{draw_spawns_from, SpawnRanges};
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{EndReason, EvalReport};
use cabc_sim::env::{Env, Spawn};
use cabc_sim::track::{Frenet, Track, TrackError};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::time::Instant;

/// Steps allowed per lap before an evaluation is cut (a policy creeping along without failing must end too): 1,000,
/// or on a track longer than 20 m 50 a metre (a lap slower than 0.2 m/s on average).
fn steps_per_lap_limit(track_length: f64) -> u64 {
    const STEPS_PER_LAP_LIMIT: u64 = 1000;
    const STEPS_PER_METRE_LIMIT: f64 = 50.0;
    STEPS_PER_LAP_LIMIT.max((STEPS_PER_METRE_LIMIT * track_length).ceil() as u64)
}

/// Mixed into the seed for an evaluation's random streams (the sun; the sensor's with [`crate::collect::SENSOR_SEED`]).
const EVAL_SEED: u64 = 0xe7a1;

/// Mixed into the run's seed for the early stop's episodes from random spawns ([`judged_episodes`]): their spawns
/// (stream: the version), their sun and sensor (with [`EVAL_SEED`] as the evaluation's), and their disturbance
/// (streams: the version in the upper 32 bits, the episode in the lower). The high bits keep every key apart from
/// `cabc robust`'s (its `--seed` mixed with constants below 2^24), the fixed-spawn evaluation's and collection's, for
/// any seed below 2^48: the early stop never judges a version on the draws a robustness study tests it on.
const JUDGED_SPAWN_SEED: u64 = 0xe55a << 48;
const JUDGED_SEED: u64 = 0xe5e5 << 48;
const JUDGED_NOISE_SEED: u64 = 0xe54e << 48;

/// Where an evaluation episode starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Start {
    /// The evaluation spawn ([`cabc_sim::env::FIXED_SPAWN`]).
    Fixed,
    /// The car placed at a Frenet pose with forward speed `v_long` (v_tran = omega = 0).
    At { pose: Frenet, v_long: f64 },
}

/// Disturbances of an episode, from a stream of their own: Gaussian noise of `action_std` added to the policy's
/// action before the plant clips it to the action box, and of `state_std` (per dimension of [v_long, v_tran, omega,
/// s, x_tran, e_psi]) added to the state the policy observes (after the run's own sensor noise; the plant's state is
/// untouched). Every step draws six normals for the state, then two for the action, whatever the deviations, so that
/// two levels of noise on one stream scale the same draws.
#[derive(Clone, Debug)]
pub struct Disturbance {
    pub action_std: [f64; 2],
    pub state_std: [f64; 6],
    pub rng: ChaCha8Rng,
}

impl Disturbance {
    /// The observed state with its noise, and the noise to add to the action, for one step.
    fn draw(&mut self, state: &mut [f32; 6]) -> [f64; 2] {
        for (x, &std) in state.iter_mut().zip(&self.state_std) {
            let n: f64 = self.rng.sample(StandardNormal);
            *x = (*x as f64 + std * n) as f32;
        }
        self.action_std.map(|std| {
            let n: f64 = self.rng.sample(StandardNormal);
            std * n
        })
    }
}

/// One evaluation episode: where it starts, how many laps it wants, its random streams and disturbance.
#[derive(Clone, Debug)]
pub struct Episode {
    /// Laps wanted: the episode ends when the env has counted this many (the env's max-laps truncation is one more).
    pub laps: u32,
    pub start: Start,
    /// The sun's and the sensor's random streams: `stream` of the seed `seed` (mixed with constants of their own).
    pub seed: u64,
    pub stream: u64,
    pub disturbance: Option<Disturbance>,
}

impl Episode {
    /// The evaluator's episode for policy `version`: the fixed spawn, `collection.eval_laps` laps, the streams of
    /// `version` under the run's seed, no disturbance.
    pub fn evaluation(config: &RunConfig, version: u64) -> Episode {
        Episode {
            laps: config.collection.eval_laps,
            start: Start::Fixed,
            seed: config.run.seed,
            stream: version,
            disturbance: None,
        }
    }
}

/// The evaluator's evaluation of policy `version` with `act` (the eval actor's and the in-process one's): the fixed
/// spawn's episode, reported; when it completes `collection.eval_laps` laps, the early stop's episodes from random
/// spawns ([`judged_episodes`]; none by default) are driven too, and the report counts them and those that did not
/// complete their laps. Its laps, lap times, end, steps and line stay the fixed spawn's.
pub fn evaluate(
    actor: &str,
    version: u64,
    config: &RunConfig,
    mut act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
) -> anyhow::Result<EvalReport> {
    let mut report = evaluate_watched(actor, version, config, &mut act, |_| {})?;
    if report.laps < config.collection.eval_laps {
        return Ok(report);
    }
    let episodes = judged_episodes(config, version)?;
    if episodes.is_empty() {
        return Ok(report);
    }
    let started = Instant::now();
    for episode in episodes {
        let driven = drive(actor, version, config, episode, &mut act, |_| {})?;
        report.spawn_episodes += 1;
        if driven.end_reason != EndReason::MaxLaps {
            report.spawn_crashes += 1;
        }
    }
    tracing::info!(
        version,
        episodes = report.spawn_episodes,
        crashes = report.spawn_crashes,
        secs = started.elapsed().as_secs_f64(),
        "the early stop's episodes from random spawns"
    );
    Ok(report)
}

/// The early stop's episodes from random spawns for policy `version` (`collection.early_stop_spawns` of them; none
/// by default): spawns drawn as `cabc robust` draws them ([`draw_spawns_from`] within [`SpawnRanges::default`]), each
/// wanting an out-lap and `collection.eval_laps` laps under Gaussian noise of `early_stop_action_noise_std` on the
/// action and `early_stop_state_noise_std` on the observed state ([`Disturbance`]). Every stream comes from the
/// run's seed and the version ([`JUDGED_SEED`]), so a version's episodes are the same whichever evaluator drives
/// them and whenever, and no two versions share theirs.
pub fn judged_episodes(config: &RunConfig, version: u64) -> Result<Vec<Episode>, TrackError> {
    let rules = &config.collection;
    if rules.early_stop_spawns == 0 {
        return Ok(Vec::new());
    }
    let track = Track::of(&config.sim)?;
    let seed = config.run.seed;
    let mut rng = Env::rng(seed ^ JUDGED_SPAWN_SEED, version);
    let spawns = draw_spawns_from(
        &track,
        rules.early_stop_spawns as usize,
        &mut rng,
        &SpawnRanges::default(),
    );
    let (action_std, state_std) = (
        rules.early_stop_action_noise_std,
        rules.early_stop_state_noise_std,
    );
    let noisy = action_std.iter().chain(&state_std).any(|&s| s > 0.0);
    Ok(spawns
        .iter()
        .enumerate()
        .map(|(i, spawn)| {
            let stream = (version << 32) | i as u64;
            Episode {
                // The out-lap, then the laps wanted.
                laps: rules.eval_laps + 1,
                start: Start::At {
                    pose: spawn.pose(),
                    v_long: spawn.v_long,
                },
                seed: seed ^ JUDGED_SEED,
                stream,
                disturbance: noisy.then(|| Disturbance {
                    action_std,
                    state_std,
                    rng: Env::rng(seed ^ JUDGED_NOISE_SEED, stream),
                }),
            }
        })
        .collect())
}

/// The fixed spawn's episode of [`evaluate`] alone, showing `watch` the environment before each step: the car's full
/// state and the sun, which a video of the evaluation draws (`cabc video`); no episode from random spawns.
pub fn evaluate_watched(
    actor: &str,
    version: u64,
    config: &RunConfig,
    act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
    watch: impl FnMut(&Env),
) -> anyhow::Result<EvalReport> {
    let episode = Episode::evaluation(config, version);
    drive(actor, version, config, episode, act, watch)
}

/// Drives `episode` with `act` (the run's observation kind and sensor noise), showing `watch` the environment before
/// each step, until truncation, the wanted laps or the step limit ([`steps_per_lap_limit`] per wanted lap).
pub fn drive(
    actor: &str,
    version: u64,
    config: &RunConfig,
    episode: Episode,
    mut act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
    mut watch: impl FnMut(&Env),
) -> anyhow::Result<EvalReport> {
    let laps_wanted = episode.laps;
    // One lap more than wanted so that the env's max-laps truncation never cuts the last wanted lap.
    let mut env = make_env(config, laps_wanted + 1)?;
    let mut rng = Env::rng(episode.seed ^ EVAL_SEED, episode.stream);
    // The fixed spawn's reset draws the sun; a given start then moves the car.
    env.reset(Spawn::Fixed, &mut rng);
    if let Start::At { pose, v_long } = episode.start {
        env.set_spawn(pose.s, pose.x_tran, pose.e_psi, v_long);
    }
    let mut eyes = (config.observation.kind == ObservationKind::Camera)
        .then(|| Eyes::new(config))
        .transpose()?;
    // The sensor's noise, from a stream of its own per episode.
    let mut sensor = Sensor::new(
        &config.observation,
        Env::rng(
            episode.seed ^ crate::collect::SENSOR_SEED ^ EVAL_SEED,
            episode.stream,
        ),
    );
    let mut disturbance = episode.disturbance;
    let mut line: Vec<[f32; 2]> = Vec::new();
    let max_steps = steps_per_lap_limit(env.track().length()) * laps_wanted.max(1) as u64;
    let mut steps = 0u64;
    let end_reason = loop {
        watch(&env);
        let obs = env.observation();
        line.push([obs.pose[0] as f32, obs.pose[1] as f32]);
        let mut state = [sensor.state(obs.state.map(|v| v as f32))];
        let action_noise = disturbance.as_mut().map(|d| d.draw(&mut state[0]));
        let images: Vec<_> = eyes
            .as_mut()
            .map(|e| vec![sensor.image(e.see(&env))])
            .unwrap_or_default();
        let action = act(&Observations {
            states: &state,
            images: &images,
        })?;
        let a = action.first().copied().unwrap_or([0.0, 0.0]);
        let mut u = [a[0] as f64, a[1] as f64];
        if let Some(n) = action_noise {
            u = [u[0] + n[0], u[1] + n[1]];
        }
        let result = env.step(&u);
        steps += 1;
        if let Some(t) = result.truncation {
            break end_reason(t);
        }
        if env.lap_no() >= laps_wanted {
            break EndReason::MaxLaps;
        }
        if steps >= max_steps {
            break EndReason::Budget;
        }
    };
    let lap_times = env.lap_times().to_vec();
    Ok(EvalReport {
        actor: actor.to_string(),
        version,
        laps: lap_times.len() as u32,
        lap_times,
        end_reason,
        steps,
        line: subsample(line, config.actors.eval_line_points),
        spawn_episodes: 0,
        spawn_crashes: 0,
    })
}

fn subsample(line: Vec<[f32; 2]>, max: usize) -> Vec<[f32; 2]> {
    if max == 0 || line.len() <= max {
        return line;
    }
    let stride = line.len().div_ceil(max);
    line.into_iter().step_by(stride).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_sim::pid::PidLaneFollower;

    #[test]
    fn the_pid_policy_completes_the_wanted_laps() {
        let mut config = RunConfig::load("smoke").unwrap();
        config.collection.eval_laps = 2;
        let mut pid = PidLaneFollower::new(1.0);
        let report = evaluate("eval", 3, &config, |input| {
            let s = input.states[0];
            let u = pid.action(s[0] as f64, s[4] as f64, s[5] as f64);
            Ok(vec![[u[0] as f32, u[1] as f32]])
        })
        .unwrap();
        assert_eq!(report.end_reason, EndReason::MaxLaps);
        assert_eq!(report.laps, 2);
        assert!(
            report.lap_times.iter().all(|t| (17.0..19.5).contains(t)),
            "{:?}",
            report.lap_times
        );
    }

    /// The PID on the observed state, as a driver.
    fn pid_act(
        pid: &mut PidLaneFollower,
    ) -> impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>> + '_ {
        |input| {
            let s = input.states[0];
            let u = pid.action(s[0] as f64, s[4] as f64, s[5] as f64);
            Ok(vec![[u[0] as f32, u[1] as f32]])
        }
    }

    #[test]
    fn an_episode_at_the_fixed_spawn_without_noise_is_the_evaluation() {
        let mut config = RunConfig::load("smoke").unwrap();
        config.collection.eval_laps = 1;
        config.observation.state_noise_std = [0.01; 6];
        let mut pid = PidLaneFollower::new(1.0);
        let evaluation = evaluate("eval", 4, &config, pid_act(&mut pid)).unwrap();
        let at_the_spawn = Episode {
            start: Start::At {
                pose: cabc_sim::env::FIXED_SPAWN,
                v_long: cabc_sim::env::FIXED_SPAWN_SPEED,
            },
            // A disturbance of zero draws from its own stream: the episode is unchanged.
            disturbance: Some(Disturbance {
                action_std: [0.0; 2],
                state_std: [0.0; 6],
                rng: Env::rng(9, 9),
            }),
            ..Episode::evaluation(&config, 4)
        };
        let driven = drive("eval", 4, &config, at_the_spawn, pid_act(&mut pid), |_| {}).unwrap();
        assert_eq!(driven, evaluation);
        // Noise on the action changes the episode; elsewhere on the track the car starts where it is put.
        let noisy = Episode {
            disturbance: Some(Disturbance {
                action_std: [0.3, 0.1],
                state_std: [0.0; 6],
                rng: Env::rng(9, 9),
            }),
            ..Episode::evaluation(&config, 4)
        };
        let driven = drive("eval", 4, &config, noisy, pid_act(&mut pid), |_| {}).unwrap();
        assert_ne!(driven, evaluation);
        let elsewhere = Episode {
            start: Start::At {
                pose: Frenet {
                    s: 8.0,
                    x_tran: 0.2,
                    e_psi: 0.05,
                },
                v_long: 1.5,
            },
            ..Episode::evaluation(&config, 4)
        };
        let mut first = None;
        drive("eval", 4, &config, elsewhere, pid_act(&mut pid), |env| {
            first.get_or_insert(env.observation().state);
        })
        .unwrap();
        let first = first.unwrap();
        assert!(
            (first[0] - 1.5).abs() < 1e-12 && (first[3] - 8.0).abs() < 1e-9,
            "{first:?}"
        );
        assert!(
            (first[4] - 0.2).abs() < 1e-9 && (first[5] - 0.05).abs() < 1e-9,
            "{first:?}"
        );
    }

    /// Issue 59 item 3: under `collection.early_stop_spawns` the evaluation of a version that completes its laps
    /// drives that many episodes more from random spawns, reproducibly, and counts those that did not complete
    /// theirs; the report's laps and lap times stay the fixed spawn's, and without the key nothing changes.
    #[test]
    fn the_pid_is_judged_on_random_spawns_under_noise() {
        let mut config = RunConfig::load("smoke").unwrap();
        config.collection.eval_laps = 2;
        let mut pid = PidLaneFollower::new(1.0);
        let plain = evaluate("eval", 3, &config, pid_act(&mut pid)).unwrap();
        assert_eq!(
            (plain.laps, plain.spawn_episodes, plain.spawn_crashes),
            (2, 0, 0)
        );
        assert!(judged_episodes(&config, 3).unwrap().is_empty());
        // Without noise the PID laps from every spawn within half the half width (as in `cabc robust`'s test).
        config.collection.early_stop_spawns = 4;
        let quiet = evaluate("eval", 3, &config, pid_act(&mut pid)).unwrap();
        assert_eq!((quiet.spawn_episodes, quiet.spawn_crashes), (4, 0));
        assert_eq!(
            EvalReport {
                spawn_episodes: 0,
                ..quiet.clone()
            },
            plain,
            "the fixed spawn's figures"
        );
        // Each episode wants the out-lap and the laps, from its own spawn; a version's spawns are its own.
        let episodes = judged_episodes(&config, 3).unwrap();
        assert_eq!(episodes.len(), 4);
        assert!(episodes
            .iter()
            .all(|e| e.laps == 3 && e.disturbance.is_none()));
        let starts = |v| {
            judged_episodes(&config, v)
                .unwrap()
                .iter()
                .map(|e| e.start)
                .collect::<Vec<_>>()
        };
        assert_eq!(starts(3), starts(3));
        assert_ne!(starts(3), starts(4));
        assert!(starts(3).windows(2).all(|w| w[0] != w[1]));
        // Under strong noise on the action some crash; the same version gives the same report.
        config.collection.early_stop_action_noise_std = [0.5, 0.5];
        config.collection.early_stop_state_noise_std = [0.01; 6];
        let noisy = evaluate("eval", 3, &config, pid_act(&mut pid)).unwrap();
        assert_eq!(noisy.spawn_episodes, 4);
        assert!(noisy.spawn_crashes >= 1, "{noisy:?}");
        assert_eq!(
            noisy,
            evaluate("eval", 3, &config, pid_act(&mut pid)).unwrap()
        );
        assert_eq!(
            (noisy.laps, &noisy.lap_times),
            (plain.laps, &plain.lap_times)
        );
        // A version that fails at the fixed spawn drives no episode more.
        let stalled = evaluate("eval", 3, &config, |_| Ok(vec![[-1.0, 0.0]])).unwrap();
        assert_eq!((stalled.laps, stalled.spawn_episodes), (0, 0));
    }

    #[test]
    fn a_zero_policy_stalls() {
        let config = RunConfig::load("smoke").unwrap();
        let report = evaluate("eval", 0, &config, |_| Ok(vec![[-1.0, 0.0]])).unwrap();
        assert_eq!(report.end_reason, EndReason::Stall);
        assert_eq!(report.laps, 0);
    }
}
