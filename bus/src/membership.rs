//! Who the learner deals an epoch's steps to (issue 64's live set, issue 74's one type): the actors alive (their
//! liveliness tokens), those that left and did not come back, the run's `actors.count` that the first epoch waits for
//! while some have not been seen, and the actors alive last, to whom a publication made while none is alive (a router
//! restarting, a link cut: they all left at once) is dealt. [`EpochGate`](crate::gate::EpochGate) decides when one
//! round of an epoch closes; this type says over whom the rounds are dealt. Pure logic, tested without zenoh.

use std::collections::BTreeSet;

/// The learner's view of its actors between and across epochs.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Membership {
    live: BTreeSet<String>,
    /// Actors that left and did not come back.
    left: BTreeSet<String>,
    /// The run's actors (`actors.count`) until the first epoch this learner gathers has closed; 0 after.
    expected: usize,
    /// The count an epoch was last dealt over while some actor was alive.
    last_members: usize,
    /// The actors alive last while some were.
    last_live: BTreeSet<String>,
}

impl Membership {
    /// A learner's view before any liveliness arrived, in a run of `expected` actors.
    pub fn new(expected: usize) -> Self {
        Membership {
            expected,
            ..Membership::default()
        }
    }

    /// `actor`'s liveliness token appeared.
    pub fn joined(&mut self, actor: &str) {
        self.left.remove(actor);
        self.live.insert(actor.to_string());
    }

    /// `actor`'s liveliness token went.
    pub fn left(&mut self, actor: &str) {
        self.live.remove(actor);
        self.left.insert(actor.to_string());
    }

    /// After a batch of liveliness changes: actors that left at once (their tokens' deletions arrive together) stay
    /// the last live set.
    pub fn settled(&mut self) {
        if !self.live.is_empty() {
            self.last_live = self.live.clone();
        }
    }

    pub fn live(&self) -> &BTreeSet<String> {
        &self.live
    }

    /// How many actors an epoch's steps are dealt over now: the live ones, or, in the first epoch this learner
    /// gathers, the run's `actors.count` less those that left while some have not been seen yet. With none alive, as
    /// many as were alive last; at least one.
    pub fn members(&mut self) -> usize {
        let now = self
            .live
            .len()
            .max(self.expected.saturating_sub(self.left.len()));
        if now > 0 {
            self.last_members = now;
        }
        self.last_members.max(1)
    }

    /// The actors a publication made now is dealt to, whom its round waits for: the live ones, or with none alive
    /// those alive last.
    pub fn dealt_to(&self) -> BTreeSet<String> {
        if self.live.is_empty() {
            self.last_live.clone()
        } else {
            self.live.clone()
        }
    }

    /// How many actors' markers an epoch's first round waits for (a grace at most) even when fewer are known to be
    /// alive: the run's `actors.count` less those that left, in the first epoch this learner gathers; after it, 0
    /// (the live set alone counts). Taking it ends the first epoch's expectation.
    pub fn take_expected(&mut self) -> usize {
        let expecting = self.expected.saturating_sub(self.left.len());
        self.expected = 0;
        expecting
    }

    /// How many the undone part of a share is dealt over again: the live actors, or with none alive as many as
    /// were alive last (its round waits for them as they come back).
    pub fn dealt_again(&mut self) -> usize {
        if self.live.is_empty() {
            self.members()
        } else {
            self.live.len()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_epoch_is_dealt_over_the_run_s_count_until_its_actors_are_seen() {
        let mut m = Membership::new(2);
        assert_eq!(m.members(), 2, "none seen yet: actors.count");
        m.joined("actor-0");
        assert_eq!(m.members(), 2, "one of two seen");
        m.joined("actor-1");
        m.joined("actor-2");
        assert_eq!(m.members(), 3, "more alive than the count");
        assert_eq!(m.take_expected(), 2);
        assert_eq!(
            m.take_expected(),
            0,
            "after the first epoch the live set alone counts"
        );
    }

    #[test]
    fn an_actor_that_leaves_before_it_was_seen_lowers_the_first_epoch_s_count() {
        let mut m = Membership::new(3);
        m.joined("actor-0");
        m.joined("actor-1");
        m.left("actor-1");
        assert_eq!(m.members(), 2, "3 expected, 1 left: 2");
        assert_eq!(m.take_expected(), 2);
        m.joined("actor-1");
        assert_eq!(m.members(), 2, "it came back");
    }

    #[test]
    fn with_none_alive_the_last_live_set_is_dealt_to() {
        let mut m = Membership::new(0);
        for a in ["actor-0", "actor-1"] {
            m.joined(a);
        }
        m.settled();
        assert_eq!(m.members(), 2);
        // A router restarts: both tokens go in one batch.
        m.left("actor-0");
        m.left("actor-1");
        m.settled();
        assert!(m.live().is_empty());
        assert_eq!(m.members(), 2, "as many as were alive last");
        assert_eq!(m.dealt_to().len(), 2, "to those alive last");
        assert_eq!(m.dealt_again(), 2);
        // One is back: the live set counts again.
        m.joined("actor-1");
        m.settled();
        assert_eq!(m.dealt_to().into_iter().collect::<Vec<_>>(), ["actor-1"]);
        assert_eq!((m.members(), m.dealt_again()), (1, 1));
    }

    #[test]
    fn actors_leaving_one_batch_at_a_time_keep_the_last_set_of_each_batch() {
        let mut m = Membership::new(0);
        for a in ["actor-0", "actor-1", "actor-2"] {
            m.joined(a);
        }
        m.settled();
        m.left("actor-2");
        m.settled();
        m.left("actor-0");
        m.left("actor-1");
        m.settled();
        assert_eq!(
            m.dealt_to().into_iter().collect::<Vec<_>>(),
            ["actor-0", "actor-1"]
        );
    }
}
