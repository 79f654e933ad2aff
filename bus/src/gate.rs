//! The epoch protocol over the bus (architecture.md): when is an epoch's collection over?
//!
//! The learner publishes PolicyUpdate j; actors collect their share of the epoch's steps with it, publish their
//! segments and then an [`EpochDone`] marker. [`EpochGate`] closes epoch j once every live actor (liveliness) has
//! said it is done with j, or once `timeout` has passed since the epoch opened and at least one actor is done: a
//! dead or stuck actor never stalls the run. The gate follows the live set, not a count: an actor that leaves before
//! its marker is no longer waited for (it is [`EpochGate::lost`], and its undone share is the learner's to deal out
//! again), one that joins is. With no live actor and no marker the gate says so ([`EpochGate::abandoned`]) once
//! `no_actor_timeout` has passed without one. Pure logic, tested without zenoh.

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
    /// How long `expected` holds.
    grace: Duration,
    /// Actors that left during the epoch before their marker.
    lost: BTreeSet<String>,
    /// When each actor was last heard from in this epoch (a segment or a marker).
    heard: BTreeMap<String, Instant>,
    /// The actors this publication is waited for from, while they live: those alive when the epoch opened, and those
    /// that joined while it still expected actors it had not heard from (the run's start: each such joiner takes the
    /// publication at once and collects its share, so its segments and marker belong to this epoch).
    answering: BTreeSet<String>,
    /// Since when no actor has been live (None while one is).
    nobody_since: Option<Instant>,
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
        let live: BTreeSet<String> = live.into_iter().collect();
        EpochGate {
            version,
            opened: now,
            timeout,
            nobody_since: live.is_empty().then_some(now),
            answering: live.clone(),
            live,
            done: BTreeMap::new(),
            expected: 0,
            grace: Duration::ZERO,
            lost: BTreeSet::new(),
            heard: BTreeMap::new(),
            published_unix_ms: None,
        }
    }

    /// Counts only markers that answer the publication of `published_unix_ms` (a resumed learner publishes a version
    /// again; actors interrupted in its first publication send a marker for that one).
    pub fn answering(mut self, published_unix_ms: u64) -> Self {
        self.published_unix_ms = Some(published_unix_ms);
        self
    }

    /// Waits (for `grace` at most, and never past the timeout) for at least `n` actors' markers even when fewer are
    /// known to be alive: at the start of a run, an actor may be done before another one's liveliness has reached the
    /// learner. After `grace` the live set alone counts (an actor of `actors.count` that never came does not hold
    /// every epoch to its timeout).
    pub fn expecting(mut self, n: usize, grace: Duration) -> Self {
        self.expected = n;
        self.grace = grace;
        self
    }

    pub fn version(&self) -> u64 {
        self.version
    }

    pub fn alive(&mut self, actor: &str) {
        if self.done.len() < self.expected {
            self.answering.insert(actor.to_string());
        }
        self.live.insert(actor.to_string());
        self.nobody_since = None;
    }

    /// `actor` left. Before its marker, it is lost to this epoch: one fewer marker is expected (the gate no longer
    /// waits for it to come back) and [`EpochGate::lost`] names it.
    pub fn gone(&mut self, actor: &str, now: Instant) {
        self.live.remove(actor);
        if !self.done.contains_key(actor) && self.lost.insert(actor.to_string()) {
            self.expected = self.expected.saturating_sub(1);
        }
        if self.live.is_empty() && self.nobody_since.is_none() {
            self.nobody_since = Some(now);
        }
    }

    /// Notes a message from `actor` at `now`.
    pub fn heard_from(&mut self, actor: &str, now: Instant) {
        self.heard.insert(actor.to_string(), now);
    }

    /// Whether live `actor` was heard from in this epoch, has not sent its marker, and has been silent for `quiet`:
    /// its marker may have been lost.
    pub fn quiet_without_marker(&self, actor: &str, now: Instant, quiet: Duration) -> bool {
        self.live.contains(actor)
            && !self.done.contains_key(actor)
            && self
                .heard
                .get(actor)
                .is_some_and(|&t| now.duration_since(t) >= quiet)
    }

    /// Actors that left during the epoch without their marker (an actor that came back and sent it is not lost).
    pub fn lost(&self) -> impl Iterator<Item = &str> {
        self.lost
            .iter()
            .filter(|a| !self.done.contains_key(*a))
            .map(String::as_str)
    }

    /// Whether no actor has been live, and none has sent a marker, for `wait` or longer: the epoch cannot close.
    pub fn abandoned(&self, now: Instant, wait: Duration) -> bool {
        self.done.is_empty()
            && self
                .nobody_since
                .is_some_and(|since| now.duration_since(since) >= wait)
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

    /// Live actors not yet done that the epoch waits for: those alive when it opened (also when they left and came
    /// back: a link cut, a router restart, a restart under the same id, each still answers this publication), and
    /// those that joined while the epoch still expected actors it had not seen (the run's start; one such joiner
    /// stays waited for once the count is reached: it collects this publication too). An actor that joins under a
    /// new id later is not waited for: its share is the next publication's.
    pub fn missing(&self) -> Vec<String> {
        self.live
            .iter()
            .filter(|a| !self.done.contains_key(*a) && self.answering.contains(*a))
            .cloned()
            .collect()
    }

    /// Whether the epoch can close now.
    pub fn closed(&self, now: Instant) -> Option<Closed> {
        if self.done.is_empty() {
            return None;
        }
        let missing = self.missing();
        let waited = now.duration_since(self.opened);
        if missing.is_empty() && (self.done.len() >= self.expected || waited >= self.grace) {
            Some(Closed::AllDone)
        } else if now.duration_since(self.opened) >= self.timeout {
            Some(Closed::Timeout { missing })
        } else {
            None
        }
    }
}

/// How an epoch's steps are dealt: `budget` steps over `members` actors, each collecting its share rounded up (the
/// epoch collects at least its budget). `members` is the live actors, or more while actors of `actors.count` have
/// not been seen yet (the run's start); at least one.
pub fn share(budget: u64, members: usize) -> u64 {
    budget.div_ceil(members.max(1) as u64)
}

/// The steps of their shares that the actors which left an epoch before their marker did not deliver: `share` each,
/// less the steps of that version heard from it.
pub fn undone<'a>(
    lost: impl IntoIterator<Item = &'a str>,
    share: u64,
    heard: &BTreeMap<String, u64>,
) -> u64 {
    lost.into_iter()
        .map(|actor| share.saturating_sub(heard.get(actor).copied().unwrap_or(0)))
        .sum()
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
        let mut g = EpochGate::open(0, Duration::from_secs(5), ["a".into()], t0)
            .expecting(2, Duration::from_secs(5));
        g.done(marker("a", 0));
        assert_eq!(g.closed(t0), None, "b has not been seen yet");
        g.alive("b");
        g.done(marker("b", 0));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        let mut g = EpochGate::open(0, Duration::from_secs(60), ["a".into()], t0)
            .expecting(2, Duration::from_secs(5));
        g.done(marker("a", 0));
        assert_eq!(g.closed(t0 + Duration::from_secs(4)), None);
        assert_eq!(
            g.closed(t0 + Duration::from_secs(5)),
            Some(Closed::AllDone),
            "b never came: after the grace the live set alone counts, long before the timeout"
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
        g.gone("b", t0);
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        assert_eq!(g.lost().collect::<Vec<_>>(), vec!["b"]);
    }

    #[test]
    fn an_actor_that_dies_mid_epoch_is_not_waited_for_even_when_expected() {
        // Two actors expected (actors.count = 2): one dies before its marker. The epoch closes on the other's marker,
        // not at the timeout (issue 64: it cost `epoch_timeout_s`).
        let t0 = Instant::now();
        let mut g = EpochGate::open(4, Duration::from_secs(120), ["a".into(), "b".into()], t0)
            .expecting(2, Duration::from_secs(60));
        g.gone("b", t0);
        assert_eq!(g.closed(t0), None, "a is still collecting");
        g.done(marker("a", 4));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        assert_eq!(g.lost().collect::<Vec<_>>(), vec!["b"]);
        // A second departure of the same actor (a restart that died again) is not a second loss.
        g.alive("b");
        g.gone("b", t0);
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
    }

    #[test]
    fn an_actor_restarted_mid_epoch_is_waited_for_and_not_lost_once_done() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(4, Duration::from_secs(120), ["a".into()], t0)
            .expecting(1, Duration::from_secs(60));
        g.gone("a", t0);
        g.alive("a");
        assert_eq!(g.closed(t0), None);
        g.done(marker("a", 4));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        assert_eq!(g.lost().count(), 0, "it came back and answered");
    }

    /// A router restarted right after a publication: both actors it was dealt to left (the learner learns it when
    /// it opens the gate) and came back; the first one's marker does not close the epoch without the other's.
    #[test]
    fn the_actors_a_publication_was_dealt_to_are_waited_for_when_they_all_left_and_came_back() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(3, Duration::from_secs(120), ["a".into(), "b".into()], t0);
        g.gone("a", t0);
        g.gone("b", t0);
        g.alive("b");
        g.alive("a");
        g.done(marker("b", 3));
        assert_eq!(g.closed(t0), None, "a was dealt its share and is back");
        g.done(marker("a", 3));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        assert_eq!(g.lost().count(), 0);
    }

    #[test]
    fn an_actor_silent_without_its_marker_is_noticed() {
        let t0 = Instant::now();
        let quiet = Duration::from_secs(10);
        let mut g = EpochGate::open(2, Duration::from_secs(120), ["a".into(), "b".into()], t0);
        assert!(
            !g.quiet_without_marker("a", t0 + quiet * 5, quiet),
            "never heard: not this case"
        );
        g.heard_from("a", t0);
        assert!(!g.quiet_without_marker("a", t0 + Duration::from_secs(9), quiet));
        assert!(g.quiet_without_marker("a", t0 + quiet, quiet));
        g.heard_from("b", t0);
        g.done(marker("b", 2));
        assert!(
            !g.quiet_without_marker("b", t0 + quiet * 5, quiet),
            "its marker came"
        );
    }

    #[test]
    fn an_actor_joining_mid_epoch_is_not_waited_for_one_coming_back_is() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(4, Duration::from_secs(120), ["a".into(), "b".into()], t0);
        // b loses its link and comes back; c joins.
        g.gone("b", t0);
        g.alive("b");
        g.alive("c");
        g.done(marker("a", 4));
        assert_eq!(
            g.missing(),
            vec!["b".to_string()],
            "b still answers this publication"
        );
        g.done(marker("b", 4));
        assert_eq!(g.closed(t0), Some(Closed::AllDone), "c is not waited for");
        assert_eq!(g.lost().count(), 0);
    }

    #[test]
    fn at_the_start_the_actors_that_join_are_waited_for() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(120), Vec::<String>::new(), t0)
            .expecting(2, Duration::from_secs(60));
        g.alive("a");
        g.alive("b");
        g.done(marker("a", 0));
        assert_eq!(g.missing(), vec!["b".to_string()]);
        assert_eq!(g.closed(t0), None);
        g.done(marker("b", 0));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
    }

    /// More actors than `actors.count` at the start (seen in CI: `a_smoke_run_completes_survives_faults_and_resumes`,
    /// three actors for a count of two): both joiners took the first publication, so the epoch waits for both, not
    /// for whichever is done first (the other's segments would go to the next epoch without its marker).
    #[test]
    fn at_the_start_every_actor_that_joins_before_the_count_is_done_is_waited_for() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(120), ["a".into()], t0)
            .expecting(2, Duration::from_secs(60));
        g.alive("b");
        g.alive("c");
        g.done(marker("a", 0));
        g.done(marker("b", 0));
        assert_eq!(g.missing(), vec!["c".to_string()]);
        assert_eq!(g.closed(t0), None, "c collects this publication too");
        g.done(marker("c", 0));
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
        // One joining once the count is done takes its share from the next publication.
        g.alive("d");
        assert!(g.missing().is_empty());
        assert_eq!(g.closed(t0), Some(Closed::AllDone));
    }

    #[test]
    fn an_epoch_with_no_live_actor_is_abandoned_after_the_wait() {
        let t0 = Instant::now();
        let wait = Duration::from_secs(30);
        let mut g = EpochGate::open(6, Duration::from_secs(120), ["a".into()], t0)
            .expecting(1, Duration::from_secs(60));
        assert!(!g.abandoned(t0 + wait * 2, wait), "a is alive");
        g.gone("a", t0 + Duration::from_secs(10));
        assert!(!g.abandoned(t0 + Duration::from_secs(39), wait));
        assert!(g.abandoned(t0 + Duration::from_secs(40), wait));
        assert_eq!(g.closed(t0 + Duration::from_secs(1000)), None, "no marker");
        // One that comes back ends the wait; leaving again starts it anew.
        g.alive("b");
        assert!(!g.abandoned(t0 + Duration::from_secs(100), wait));
        g.gone("b", t0 + Duration::from_secs(100));
        assert!(!g.abandoned(t0 + Duration::from_secs(129), wait));
        assert!(g.abandoned(t0 + Duration::from_secs(130), wait));
        // A gate opened with nobody live waits from its opening (the run's start: actors not up yet).
        let g = EpochGate::open(0, Duration::from_secs(120), Vec::<String>::new(), t0);
        assert!(!g.abandoned(t0 + Duration::from_secs(29), wait));
        assert!(g.abandoned(t0 + wait, wait));
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
    fn an_actor_joining_late_is_waited_for_only_while_actors_are_expected() {
        let t0 = Instant::now();
        let mut g = EpochGate::open(0, Duration::from_secs(60), ["a".into()], t0);
        g.alive("c");
        g.done(marker("a", 0));
        assert_eq!(
            g.closed(t0),
            Some(Closed::AllDone),
            "c takes its share from the next publication"
        );
        let mut g = EpochGate::open(0, Duration::from_secs(60), ["a".into()], t0)
            .expecting(2, Duration::from_secs(30));
        g.alive("c");
        g.done(marker("a", 0));
        assert_eq!(
            g.missing(),
            vec!["c".to_string()],
            "the run's start: c is one of the two"
        );
        assert_eq!(g.closed(t0), None);
    }

    #[test]
    fn an_epochs_steps_are_dealt_over_its_members() {
        assert_eq!(share(1024, 2), 512);
        assert_eq!(
            share(1024, 1),
            1024,
            "the one actor left collects the whole epoch"
        );
        assert_eq!(share(1024, 3), 342, "rounded up: at least the budget");
        assert_eq!(share(1024, 0), 1024);
    }

    #[test]
    fn what_a_lost_actor_did_not_deliver_is_undone() {
        let heard: BTreeMap<String, u64> = [("a".to_string(), 300), ("b".to_string(), 600)].into();
        assert_eq!(undone(["a"], 512, &heard), 212);
        assert_eq!(undone(["b"], 512, &heard), 0, "it delivered its share");
        assert_eq!(undone(["a", "c"], 512, &heard), 212 + 512, "c sent nothing");
        assert_eq!(undone([], 512, &heard), 0);
    }
}
