//! The epoch protocol (architecture.md), zenoh-free so that tests drive it directly.
//!
//! 1. The learner publishes PolicyUpdate j; actors collect their share of the epoch's steps with it, publish their
//!    segments and then an [`EpochDone`] marker.
//! 2. [`EpochGate`] closes epoch j once every live actor (liveliness) has said it is done with j, or once
//!    `timeout` has passed since the epoch opened and at least one actor is done: a dead or stuck actor never
//!    stalls the run.
//! 3. [`Ledger`] makes delivery exactly-once: a segment is identified by (actor, seq); a duplicate is dropped and
//!    counted, and segments of older versions that arrive late are still stored.

use cabc_proto::messages::{EpochDone, Segment};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::time::{Duration, Instant};

/// Why an epoch closed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Closed {
    /// Every live actor is done.
    AllDone,
    /// The timeout passed; these live actors had not said they were done.
    Timeout { missing: Vec<String> },
}

/// Decides when epoch `version` is complete.
#[derive(Debug)]
pub struct EpochGate {
    version: u64,
    opened: Instant,
    timeout: Duration,
    live: BTreeSet<String>,
    done: BTreeMap<String, EpochDone>,
}

impl EpochGate {
    /// Opens epoch `version`; `live` are the actors alive right now.
    pub fn open(
        version: u64,
        timeout: Duration,
        live: impl IntoIterator<Item = String>,
        now: Instant,
    ) -> Self {
        EpochGate {
            version,
            opened: now,
            timeout,
            live: live.into_iter().collect(),
            done: BTreeMap::new(),
        }
    }

    pub fn version(&self) -> u64 {
        self.version
    }

    pub fn alive(&mut self, actor: &str) {
        self.live.insert(actor.to_string());
    }

    pub fn gone(&mut self, actor: &str) {
        self.live.remove(actor);
    }

    /// Records a marker; markers of other versions are ignored (returns false).
    pub fn done(&mut self, marker: EpochDone) -> bool {
        if marker.version != self.version {
            return false;
        }
        self.done.insert(marker.actor.clone(), marker);
        true
    }

    /// The markers received so far.
    pub fn markers(&self) -> impl Iterator<Item = &EpochDone> {
        self.done.values()
    }

    /// Live actors not yet done.
    pub fn missing(&self) -> Vec<String> {
        self.live
            .iter()
            .filter(|a| !self.done.contains_key(*a))
            .cloned()
            .collect()
    }

    /// Whether the epoch can close now.
    pub fn closed(&self, now: Instant) -> Option<Closed> {
        if self.done.is_empty() {
            return None;
        }
        let missing = self.missing();
        if missing.is_empty() {
            Some(Closed::AllDone)
        } else if now.duration_since(self.opened) >= self.timeout {
            Some(Closed::Timeout { missing })
        } else {
            None
        }
    }
}

/// Which segments were stored, so that each one is stored exactly once (saved with the checkpoint).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Ledger {
    seen: HashMap<String, HashSet<u64>>,
    pub duplicates: u64,
    pub stored_segments: u64,
    pub stored_steps: u64,
}

impl Ledger {
    /// True the first time a segment is offered.
    pub fn admit(&mut self, segment: &Segment) -> bool {
        let fresh = self
            .seen
            .entry(segment.actor.clone())
            .or_default()
            .insert(segment.seq);
        if fresh {
            self.stored_segments += 1;
            self.stored_steps += segment.steps.len() as u64;
        } else {
            self.duplicates += 1;
        }
        fresh
    }

    /// Segments stored from one actor.
    pub fn segments_of(&self, actor: &str) -> usize {
        self.seen.get(actor).map_or(0, |s| s.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Outcome;

    fn marker(actor: &str, version: u64) -> EpochDone {
        EpochDone {
            actor: actor.into(),
            version,
            segments: 1,
            steps: 10,
        }
    }

    #[test]
    fn closes_when_every_live_actor_is_done() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(3, Duration::from_secs(60), ["a".into(), "b".into()], t0);
        assert_eq!(g.closed(t0), None);
        assert!(g.done(marker("a", 3)));
        assert_eq!(g.closed(t0), None);
        assert!(!g.done(marker("b", 2)), "another version's marker");
        assert_eq!(g.closed(t0), None);
        assert!(g.done(marker("b", 3)));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
    }

    #[test]
    fn a_dead_actor_does_not_stall_the_epoch() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(60), ["a".into(), "b".into()], t0);
        g.done(marker("a", 0));
        g.gone("b");
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
    }

    #[test]
    fn a_stuck_actor_is_left_behind_after_the_timeout() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(5), ["a".into(), "b".into()], t0);
        g.done(marker("a", 0));
        assert_eq!(g.closed(t0 + Duration::from_secs(4)), None);
        assert_eq!(
            g.closed(t0 + Duration::from_secs(5)),
            Some(Closed::Timeout {
                missing: vec!["b".into()]
            })
        );
    }

    #[test]
    fn no_marker_no_close_even_after_the_timeout() {
        let t0 = Instant::now();
        let g = EpochGate::open(0, Duration::from_secs(1), Vec::<String>::new(), t0);
        assert_eq!(g.closed(t0 + Duration::from_secs(100)), None);
    }

    #[test]
    fn an_actor_joining_late_is_waited_for() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(60), ["a".into()], t0);
        g.alive("c");
        g.done(marker("a", 0));
        assert_eq!(g.closed(t0), None);
        assert_eq!(g.missing(), vec!["c".to_string()]);
    }

    #[test]
    fn the_ledger_admits_each_segment_once() {
        let seg = |actor: &str, seq| Segment {
            actor: actor.into(),
            env: 0,
            episode: 0,
            seq,
            policy_version: 0,
            outcome: Outcome::Lap,
            steps: vec![],
        };
        let mut l = Ledger::default();
        assert!(l.admit(&seg("a", 0)));
        assert!(l.admit(&seg("a", 1)));
        assert!(l.admit(&seg("b", 0)));
        assert!(!l.admit(&seg("a", 1)));
        assert_eq!((l.stored_segments, l.duplicates), (3, 1));
        assert_eq!(l.segments_of("a"), 2);
    }
}
