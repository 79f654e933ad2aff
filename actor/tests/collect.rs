//! The collector end to end without a bus: the PID lane follower answers as the expert, a fixed function stands in
//! for the policy, and the segments of three epochs must come out exactly as they did before the collector stepped
//! `sim::EnvBatch` (a digest of every number of every segment).

use cabc_actor::collect::Collector;
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{ExpertAnswer, Outcome, Segment};
use cabc_sim::pid::PidLaneFollower;
use std::hash::{Hash, Hasher};

fn answer(n: usize, frenet: &[f64; 6]) -> ExpertAnswer {
    let u = PidLaneFollower::new(1.2).action(frenet[0], frenet[4], frenet[5]);
    ExpertAnswer {
        action: u,
        // Every 37th query fails, so expert-failure segments and patience are exercised too.
        success: n % 37 != 36,
        status: String::new(),
        iterations: 0,
        solve_time_us: 0,
    }
}

/// Collects three epochs and returns the segments.
fn collect(config: &RunConfig, budget: u64) -> Vec<Segment> {
    let mut collector = Collector::new("golden", 1, config);
    let (mut out, mut n) = (Vec::new(), 0usize);
    for version in 0..3u64 {
        collector.begin_epoch();
        while collector.taken() < budget {
            let active = collector.active(budget);
            let answers: Vec<ExpertAnswer> = collector
                .queries(active)
                .iter()
                .map(|q| {
                    n += 1;
                    answer(n, &q.frenet)
                })
                .collect();
            let input = collector.observations(active);
            assert_eq!(input.states.len(), active);
            let policy: Vec<[f32; 2]> = input
                .states
                .iter()
                .map(|s| {
                    [
                        0.8 - s[0] * 0.3,
                        -0.9 * s[4] - 0.4 * s[5] + 0.05 * s[3].sin(),
                    ]
                })
                .collect();
            collector.step(&answers, &policy, 0.6, version, &mut out);
        }
        collector.end_epoch(version, &mut out);
    }
    out
}

/// A hash of every number of every segment. std's hasher is deterministic but may change with the toolchain: if a
/// Rust update alone breaks the digests, re-record them from a commit whose behaviour is trusted.
fn digest(segments: &[Segment]) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    // Recorded before segments carried an incarnation (0 in-process): left out, the digest still checks the data.
    format!("{segments:?}")
        .replace("incarnation: 0, ", "")
        .hash(&mut h);
    h.finish()
}

#[test]
fn state_collection_is_unchanged() {
    let config = RunConfig::load("smoke").unwrap();
    let segments = collect(&config, 1500);
    let steps: usize = segments.iter().map(|s| s.steps.len()).sum();
    assert_eq!(steps, 4500);
    assert!(segments.iter().any(|s| s.outcome == Outcome::Lap));
    assert!(segments.iter().any(|s| s.outcome == Outcome::ExpertFailure));
    assert_eq!(
        digest(&segments),
        13490823466596415851,
        "{} segments",
        segments.len()
    );
}

#[test]
fn camera_collection_is_unchanged() {
    let mut config = RunConfig::load("smoke").unwrap();
    config.observation.kind = ObservationKind::Camera;
    (config.observation.width, config.observation.height) = (16, 12);
    let segments = collect(&config, 301);
    assert!(segments
        .iter()
        .flat_map(|s| &s.steps)
        .all(|s| s.image.as_ref().is_some_and(|i| i.rgb.len() == 16 * 12 * 3)));
    assert_eq!(
        digest(&segments),
        13991557341307712987,
        "{} segments",
        segments.len()
    );
}
