//! Evaluation (algorithm.md 5): the policy drives alone (beta = 0) from the fixed spawn until truncation or
//! `eval_laps` completed laps.
//!
//! One loop drives every evaluation episode ([`drive`]): the evaluator's (the fixed spawn, no disturbance:
//! [`Episode::evaluation`]) and the robustness study's (`cabc robust`: a given spawn pose and speed, Gaussian noise on
//! the policy's action and on the state it observes, [`Disturbance`]).

use crate::collect::{end_reason, make_env, Observations};
use crate::eyes::Eyes;
use crate::sensor::Sensor;
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{EndReason, EvalReport};
use cabc_sim::env::{Env, Spawn};
use cabc_sim::track::Frenet;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Steps allowed per lap before an evaluation is cut (a policy creeping along without failing must end too).
const STEPS_PER_LAP_LIMIT: u64 = 1000;

/// Mixed into the seed for an evaluation's random streams (the sun; the sensor's with [`crate::collect::SENSOR_SEED`]).
const EVAL_SEED: u64 = 0xe7a1;

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

/// Drives one evaluation episode with `act` and reports it.
pub fn evaluate(
    actor: &str,
    version: u64,
    config: &RunConfig,
    act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
) -> anyhow::Result<EvalReport> {
    evaluate_watched(actor, version, config, act, |_| {})
}

/// [`evaluate`], showing `watch` the environment before each step: the car's full state and the sun, which a video
/// of the evaluation draws (`cabc video`).
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
/// each step, until truncation, the wanted laps or the step limit ([`STEPS_PER_LAP_LIMIT`] per wanted lap).
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
    let mut env = make_env(config, laps_wanted + 1);
    let mut rng = Env::rng(episode.seed ^ EVAL_SEED, episode.stream);
    // The fixed spawn's reset draws the sun; a given start then moves the car.
    env.reset(Spawn::Fixed, &mut rng);
    if let Start::At { pose, v_long } = episode.start {
        env.set_spawn(pose.s, pose.x_tran, pose.e_psi, v_long);
    }
    let mut eyes = (config.observation.kind == ObservationKind::Camera).then(|| Eyes::new(config));
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
    let max_steps = STEPS_PER_LAP_LIMIT * laps_wanted.max(1) as u64;
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

    #[test]
    fn a_zero_policy_stalls() {
        let config = RunConfig::load("smoke").unwrap();
        let report = evaluate("eval", 0, &config, |_| Ok(vec![[-1.0, 0.0]])).unwrap();
        assert_eq!(report.end_reason, EndReason::Stall);
        assert_eq!(report.laps, 0);
    }
}
