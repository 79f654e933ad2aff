//! Exactly-once storage: a segment is identified by (actor, incarnation, seq), so a restarted actor (a new
//! incarnation whose `seq` starts again at 0) is told apart from a duplicate; a duplicate is dropped and counted,
//! and segments of older versions that arrive late are still stored. Saved with the checkpoint.

use cabc_proto::messages::Segment;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};

/// Which segments were stored, so that each one is stored exactly once (saved with the checkpoint).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Ledger {
    /// Seqs admitted per `<actor>/<incarnation>`.
    seen: HashMap<String, HashSet<u64>>,
    pub duplicates: u64,
    pub stored_segments: u64,
    pub stored_steps: u64,
}

impl Ledger {
    /// Whether a segment with this (actor, incarnation, seq) was admitted before (a duplicate, counted).
    pub fn seen(&mut self, segment: &Segment) -> bool {
        let seen = self
            .seen
            .get(&Self::key(segment))
            .is_some_and(|seqs| seqs.contains(&segment.seq));
        if seen {
            self.duplicates += 1;
        }
        seen
    }

    /// Marks a segment admitted: its copies offered later are duplicates ([`Ledger::seen`]). Counted stored by
    /// [`Ledger::stored`] once the replay holds it.
    pub fn admit(&mut self, segment: &Segment) {
        self.seen
            .entry(Self::key(segment))
            .or_default()
            .insert(segment.seq);
    }

    /// Counts an admitted segment stored in the replay.
    pub fn stored(&mut self, segment: &Segment) {
        self.stored_segments += 1;
        self.stored_steps += segment.steps.len() as u64;
    }

    fn key(segment: &Segment) -> String {
        format!("{}/{}", segment.actor, segment.incarnation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Outcome;

    /// A segment offered as the learner offers it: a new one is admitted, then stored; whether it was new.
    fn offer(l: &mut Ledger, s: &Segment) -> bool {
        let new = !l.seen(s);
        if new {
            l.admit(s);
            l.stored(s);
        }
        new
    }

    /// An empty segment of `actor`'s incarnation `incarnation`, number `seq`.
    fn seg(actor: &str, incarnation: u64, seq: u64) -> Segment {
        Segment {
            actor: actor.into(),
            env: 0,
            episode: 0,
            incarnation,
            seq,
            policy_version: 0,
            outcome: Outcome::Lap,
            steps: vec![],
        }
    }

    #[test]
    fn the_ledger_admits_each_segment_once() {
        let mut l = Ledger::default();
        let mut offer = |s: Segment| offer(&mut l, &s);
        assert!(offer(seg("a", 0, 0)));
        assert!(offer(seg("a", 0, 1)));
        assert!(offer(seg("b", 0, 0)));
        assert!(!offer(seg("a", 0, 1)));
        assert_eq!((l.stored_segments, l.duplicates), (3, 1));
    }

    #[test]
    fn a_restarted_actor_is_not_a_duplicate() {
        let mut l = Ledger::default();
        let mut offer = |s: Segment| offer(&mut l, &s);
        assert!(offer(seg("a", 1, 0)));
        assert!(offer(seg("a", 1, 1)));
        assert!(offer(seg("a", 2, 0)), "the restart's first segment is new");
        assert!(!offer(seg("a", 2, 0)));
        assert_eq!((l.stored_segments, l.duplicates), (3, 1));
        assert!(
            l.seen(&seg("a", 1, 1)) && !l.seen(&seg("a", 3, 1)),
            "each incarnation its own seqs"
        );
    }
}
