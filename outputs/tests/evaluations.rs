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
