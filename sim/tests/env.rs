//! Env checks: truncation reasons, lap counting, spawns, batches (simulator.md §3).
use std::sync::Arc;

use cabc_sim::env::{fixed_spawn_state, Env, EnvBatch, EnvConfig, EnvError, Spawn, Truncation};
use cabc_sim::{PidLaneFollower, Track, VehicleParams};

fn pid_until(env: &mut Env, max_steps: usize) -> (usize, Option<Truncation>) {
    let mut pid = PidLaneFollower::default();
    let mut obs = env.observation();
    for k in 1..=max_steps {
        let r = env.step(&pid.action(obs.state[0], obs.state[4], obs.state[5]));
        obs = r.obs;
        if r.truncation.is_some() {
            return (k, r.truncation);
        }
    }
    (max_steps, None)
}

#[test]
fn fixed_spawn_observation() {
    let mut env = Env::barc();
    let obs = env.reset(Spawn::Fixed, &mut Env::rng(0, 0));
    assert_eq!(obs.state, [0.5, 0.0, 0.0, 0.1, 0.0, 0.0]);
    assert_eq!(obs.pose, [0.1, 0.0, 0.0]);
}

#[test]
fn pid_laps_in_about_18_2_seconds() {
    let mut env = Env::barc();
    env.reset(Spawn::Fixed, &mut Env::rng(0, 0));
    let mut pid = PidLaneFollower::default();
    let mut obs = env.observation();
    let mut lap_steps = Vec::new();
    let mut total_reward = 0.0;
    for k in 1..=600 {
        let r = env.step(&pid.action(obs.state[0], obs.state[4], obs.state[5]));
        obs = r.obs;
        total_reward += r.reward;
        assert!(
            r.truncation.is_none(),
            "PID truncated at step {k}: {:?}",
            r.truncation
        );
        if r.lap_completed {
            lap_steps.push(k);
            assert_eq!(r.lap_no as usize, lap_steps.len());
            assert!(
                r.reward > 0.0 && r.reward < 0.2,
                "lap reward {} should be the progress",
                r.reward
            );
        }
    }
    assert_eq!(env.lap_no(), 3);
    let times = env.lap_times();
    assert_eq!(times.len(), 3);
    // First lap starts at s = 0.1 from 0.5 m/s; later laps are full laps at ~1 m/s.
    for t in times {
        assert!((t - 18.2).abs() < 0.35, "lap time {t}");
    }
    assert!(
        (times[0] - lap_steps[0] as f64 * 0.1).abs() < 1e-9,
        "true n·dt lap time"
    );
    // Reward sums to the progress: 3 laps less the start offset plus the final s.
    let expect = 3.0 * Track::l_track_barc().length() - 0.1 + obs.state[3];
    assert!(
        (total_reward - expect).abs() < 1e-6,
        "{total_reward} vs {expect}"
    );
}

#[test]
fn max_laps_truncates_on_the_step_after() {
    let config = EnvConfig {
        max_laps: 1,
        ..EnvConfig::default()
    };
    let mut env = Env::new(
        Arc::new(Track::l_track_barc()),
        VehicleParams::default(),
        config,
    );
    env.reset(Spawn::Fixed, &mut Env::rng(0, 0));
    let (k, t) = pid_until(&mut env, 1000);
    assert_eq!(t, Some(Truncation::MaxLaps));
    assert_eq!(env.lap_no(), 1);
    // The lap step itself does not truncate: the next one does.
    assert!((env.lap_times()[0] - (k - 1) as f64 * 0.1).abs() < 1e-9);
}

#[test]
fn stall() {
    let mut env = Env::barc();
    env.reset(Spawn::Fixed, &mut Env::rng(0, 0));
    let mut last = None;
    for _ in 0..5 {
        let r = env.step(&[-2.0, 0.0]);
        if r.truncation.is_some() {
            last = r.truncation;
            break;
        }
    }
    // 0.5 − 2·0.1 = 0.3, then 0.1 < 0.25.
    assert_eq!(last, Some(Truncation::Stall));
    assert_eq!(env.steps(), 2);
}

#[test]
fn out_of_track() {
    let mut env = Env::barc();
    env.set_spawn(1.0, 0.54, 0.3, 1.0);
    let r = env.step(&[0.0, 0.0]);
    assert_eq!(r.truncation, Some(Truncation::OutOfTrack));
    assert!(r.obs.state[4] > 0.55 && r.obs.state[4] <= 0.85);
}

#[test]
fn left_band_keeps_stale_frenet() {
    let mut env = Env::barc();
    env.set_spawn(1.0, 0.8, 1.2, 2.0);
    let before = env.frenet();
    let r = env.step(&[2.0, 0.45]);
    assert_eq!(r.truncation, Some(Truncation::LeftBand));
    let q = env.vehicle_state();
    let track = Track::l_track_barc();
    assert!(
        track.global_to_local(q[3], q[4], q[5]).is_err(),
        "pose is fresh and out of band"
    );
    let f = env.frenet();
    assert!(
        f.x_tran.abs() <= 0.85 && f.x_tran >= before.x_tran,
        "Frenet is the last successful one"
    );
    assert_eq!(r.obs.state[3], f.s);
    // Integration stopped at the failing sub-step: the car is just outside the band, not a full step on.
    let d = track.distance_to_centreline(q[3], q[4]);
    assert!(d > 0.85 && d < 0.85 + 0.03, "distance {d}");
}

#[test]
fn spin() {
    let mut env = Env::barc();
    // Heading error just below π/2 on the centreline, steering left: e_psi grows past π/2 first.
    env.set_spawn(1.0, 0.0, 1.5, 1.0);
    let r = env.step(&[0.0, 0.45]);
    assert_eq!(r.truncation, Some(Truncation::Spin), "{:?}", r.obs.state);
}

#[test]
fn random_spawn_draws_and_reproducibility() {
    let track = Track::l_track_barc();
    let mut env = Env::barc();
    let mut rng = Env::rng(42, 0);
    let mut outside = 0;
    for _ in 0..2000 {
        let o = env.reset(Spawn::Random, &mut rng);
        let [v, vt, w, s, e, p] = o.state;
        assert!((0.5..2.0).contains(&v) && vt == 0.0 && w == 0.0);
        assert!(s >= 0.1 - 1e-9 && s <= track.length() - 2.0 + 1e-9);
        assert!(e.abs() <= 0.85 + 1e-9 && p.abs() <= std::f64::consts::FRAC_PI_6 + 1e-9);
        assert!(o.pose[2].abs() <= std::f64::consts::PI);
        if e.abs() > 0.55 {
            outside += 1;
        }
        let sun = env.sun();
        assert!(sun.elevation >= 15f64.to_radians() && sun.elevation <= 75f64.to_radians());
    }
    let frac = outside as f64 / 2000.0;
    assert!(
        (frac - 0.353).abs() < 0.04,
        "fraction spawned outside the constraint {frac}"
    );
    let a = Env::barc().reset(Spawn::Random, &mut Env::rng(5, 1));
    let b = Env::barc().reset(Spawn::Random, &mut Env::rng(5, 1));
    let c = Env::barc().reset(Spawn::Random, &mut Env::rng(5, 2));
    assert_eq!(a, b);
    assert_ne!(a, c);
}

#[test]
fn batch_streams_and_errors() {
    let track = Arc::new(Track::l_track_barc());
    let mut batch = EnvBatch::new(track, VehicleParams::default(), EnvConfig::default(), 3, 9);
    let obs = batch.reset_all(Spawn::Random);
    assert_eq!(obs.len(), 3);
    assert_ne!(obs[0], obs[1]);
    let single = Env::barc().reset(Spawn::Random, &mut Env::rng(9, 1));
    assert_eq!(obs[1], single, "env i uses stream (seed, i)");
    let res = batch.step(&[[0.0, 0.0]; 3]).unwrap();
    assert_eq!(res.len(), 3);
    // A prefix steps the first envs only (a budget can end mid-batch).
    let before = batch.env(2).unwrap().steps();
    assert_eq!(batch.step(&[[0.0, 0.0]; 2]).unwrap().len(), 2);
    assert_eq!(batch.env(2).unwrap().steps(), before);
    assert_eq!(
        batch.step(&[[0.0, 0.0]; 4]).unwrap_err(),
        EnvError::BatchSize {
            expected: 3,
            got: 4
        }
    );
    assert!(batch.reset_one(2, Spawn::Fixed).is_ok());
    assert!(batch.reset_one(3, Spawn::Fixed).is_err());
    assert_eq!(batch.env(2).unwrap().observation().state[3], 0.1);
}

#[test]
fn batch_streams_can_start_anywhere() {
    let track = Arc::new(Track::l_track_barc());
    let config = EnvConfig::default();
    let mut batch = EnvBatch::with_streams(track, VehicleParams::default(), config, 9, 4..6);
    let obs = batch.reset_all(Spawn::Random);
    assert_eq!(
        obs[1],
        Env::barc().reset(Spawn::Random, &mut Env::rng(9, 5))
    );
}

#[test]
fn set_state_places_the_car_and_refuses_points_off_the_band() {
    let mut env = Env::barc();
    let q = fixed_spawn_state(env.track());
    env.step(&[1.0, 0.1]);
    env.set_state(q).unwrap();
    assert_eq!(env.steps(), 0);
    assert_eq!(env.observation(), Env::barc().observation());
    assert!(env.set_state([1.0, 0.0, 0.0, 50.0, 50.0, 0.0]).is_err());
    assert_eq!(env.vehicle_state(), q, "unchanged on error");
}

#[test]
fn truncations_read_as_the_protocol_end_reasons() {
    assert_eq!(Truncation::OutOfTrack.to_string(), "out-of-track");
    assert_eq!(Truncation::LeftBand.to_string(), "left-band");
    assert_eq!(Truncation::MaxLaps.to_string(), "max-laps");
}
