//! The epoch protocol over the bus (architecture.md): when is an epoch's collection over?
//!
//! The learner publishes PolicyUpdate j; actors collect their share of the epoch's steps with it, publish their
//! segments and then an [`EpochDone`] marker. [`EpochGate`] closes epoch j once every live actor (liveliness) has
//! said it is done with j, or once `timeout` has passed since the epoch opened and at least one actor is done: a
//! dead or stuck actor never stalls the run. Pure logic, tested without zenoh.

use cabc_proto::messages::EpochDone;
use std::collections::{BTreeMap, BTreeSet};
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
    expected: usize,
    /// The publication's time, when markers must answer that publication and not an earlier one of the version.
    published_unix_ms: Option<u64>,
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
            expected: 0,
            published_unix_ms: None,
        }
    }

    /// Counts only markers that answer the publication of `published_unix_ms` (a resumed learner publishes a version
    /// again; actors interrupted in its first publication send a marker for that one).
    pub fn answering(mut self, published_unix_ms: u64) -> Self {
        self.published_unix_ms = Some(published_unix_ms);
        self
    }

    /// Waits (until the timeout) for at least `n` actors' markers even when fewer are known to be alive: at the start
    /// of a run, an actor may be done before another one's liveliness has reached the learner.
    pub fn expecting(mut self, n: usize) -> Self {
        self.expected = n;
        self
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
        if marker.version != self.version
            || self
                .published_unix_ms
                .is_some_and(|p| p != marker.published_unix_ms)
        {
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
        if missing.is_empty() && self.done.len() >= self.expected {
            Some(Closed::AllDone)
        } else if now.duration_since(self.opened) >= self.timeout {
            Some(Closed::Timeout { missing })
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn marker(actor: &str, version: u64) -> EpochDone {
        EpochDone {
            actor: actor.into(),
            version,
            published_unix_ms: 0,
            segments: 1,
            steps: 10,
            taken: 10,
            staged: 0,
            shielded: 0,
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
    fn the_expected_actors_are_waited_for_before_their_liveliness_arrives() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(5), ["a".into()], t0).expecting(2);
        g.done(marker("a", 0));
        assert_eq!(g.closed(t0), None, "b has not been seen yet");
        g.alive("b");
        g.done(marker("b", 0));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        let mut g = EpochGate::open(0, Duration::from_secs(5), ["a".into()], t0).expecting(2);
        g.done(marker("a", 0));
        assert_eq!(
            g.closed(t0 + Duration::from_secs(5)),
            Some(Closed::Timeout { missing: vec![] }),
            "b never came: the timeout closes the epoch"
        );
    }

    #[test]
    fn a_marker_of_an_earlier_publication_of_the_version_does_not_count() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(3, Duration::from_secs(5), ["a".into()], t0).answering(200);
        let mut early = marker("a", 3);
        early.published_unix_ms = 100;
        assert!(
            !g.done(early),
            "an interrupted collection of the first publication"
        );
        let mut answer = marker("a", 3);
        answer.published_unix_ms = 200;
        assert!(g.done(answer));
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
}
