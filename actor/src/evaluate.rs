//! Evaluation (algorithm.md 5): the policy drives alone (beta = 0) from the fixed spawn until truncation or
//! `eval_laps` completed laps.

use crate::collect::{end_reason, make_env, Observations};
use crate::eyes::Eyes;
use crate::sensor::Sensor;
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{EndReason, EvalReport};
use cabc_sim::env::{Env, Spawn};

/// Steps allowed per lap before an evaluation is cut (a policy creeping along without failing must end too).
const STEPS_PER_LAP_LIMIT: u64 = 1000;

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
    mut act: impl FnMut(&Observations) -> anyhow::Result<Vec<[f32; 2]>>,
    mut watch: impl FnMut(&Env),
) -> anyhow::Result<EvalReport> {
    let laps_wanted = config.collection.eval_laps;
    // One lap more than wanted so that the env's max-laps truncation never cuts the last wanted lap.
    let mut env = make_env(laps_wanted + 1);
    let mut rng = Env::rng(config.run.seed ^ 0xe7a1, version);
    env.reset(Spawn::Fixed, &mut rng);
    let mut eyes = (config.observation.kind == ObservationKind::Camera)
        .then(|| Eyes::new(&config.observation));
    // The sensor's noise, from a stream of its own per version.
    let mut sensor = Sensor::new(
        &config.observation,
        Env::rng(
            config.run.seed ^ crate::collect::SENSOR_SEED ^ 0xe7a1,
            version,
        ),
    );
    let mut line: Vec<[f32; 2]> = Vec::new();
    let max_steps = STEPS_PER_LAP_LIMIT * laps_wanted.max(1) as u64;
    let mut steps = 0u64;
    let end_reason = loop {
        watch(&env);
        let obs = env.observation();
        line.push([obs.pose[0] as f32, obs.pose[1] as f32]);
        let state = [sensor.state(obs.state.map(|v| v as f32))];
        let images: Vec<_> = eyes
            .as_mut()
            .map(|e| vec![sensor.image(e.see(&env))])
            .unwrap_or_default();
        let action = act(&Observations {
            states: &state,
            images: &images,
        })?;
        let a = action.first().copied().unwrap_or([0.0, 0.0]);
        let result = env.step(&[a[0] as f64, a[1] as f64]);
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

    #[test]
    fn a_zero_policy_stalls() {
        let config = RunConfig::load("smoke").unwrap();
        let report = evaluate("eval", 0, &config, |_| Ok(vec![[-1.0, 0.0]])).unwrap();
        assert_eq!(report.end_reason, EndReason::Stall);
        assert_eq!(report.laps, 0);
    }
}
