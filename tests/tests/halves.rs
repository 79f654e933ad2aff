//! The actor's environments step in two halves that alternate (one half's relabelling travels while the other half
//! steps): with the MPCC expert, whose answers depend on each stream's warm start, the data must be what whole-batch
//! steps give, whether the expert answers at once or only when asked for the answers.

use cabc_actor::collect::Collector;
use cabc_actor::local::Deferred;
use cabc_expert::mpcc::Mpcc;
use cabc_expert::relabel::{Expert, Relabeller};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::Segment;
use cabc_proto::ports::{ExpertClient, PortError};
use std::sync::Arc;

fn config() -> RunConfig {
    let mut c = RunConfig::load("v-b").unwrap();
    c.actors.envs_per_actor = 4;
    c
}

fn relabeller() -> Relabeller {
    let c = config();
    Relabeller::new(
        Expert::Mpcc(Arc::new(Mpcc::reference())),
        c.expert.max_streams,
        c.expert.max_batch,
    )
}

/// A fixed stand-in for the policy.
fn policy(states: &[[f32; 6]]) -> Vec<[f32; 2]> {
    states
        .iter()
        .map(|s| [0.5 - 0.2 * s[0], -0.8 * s[4] - 0.3 * s[5]])
        .collect()
}

const BUDGET: u64 = 240;
const BETA: f64 = 0.7;

fn whole_batches() -> Vec<Segment> {
    let mut expert = relabeller();
    let mut collector = Collector::new("a", 0, &config()).unwrap();
    let mut out = Vec::new();
    for version in 0..2 {
        collector.begin_epoch();
        while collector.taken() < BUDGET {
            let n = (BUDGET - collector.taken()).min(collector.len() as u64) as usize;
            let answers = expert.relabel(collector.queries(0..n)).unwrap();
            let actions = policy(collector.observations(0..n).states);
            collector.step(0, &answers, &actions, BETA, version, &mut out);
        }
        collector.end_epoch(version, &mut out);
    }
    out
}

fn halves(expert: &mut dyn ExpertClient) -> Vec<Segment> {
    let mut collector = Collector::new("a", 0, &config()).unwrap();
    let mut out = Vec::new();
    for version in 0..2 {
        collector.begin_epoch();
        let ended = collector
            .collect(
                BUDGET,
                BETA,
                version,
                expert,
                |input| Ok::<_, PortError>(policy(input.states)),
                |segments| {
                    out.append(segments);
                    Ok(None)
                },
            )
            .unwrap();
        assert!(ended.is_none());
        collector.end_epoch(version, &mut out);
    }
    out
}

#[test]
fn mpcc_data_is_the_same_in_halves() {
    let whole = whole_batches();
    assert!(whole.len() > 2, "{} segments", whole.len());
    let mut at_once = relabeller();
    assert!(halves(&mut at_once) == whole, "answered at once");
    let mut deferred = Deferred::new(relabeller());
    assert!(halves(&mut deferred) == whole, "answered when asked");
}
