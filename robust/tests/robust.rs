//! `cabc robust`'s study on the PID lane follower as the driver (the same observations a policy gets): a seed gives
//! one report, noise makes the PID crash more often, and bad options are refused with the flag named.

use cabc_proto::config::RunConfig;
use cabc_robust::{study, RobustError, RobustOptions, RobustReport, SpawnRanges};
use cabc_sim::pid::PidLaneFollower;
use clap::Parser;

fn config() -> RunConfig {
    RunConfig::load("smoke").unwrap()
}

/// The PID's action on the observed state [v_long, v_tran, omega, s, x_tran, e_psi].
fn pid_study(options: &RobustOptions) -> Result<RobustReport, RobustError> {
    let config = config();
    let settings = options.settings(&config)?;
    let mut pid = PidLaneFollower::new(1.0);
    study(&config, &settings, "pid", |input| {
        Ok(input
            .states
            .iter()
            .map(|s| {
                let u = pid.action(s[0] as f64, s[4] as f64, s[5] as f64);
                [u[0] as f32, u[1] as f32]
            })
            .collect())
    })
}

/// PID driving with the given noise at levels 0 and 1, from 20 spawns, one lap after the out-lap.
fn options(action_noise: Vec<f64>, state_noise: Vec<f64>) -> RobustOptions {
    RobustOptions {
        spawns: 20,
        laps: Some(1),
        action_noise,
        state_noise,
        levels: vec![0.0, 1.0],
        ..RobustOptions::default()
    }
}

#[test]
fn a_seed_gives_one_report() {
    let options = options(vec![0.3, 0.1], vec![0.05]);
    let json = |o: &RobustOptions| serde_json::to_string(&pid_study(o).unwrap()).unwrap();
    let first = json(&options);
    assert_eq!(first, json(&options));
    let other = json(&RobustOptions {
        seed: 2,
        ..options.clone()
    });
    assert_ne!(first, other);
    // The spawns lie within their ranges, and the printed summary drops the per-spawn lists only.
    let report = pid_study(&options).unwrap();
    assert_eq!(report.spawn_points.len(), 20);
    for p in &report.spawn_points {
        assert!(
            p.x_tran.abs() <= 0.5 * 0.55 && p.e_psi.abs() <= 0.1,
            "{p:?}"
        );
        assert!(
            (0.5..=2.0).contains(&p.v_long) && (0.0..17.47).contains(&p.s),
            "{p:?}"
        );
    }
    let summary = report.summary();
    assert!(
        summary.spawn_points.is_empty() && summary.levels.iter().all(|l| l.outcomes.is_empty())
    );
    assert_eq!(summary.levels[1].crashes, report.levels[1].crashes);
}

#[test]
fn noise_makes_the_pid_crash_more() {
    // Without noise the PID laps from every spawn within half the half width (simulator.md 7: about 18.2 s a lap).
    let report = pid_study(&options(vec![0.5, 0.5], vec![0.0])).unwrap();
    let (quiet, noisy) = (&report.levels[0], &report.levels[1]);
    assert_eq!((quiet.level, noisy.level), (0.0, 1.0));
    assert_eq!(noisy.action_std, [0.5, 0.5]);
    assert_eq!(
        (quiet.episodes, quiet.crashes, quiet.completed),
        (20, 0, 20)
    );
    assert_eq!((quiet.laps_total, quiet.laps_mean), (20, 1.0));
    let lap = quiet.lap_time.as_ref().unwrap();
    assert!(
        lap.laps == 20 && (17.0..19.5).contains(&lap.mean),
        "{lap:?}"
    );
    assert!(lap.min <= lap.mean && lap.mean <= lap.max);
    assert_eq!(quiet.steps_before_crash_mean, None);
    // Under noise on the action, at least a quarter of the spawns end in a crash, and the counts agree.
    assert!(noisy.crashes >= quiet.crashes + 5, "{noisy:?}");
    assert_eq!(noisy.crash_share, noisy.crashes as f64 / 20.0);
    let [lo, hi] = noisy.crash_share_95;
    assert!(
        lo < noisy.crash_share && noisy.crash_share <= hi,
        "{lo} {hi}"
    );
    assert_eq!(noisy.end_reasons.values().sum::<usize>(), 20);
    assert_eq!(
        noisy.outcomes.iter().filter(|o| o.crashed).count(),
        noisy.crashes
    );
    assert!(noisy.steps_before_crash_mean.is_some_and(|s| s >= 1.0));
    // Noise on the observed state alone slows the PID down (its steering weaves) at a level that still laps.
    let report = pid_study(&options(vec![0.0], vec![0.1])).unwrap();
    let (quiet, noisy) = (&report.levels[0], &report.levels[1]);
    let (t0, t1) = (
        quiet.lap_time.as_ref().unwrap().mean,
        noisy.lap_time.as_ref().unwrap().mean,
    );
    assert!(t1 > t0 + 1.0, "{t0} {t1}");
}

#[test]
fn bad_options_are_refused_with_the_flag_named() {
    let good = options(vec![0.1], vec![0.0]);
    let cases: Vec<(RobustOptions, &str)> = vec![
        (
            RobustOptions {
                spawns: 0,
                ..good.clone()
            },
            "--spawns: at least one",
        ),
        (
            RobustOptions {
                action_noise: vec![-0.1],
                ..good.clone()
            },
            "--action-noise: -0.1 is not",
        ),
        (
            RobustOptions {
                action_noise: vec![0.1, 0.2, 0.3],
                ..good.clone()
            },
            "--action-noise: 3 values",
        ),
        (
            RobustOptions {
                state_noise: vec![0.1, 0.2],
                ..good.clone()
            },
            "--state-noise: 2 values given: one for every entry, or 6",
        ),
        (
            RobustOptions {
                state_noise: vec![f64::NAN],
                ..good.clone()
            },
            "--state-noise: NaN",
        ),
        (
            RobustOptions {
                levels: vec![],
                ..good.clone()
            },
            "--levels: at least one",
        ),
        (
            RobustOptions {
                levels: vec![0.0, -1.0],
                ..good.clone()
            },
            "--levels: -1",
        ),
        (
            RobustOptions {
                lateral: 1.5,
                ..good.clone()
            },
            "--lateral: 1.5 is beyond",
        ),
        (
            RobustOptions {
                heading: 2.0,
                ..good.clone()
            },
            "--heading: 2 rad",
        ),
        (
            RobustOptions {
                speed: vec![2.0, 1.0],
                ..good.clone()
            },
            "--speed: MIN 2 above MAX 1",
        ),
        (
            RobustOptions {
                speed: vec![0.1],
                ..good.clone()
            },
            "--speed: 0.1 m/s is below the stall",
        ),
        (
            RobustOptions {
                speed: vec![],
                ..good.clone()
            },
            "--speed: one speed",
        ),
        (
            RobustOptions {
                laps: Some(0),
                ..good.clone()
            },
            "--laps: at least one",
        ),
    ];
    for (options, message) in cases {
        let err = options.settings(&config()).unwrap_err();
        assert!(err.to_string().starts_with(message), "{err}, not {message}");
    }
    // A driver's error names the spawn and the level.
    let settings = good.settings(&config()).unwrap();
    let err = study(&config(), &settings, "broken", |_| {
        anyhow::bail!("no weights")
    })
    .unwrap_err();
    assert_eq!(err.to_string(), "spawn 0 at noise level 0: no weights");
    // The run's evaluation laps unless --laps is given.
    let settings = RobustOptions { laps: None, ..good }
        .settings(&config())
        .unwrap();
    assert_eq!(settings.laps, config().collection.eval_laps);
}

/// `cabc robust`'s spawns by default are [`SpawnRanges`]' default, which the early stop's episodes draw from
/// (`collection.early_stop_spawns`): the command line's defaults and [`RobustOptions::default`] agree with it.
#[test]
fn the_default_spawns_are_the_early_stops() {
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        options: RobustOptions,
    }
    let parsed = Cli::parse_from(["robust"]).options;
    for options in [parsed, RobustOptions::default()] {
        let settings = options.settings(&config()).unwrap();
        assert_eq!(settings.spawn, SpawnRanges::default());
    }
}
