//! Evaluations as the learner takes them (issue 11, item 2): early stopping counts distinct versions, a second
//! report of a version is ignored, the best evaluated policy is kept whatever its version (its weights are held
//! until its report arrives, late or out of order), and the versions the run ends without are listed.

use cabc_outputs::rundir::RunDir;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EndReason, EvalReport};

fn report(version: u64, lap_times: &[f64]) -> EvalReport {
    let end = if lap_times.len() >= 2 {
        EndReason::MaxLaps
    } else {
        EndReason::OutOfTrack
    };
    cabc_fixtures::eval_report("eval-0", version, lap_times, end, 100)
}

#[test]
fn early_stop_counts_distinct_versions_and_the_best_policy_is_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = RunConfig::load("smoke").unwrap();
    config.collection.eval_laps = 2;
    config.collection.early_stop_successes = 2;
    let run_dir = RunDir::create(tmp.path()).unwrap();
    let mut learner = cabc_outputs::learner(config, run_dir, false).unwrap();
    let mut published = Vec::new();
    for version in 0..6 {
        published.push(learner.policy_update(version).weights);
    }
    let best = tmp.path().join("best-policy.safetensors");
    // Out of order, as two evaluators deliver them.
    learner.on_eval(report(1, &[20.0]));
    assert_eq!(std::fs::read(&best).unwrap(), published[1]);
    learner.on_eval(report(0, &[]));
    // The best so far: 2 laps.
    learner.on_eval(report(3, &[19.0, 19.5]));
    assert_eq!(std::fs::read(&best).unwrap(), published[3]);
    // Version 3 again (a second evaluator, or a resumed one): ignored, not a second success.
    learner.on_eval(report(3, &[18.0, 18.0]));
    assert_eq!(
        learner.early_stop(),
        None,
        "one version succeeded, twice reported"
    );
    assert_eq!(std::fs::read(&best).unwrap(), published[3]);
    // A slower success: the second distinct version stops the run; the faster one stays best.
    learner.on_eval(report(2, &[21.0, 21.0]));
    assert_eq!(learner.early_stop(), Some(2));
    assert_eq!(std::fs::read(&best).unwrap(), published[3]);
    let summary = learner.finish("test", false, 0).unwrap();
    assert_eq!(summary.duplicate_evals, 1, "{summary:?}");
    assert_eq!(summary.best_eval.map(|e| e.version), Some(3));
    assert_eq!(summary.versions_not_evaluated, [4, 5]);
}

/// Issue 59 item 3: under `collection.early_stop_spawns` a version whose episodes from random spawns crashed does
/// not count toward the early stop nor stays best over one whose did not, and evals.csv gets their columns.
#[test]
fn the_early_stop_judged_on_random_spawns_goes_through_the_learner() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = RunConfig::load("smoke").unwrap();
    config.collection.eval_laps = 2;
    config.collection.early_stop_successes = 2;
    config.collection.early_stop_spawns = 5;
    let run_dir = RunDir::create(tmp.path()).unwrap();
    let mut learner = cabc_outputs::learner(config, run_dir, false).unwrap();
    let published: Vec<_> = (0..4).map(|v| learner.policy_update(v).weights).collect();
    let judged = |version, crashes| EvalReport {
        spawn_episodes: 5,
        spawn_crashes: crashes,
        ..report(version, &[19.0, 19.0])
    };
    let best = tmp.path().join("best-policy.safetensors");
    learner.on_eval(judged(0, 2));
    learner.on_eval(judged(1, 1));
    assert_eq!(learner.early_stop(), None, "two crashed from random spawns");
    assert_eq!(std::fs::read(&best).unwrap(), published[1], "fewer crashes");
    learner.on_eval(judged(2, 0));
    assert_eq!(std::fs::read(&best).unwrap(), published[2], "no crash");
    assert_eq!(learner.early_stop(), None, "one success");
    learner.on_eval(judged(3, 0));
    assert_eq!(learner.early_stop(), Some(3));
    learner.finish("test", false, 0).unwrap();
    let evals = std::fs::read_to_string(tmp.path().join("evals.csv")).unwrap();
    let mut lines = evals.lines();
    assert!(
        lines
            .next()
            .unwrap()
            .ends_with(",steps,spawn_episodes,spawn_crashes"),
        "{evals}"
    );
    assert!(
        lines.next().unwrap().ends_with(",max-laps,100,5,2"),
        "{evals}"
    );
}
