//! The run's evaluations: the evaluator drives each published policy version alone from the fixed spawn and reports
//! it. Kept here: every version's summary, early stopping (the `collection.early_stop_successes`-th distinct version
//! that completes `collection.eval_laps` laps stops the run; under `collection.early_stop_spawns`, a version that also
//! completed its laps from every one of that many random spawns under noise), the best version (whose weights go to
//! `best-policy.safetensors` through the [`Sink`]), and the reports refused (a version not published yet) or ignored
//! (a second report of a version).

use crate::record::Record;
use cabc_proto::config::CollectionSection;
use cabc_proto::messages::EvalReport;
use cabc_proto::stats::mean_std;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};

/// Published versions' weights are kept until their evaluation arrives (the best evaluated one is written to
/// `best-policy.safetensors`, whatever its version), up to this many bytes together (a ResNet-18 policy is 45 MB, so
/// 11 versions; the full-state MLP is 0.1 MB): past it the oldest are dropped, logged; the newest always stays.
const PENDING_WEIGHT_BYTES: usize = 512 << 20;

/// An evaluation, without its line.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalSummary {
    pub version: u64,
    pub laps: u32,
    pub lap_mean: Option<f64>,
    pub lap_std: Option<f64>,
    pub lap_min: Option<f64>,
    pub lap_max: Option<f64>,
    pub end_reason: String,
    pub steps: u64,
    /// Episodes from random spawns the early stop judged the version on (`collection.early_stop_spawns`; 0 without
    /// the key, or when the fixed spawn did not complete its laps), and how many of them did not complete theirs.
    /// Checkpoints and tables written before them hold none: 0.
    #[serde(default)]
    pub spawn_episodes: u32,
    #[serde(default)]
    pub spawn_crashes: u32,
}

impl EvalSummary {
    /// The better of two evaluations: more laps, then fewer crashes from the early stop's random spawns (none
    /// without `collection.early_stop_spawns`), then a lower mean lap time (ties: the earlier one stays best).
    pub fn better_than(&self, other: &EvalSummary) -> bool {
        let fewer_crashes = other.spawn_crashes.cmp(&self.spawn_crashes);
        match self.laps.cmp(&other.laps).then(fewer_crashes) {
            std::cmp::Ordering::Greater => true,
            std::cmp::Ordering::Less => false,
            std::cmp::Ordering::Equal => match (self.lap_mean, other.lap_mean) {
                (Some(a), Some(b)) => a < b,
                (Some(_), None) => true,
                _ => false,
            },
        }
    }

    pub fn of(report: &EvalReport) -> Self {
        let ms = mean_std(&report.lap_times);
        let fold = |f: fn(f64, f64) -> f64| report.lap_times.iter().copied().reduce(f);
        EvalSummary {
            version: report.version,
            laps: report.laps,
            lap_mean: ms.map(|m| m.0),
            lap_std: ms.map(|m| m.1),
            lap_min: fold(f64::min),
            lap_max: fold(f64::max),
            end_reason: report.end_reason.to_string(),
            steps: report.steps,
            spawn_episodes: report.spawn_episodes,
            spawn_crashes: report.spawn_crashes,
        }
    }
}

/// Whether `report` counts toward the early stop: it completed `eval_laps` laps from the fixed spawn and, under
/// `early_stop_spawns`, drove at least that many episodes from random spawns, none of which crashed.
pub fn counts_toward_early_stop(report: &EvalReport, rules: &CollectionSection) -> bool {
    let judged = rules.early_stop_spawns == 0
        || (report.spawn_episodes >= rules.early_stop_spawns && report.spawn_crashes == 0);
    report.laps >= rules.eval_laps && judged
}

/// The evaluations of a run. `evals`, `successes` and `early_stop` are saved with each checkpoint (as the learner
/// state's fields of those names; a checkpoint written before `early_stop` was saved has none); the rest lives as
/// long as the process.
#[derive(Default, Serialize, Deserialize)]
#[serde(default)]
pub struct Evaluations {
    /// Every version evaluated, in the order the reports arrived.
    pub evals: Vec<EvalSummary>,
    /// Evaluations that counted toward the early stop ([`counts_toward_early_stop`]; distinct versions).
    pub successes: u32,
    /// Published versions' weights awaiting their evaluation.
    #[serde(skip)]
    pending: BTreeMap<u64, Vec<u8>>,
    /// The newest version published: reports of later versions are refused.
    #[serde(skip)]
    published: Option<u64>,
    #[serde(skip)]
    refused: u64,
    #[serde(skip)]
    duplicates: u64,
    /// The version that stopped the run early, once decided: a run interrupted in the epoch that decided it ends there
    /// when resumed.
    early_stop: Option<u64>,
    /// The last report taken in, with its line.
    #[serde(skip)]
    last: Option<EvalReport>,
}

impl std::fmt::Debug for Evaluations {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Evaluations")
            .field("evals", &self.evals)
            .field("successes", &self.successes)
            .field("published", &self.published)
            .field("early_stop", &self.early_stop)
            .finish_non_exhaustive()
    }
}

impl Evaluations {
    /// Version `version` is published with `weights`: they are held until its report arrives (see
    /// [`PENDING_WEIGHT_BYTES`]).
    pub fn publish(&mut self, version: u64, weights: Vec<u8>) {
        self.pending.insert(version, weights);
        let mut held: usize = self.pending.values().map(Vec::len).sum();
        while held > PENDING_WEIGHT_BYTES && self.pending.len() > 1 {
            if let Some((version, dropped)) = self.pending.pop_first() {
                held -= dropped.len();
                tracing::warn!(
                    version,
                    "no evaluation of version {version} yet, and the versions awaiting one hold over \
                     {} MB: its weights are dropped (it cannot become best-policy.safetensors)",
                    PENDING_WEIGHT_BYTES >> 20
                );
            }
        }
        self.published = Some(version);
    }

    /// An evaluation report: taken in and handed to `taken` (the learner's sink; counting toward early stopping when it completed
    /// `eval_laps` laps, and under `early_stop_spawns` none of its episodes from random spawns crashed), or refused and counted when its version is not published yet (the bus already checked
    /// that it came from an evaluator under its own name), or ignored and counted when its version was evaluated
    /// already (early stopping counts distinct versions).
    pub fn take(
        &mut self,
        report: EvalReport,
        rules: &CollectionSection,
        taken: impl FnOnce(&Taken<'_>),
    ) {
        if self
            .published
            .is_none_or(|published| report.version > published)
        {
            self.refused += 1;
            tracing::warn!(
                actor = report.actor,
                version = report.version,
                published = ?self.published,
                "evaluation report of a version not published: refused"
            );
            return;
        }
        if self.evals.iter().any(|e| e.version == report.version) {
            self.duplicates += 1;
            tracing::warn!(
                actor = report.actor,
                version = report.version,
                "a second evaluation of a version: ignored (early stopping counts distinct versions)"
            );
            return;
        }
        let summary = EvalSummary::of(&report);
        let weights = self.pending.remove(&report.version);
        let best = self.evals.iter().all(|e| summary.better_than(e));
        if best && weights.is_none() {
            tracing::warn!(
                version = report.version,
                "the best evaluation so far, but its weights are no longer held"
            );
        }
        tracing::info!(
            version = report.version,
            laps = report.laps,
            end = %report.end_reason,
            lap_mean = ?summary.lap_mean,
            spawn_episodes = report.spawn_episodes,
            spawn_crashes = report.spawn_crashes,
            "evaluation"
        );
        let completed = report.laps >= rules.eval_laps;
        if counts_toward_early_stop(&report, rules) {
            self.successes += 1;
            if self.successes >= rules.early_stop_successes && self.early_stop.is_none() {
                self.early_stop = Some(report.version);
            }
        }
        taken(&Taken {
            report: &report,
            summary: &summary,
            best,
            completed,
            weights: weights.as_deref().filter(|_| best),
        });
        self.evals.push(summary);
        self.last = Some(report);
    }

    /// The epoch's evaluation metrics: the last version evaluated and its laps, the reports refused and ignored.
    pub fn put(&self, record: &mut Record) {
        if let Some(last) = &self.last {
            record.count("eval_version", last.version);
            record.count("eval_laps", last.laps);
        }
        record.count("refused_evals", self.refused);
        record.count("duplicate_evals", self.duplicates);
    }

    /// The newest version published (none before the first [`Evaluations::publish`]).
    pub fn published(&self) -> Option<u64> {
        self.published
    }

    /// The version that stopped the run early, once decided.
    pub fn early_stop(&self) -> Option<u64> {
        self.early_stop
    }

    /// The last report taken in (with its line).
    pub fn last(&self) -> Option<&EvalReport> {
        self.last.as_ref()
    }

    /// Reports refused: their version was not published yet.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Second reports of a version, ignored.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    /// The best evaluation ([`EvalSummary::better_than`]; ties: the earlier).
    pub fn best(&self) -> Option<&EvalSummary> {
        self.evals
            .iter()
            .reduce(|best, e| if e.better_than(best) { e } else { best })
    }

    /// The first version (in the order reports arrived) that completed `laps` laps.
    pub fn first_completing(&self, laps: u32) -> Option<u64> {
        self.evals
            .iter()
            .find(|e| e.laps >= laps)
            .map(|e| e.version)
    }

    /// Published versions with no evaluation report.
    pub fn not_evaluated(&self) -> Vec<u64> {
        let evaluated: HashSet<u64> = self.evals.iter().map(|e| e.version).collect();
        let published = self.published.map_or(0, |p| p + 1);
        (0..published).filter(|v| !evaluated.contains(v)).collect()
    }
}

/// An evaluation the run took in (neither refused nor a second report of its version).
pub struct Taken<'a> {
    pub report: &'a EvalReport,
    pub summary: &'a EvalSummary,
    /// Whether it is the best evaluation so far ([`EvalSummary::better_than`] every earlier one).
    pub best: bool,
    /// Whether it completed `collection.eval_laps` laps from the fixed spawn (whatever its episodes from random
    /// spawns did: [`counts_toward_early_stop`] says whether it counts).
    pub completed: bool,
    /// The version's weights, when it is the best so far and they are still held.
    pub weights: Option<&'a [u8]>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::EndReason;

    /// What the learner's sink is told of each evaluation: (version, best, completed, weights).
    #[derive(Default)]
    struct Told(Vec<(u64, bool, bool, Option<Vec<u8>>)>);

    impl Told {
        fn take(&mut self) -> impl FnOnce(&Taken<'_>) + '_ {
            |t| {
                let weights = t.weights.map(<[u8]>::to_vec);
                self.0
                    .push((t.report.version, t.best, t.completed, weights));
            }
        }
    }

    fn report(version: u64, laps: u32) -> EvalReport {
        EvalReport {
            actor: "eval-0".into(),
            version,
            laps,
            lap_times: vec![20.0; laps as usize],
            end_reason: EndReason::OutOfTrack,
            steps: 10,
            line: Vec::new(),
            spawn_episodes: 0,
            spawn_crashes: 0,
        }
    }

    #[test]
    fn refused_ignored_best_and_early_stop_go_through_the_port() {
        let rules = CollectionSection {
            eval_laps: 2,
            early_stop_successes: 2,
            ..CollectionSection::default()
        };
        let (mut evals, mut told) = (Evaluations::default(), Told::default());
        evals.take(report(0, 0), &rules, told.take());
        (0..4).for_each(|v| evals.publish(v, vec![v as u8]));
        evals.take(report(5, 9), &rules, told.take());
        evals.take(report(1, 2), &rules, told.take());
        evals.take(report(1, 2), &rules, told.take());
        evals.take(report(0, 1), &rules, told.take());
        assert_eq!(evals.early_stop(), None);
        evals.take(report(3, 2), &rules, told.take());
        assert_eq!(evals.early_stop(), Some(3));
        assert_eq!(
            told.0,
            [
                (1, true, true, Some(vec![1])),
                (0, false, false, None),
                (3, false, true, None)
            ]
        );
        assert_eq!((evals.refused(), evals.duplicates()), (2, 1));
        assert_eq!(evals.not_evaluated(), [2]);
        let mut record = Record::new(4);
        evals.put(&mut record);
        assert_eq!(
            record.to_string(),
            "epoch=4 eval_version=3 eval_laps=2 refused_evals=2 duplicate_evals=1"
        );
    }

    /// `report(version, laps)` with `episodes` episodes from random spawns, `crashes` of them crashed.
    fn judged(version: u64, laps: u32, episodes: u32, crashes: u32) -> EvalReport {
        EvalReport {
            spawn_episodes: episodes,
            spawn_crashes: crashes,
            ..report(version, laps)
        }
    }

    /// Under `early_stop_spawns`, a version counts toward the early stop only when it completed its laps from the
    /// fixed spawn and from every random spawn asked for: one whose episodes crashed, or that drove fewer than
    /// asked, does not; one that crashed is not best over one that did not; without the key the same reports count
    /// as before.
    #[test]
    fn a_version_that_crashed_from_random_spawns_does_not_count() {
        let without = CollectionSection {
            eval_laps: 2,
            early_stop_successes: 2,
            ..CollectionSection::default()
        };
        let with = CollectionSection {
            early_stop_spawns: 3,
            ..without.clone()
        };
        let reports = [
            judged(0, 2, 3, 1),
            judged(1, 2, 2, 0),
            judged(2, 1, 0, 0),
            judged(3, 2, 3, 0),
            judged(4, 2, 3, 0),
        ];
        let (mut evals, mut told) = (Evaluations::default(), Told::default());
        (0..5).for_each(|v| evals.publish(v, vec![v as u8]));
        for (i, r) in reports.iter().enumerate() {
            evals.take(r.clone(), &with, told.take());
            assert_eq!(evals.early_stop(), (i == 4).then_some(4), "version {i}");
        }
        assert_eq!(evals.successes, 2);
        // Completed stays the fixed spawn's laps; the best is the first with no crash among those of most laps.
        assert_eq!(
            told.0,
            [
                (0, true, true, Some(vec![0])),
                (1, true, true, Some(vec![1])),
                (2, false, false, None),
                (3, false, true, None),
                (4, false, true, None),
            ]
        );
        assert_eq!(evals.best().map(|b| b.version), Some(1));
        assert_eq!(
            (evals.evals[0].spawn_episodes, evals.evals[0].spawn_crashes),
            (3, 1)
        );
        // Without the key (0 spawns) the fixed spawn alone decides, whatever a report says of random spawns.
        let mut evals = Evaluations::default();
        (0..5).for_each(|v| evals.publish(v, vec![]));
        for r in &reports[..2] {
            evals.take(r.clone(), &without, |_| {});
        }
        assert_eq!((evals.successes, evals.early_stop()), (2, Some(1)));
        assert!(counts_toward_early_stop(&reports[0], &without));
        assert!(!counts_toward_early_stop(&reports[0], &with));
        assert!(!counts_toward_early_stop(&reports[2], &without));
    }
}
