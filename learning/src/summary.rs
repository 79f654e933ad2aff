//! The run's summary: how it ended, the evaluations, what the learner stored and refused. [`Learner::finish`]
//! returns it; the sinks write it (`summary.json`, [`crate::sink::Sink::close`]) and the `learner` binary prints it.
//!
//! [`Learner::finish`]: crate::learner::Learner::finish

use crate::evaluations::EvalSummary;
use cabc_proto::config::Precision;
use serde::Serialize;
use std::collections::BTreeMap;

/// The run's processes restarted so far by its supervisor, by role (`learner`, `expert`, `actor`, `evaluator`), as the
/// `learner` binary reads them from the run folder's `supervision.json` (issue 64): the `restarts_<role>` columns and
/// the summary's `restarts`.
pub type Restarts = Box<dyn Fn() -> BTreeMap<String, u64>>;

/// The roles whose restarts are columns of `metrics.csv`, in order.
pub const RESTARTED_ROLES: [(&str, &str); 4] = [
    ("learner", "restarts_learner"),
    ("expert", "restarts_expert"),
    ("actor", "restarts_actor"),
    ("evaluator", "restarts_evaluator"),
];

/// The run's summary. Its fields are in alphabetical order, the order of `summary.json`'s keys since the file was
/// first written (a JSON object of sorted keys), so that a run's file reads the same as before.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// The access control's refusals by "<subject>: <action> on <key>" (the bus side's count; empty in process).
    pub acl_denied: BTreeMap<String, u64>,
    /// The best evaluation (most laps, then the fastest mean lap).
    pub best_eval: Option<EvalSummary>,
    /// What the last auto-labelling left in D? (the critic's negatives).
    pub d_minus: usize,
    pub d_plus: usize,
    pub d_uncertain: usize,
    /// The device the networks trained on ("cpu", "cuda:0"), and the collection's and evaluation's policy with them
    /// in `learner run --local`.
    pub device: String,
    /// Evaluation reports of a version evaluated before.
    pub duplicate_evals: u64,
    /// Segments the ledger dropped as copies of one stored.
    pub duplicate_segments: u64,
    /// The policy version kept by the early stop.
    pub early_stop_version: Option<u64>,
    /// Why the run ended.
    pub ended: String,
    /// Epochs done.
    pub epochs: usize,
    pub experiment: String,
    /// The expert's lap time, from the laps it drove alone (beta = 1).
    pub expert_lap_time: Option<LapTime>,
    /// The first version whose evaluation completed `collection.eval_laps` laps.
    pub first_version_with_eval_laps: Option<u64>,
    pub lambda: f64,
    pub last_eval: Option<EvalSummary>,
    pub learner_peak_rss_mb: Option<f64>,
    pub mean_epoch_s: f64,
    /// The arithmetic the networks trained in: "bf16" (autocast, CUDA alone) or "fp32" (`training.precision` on a
    /// CPU is fp32).
    pub precision: Precision,
    /// Evaluation reports of versions not published.
    pub refused_evals: u64,
    /// Messages the bus refused (foreign, malformed).
    pub rejected_messages: u64,
    /// The run's processes restarted by its supervisor, by role (`cabc supervise`'s `supervision.json`; absent in a
    /// run without one).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub restarts: Option<BTreeMap<String, u64>>,
    pub rho: f64,
    pub run: String,
    /// Segments refused before the ledger saw them (images not of the run's observation size).
    pub segments_not_stored: u64,
    pub segments_stored: u64,
    pub steps_stored: u64,
    /// What the policy's vision trunk started from.
    pub trunk_init: Option<String>,
    /// Versions published whose evaluations had not arrived when the run ended.
    pub versions_not_evaluated: Vec<u64>,
}

/// A lap time over several laps, in seconds (its fields in alphabetical order, as [`Summary`]'s).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LapTime {
    pub laps: usize,
    pub mean: f64,
    pub std: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fields serialise in the order of a JSON object's sorted keys: `summary.json` (written from the struct)
    /// reads as it did when it was written from a `serde_json::Value`.
    #[test]
    fn the_keys_are_in_sorted_order() {
        let summary = Summary {
            acl_denied: BTreeMap::from([("actor-9: put on x".to_string(), 2)]),
            best_eval: None,
            d_minus: 1,
            d_plus: 2,
            d_uncertain: 3,
            device: "cuda:0".into(),
            duplicate_evals: 4,
            duplicate_segments: 5,
            early_stop_version: Some(6),
            ended: "max_epochs 7 reached".into(),
            epochs: 7,
            experiment: "V-B".into(),
            expert_lap_time: Some(LapTime {
                laps: 2,
                mean: 17.5,
                std: 0.25,
            }),
            first_version_with_eval_laps: None,
            lambda: 1.0,
            last_eval: None,
            learner_peak_rss_mb: Some(f64::NAN),
            mean_epoch_s: 0.5,
            precision: Precision::Bf16,
            refused_evals: 8,
            rejected_messages: 9,
            restarts: Some(BTreeMap::from([("actor".to_string(), 1)])),
            rho: 0.5,
            run: "r".into(),
            segments_not_stored: 10,
            segments_stored: 11,
            steps_stored: 12,
            trunk_init: None,
            versions_not_evaluated: vec![13],
        };
        let value = serde_json::to_value(&summary).unwrap();
        assert_eq!(
            serde_json::to_string_pretty(&summary).unwrap(),
            serde_json::to_string_pretty(&value).unwrap()
        );
        assert_eq!(value["learner_peak_rss_mb"], serde_json::Value::Null);
        assert_eq!(value["expert_lap_time"]["laps"], 2);
        assert_eq!(value["device"], "cuda:0");
        assert_eq!(value["precision"], "bf16");
    }
}
