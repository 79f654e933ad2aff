//! Exactly-once storage: a segment is identified by (actor, incarnation, seq), so a restarted actor (a new
//! incarnation whose `seq` starts again at 0) is told apart from a duplicate; a duplicate is dropped and counted,
//! and segments of older versions that arrive late are still stored. Saved with the checkpoint.

use cabc_proto::messages::Segment;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};

/// Which segments were stored, so that each one is stored exactly once (saved with the checkpoint).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Ledger {
    /// Seqs stored per `<actor>/<incarnation>`.
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
            .entry(format!("{}/{}", segment.actor, segment.incarnation))
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

    /// Segments stored from one actor (all its incarnations).
    pub fn segments_of(&self, actor: &str) -> usize {
        self.seen
            .iter()
            .filter(|(key, _)| key.rsplit_once('/').map(|(a, _)| a) == Some(actor))
            .map(|(_, seqs)| seqs.len())
            .sum()
    }

    /// Incarnations seen of one actor.
    pub fn incarnations_of(&self, actor: &str) -> usize {
        self.seen
            .keys()
            .filter(|key| key.rsplit_once('/').map(|(a, _)| a) == Some(actor))
            .count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Outcome;

    #[test]
    fn the_ledger_admits_each_segment_once() {
        let seg = |actor: &str, seq| Segment {
            actor: actor.into(),
            env: 0,
            episode: 0,
            incarnation: 0,
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

    #[test]
    fn a_restarted_actor_is_not_a_duplicate() {
        let seg = |incarnation, seq| Segment {
            actor: "a".into(),
            env: 0,
            episode: 0,
            incarnation,
            seq,
            policy_version: 0,
            outcome: Outcome::Lap,
            steps: vec![],
        };
        let mut l = Ledger::default();
        assert!(l.admit(&seg(1, 0)));
        assert!(l.admit(&seg(1, 1)));
        assert!(l.admit(&seg(2, 0)), "the restart's first segment is new");
        assert!(!l.admit(&seg(2, 0)));
        assert_eq!((l.stored_segments, l.duplicates), (3, 1));
        assert_eq!((l.segments_of("a"), l.incarnations_of("a")), (3, 2));
    }
}
