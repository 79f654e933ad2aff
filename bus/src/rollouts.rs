//! The learner's port over zenoh: [`ZenohActors`] publishes each policy version on `policy` (and answers late
//! joiners from a queryable on the same key), takes segments from `traj/*` until the epoch's [`EpochGate`] closes,
//! follows the actors' liveliness, and keeps the evaluation reports of `eval/*` until the learner asks for them.
//! What arrives while the learner trains waits in the subscriptions' queues: nothing is dropped.
//!
//! Each message is held to the key it came on ([`check_traj`], [`check_eval`]): a segment or marker whose `actor`
//! is not the `<actor>` of its `traj/<actor>` key, or an evaluation report not from `eval/<id>` with `actor == id`,
//! is refused and counted with the codec's refusals ([`crate::Rejects`]).
//!
//! The queues are bounded in messages: [`TRAJ_QUEUE`] segments and markers (a full epoch of every actor waits there
//! while the learner trains; when full, zenoh's reliable delivery holds the publishers back rather than dropping),
//! [`EVAL_QUEUE`] reports. Each message is at most [`crate::MAX_MESSAGE`] bytes (zenoh reassembles nothing larger).

use crate::gate::{Closed, EpochGate};
use crate::interrupt::Interrupt;
use crate::{decode_sample, encoding_of, Bus};
use bytes::Bytes;
use cabc_proto::codec;
use cabc_proto::messages::{EvalReport, PolicyUpdate, Segment, TrajMessage};
use cabc_proto::ports::{Collected, PortError, Rollouts};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::handlers::{FifoChannel, FifoChannelHandler};
use zenoh::pubsub::Subscriber;
use zenoh::query::Queryable;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Wait;

/// Segments (and markers) that may wait while the learner trains.
pub const TRAJ_QUEUE: usize = 1 << 16;
/// Evaluation reports that may wait (one per version per evaluator; the learner takes them every epoch).
pub const EVAL_QUEUE: usize = 256;
/// How long one wait for a segment lasts before the gate and the interrupt are looked at again.
const POLL: Duration = Duration::from_millis(250);
/// While a live actor has sent nothing for the open epoch, the policy is published again, after this long and then
/// at doubling intervals: an actor that missed the first publication (it was reconnecting to a restarted learner)
/// still gets it, and actors ignore a publication they already have.
const REPUBLISH: Duration = Duration::from_secs(3);

/// The publications the policy queryable holds, at most this many bytes (always the latest).
const HELD_BYTES: usize = 256 << 20;

fn transport(e: impl std::fmt::Display) -> PortError {
    PortError::Transport(e.to_string())
}

/// The component name of an actor's liveliness token `.../alive/actor/<id>`.
pub fn actor_of_token(key: &str) -> Option<String> {
    let (_, rest) = key.split_once("/alive/actor/")?;
    Some(rest.to_string())
}

/// The `<actor>` of a key `.../traj/<actor>` (one chunk, nothing after it).
pub fn traj_sender(key: &str) -> Option<&str> {
    let (_, actor) = key.rsplit_once("/traj/")?;
    (!actor.is_empty() && !actor.contains('/')).then_some(actor)
}

/// The `<id>` of a key `.../eval/<id>` (one chunk, nothing after it).
pub fn eval_sender(key: &str) -> Option<&str> {
    let (_, id) = key.rsplit_once("/eval/")?;
    (!id.is_empty() && !id.contains('/')).then_some(id)
}

/// A segment's or a marker's `actor` must be the actor of the key it came on.
pub fn check_traj(key: &str, message: &TrajMessage) -> Result<(), String> {
    let named = match message {
        TrajMessage::Segment(s) => &s.actor,
        TrajMessage::EpochDone(d) => &d.actor,
    };
    match traj_sender(key) {
        Some(sender) if sender == named => Ok(()),
        Some(sender) => Err(format!("names actor `{named}` but came from `{sender}`")),
        None => Err(format!("not an actor's key (names actor `{named}`)")),
    }
}

/// An evaluation report counts only from an evaluator's key `eval/<id>` with `report.actor == id`.
pub fn check_eval(key: &str, report: &EvalReport) -> Result<(), String> {
    match eval_sender(key) {
        Some(id) if id == report.actor => Ok(()),
        Some(id) => Err(format!(
            "an evaluation report of `{}` from `{id}`",
            report.actor
        )),
        None => Err(format!(
            "not an evaluator's key (report of `{}`)",
            report.actor
        )),
    }
}

/// The actors of a run, as the learner sees them over zenoh.
pub struct ZenohActors {
    bus: Bus,
    traj: Subscriber<FifoChannelHandler<Sample>>,
    eval: Subscriber<FifoChannelHandler<Sample>>,
    alive: Subscriber<FifoChannelHandler<Sample>>,
    _policy: Queryable<()>,
    /// The encoded publications of the last versions (the queryable's answers): the latest for late joiners, any
    /// held version for an evaluator that missed it (`policy?version=<v>`).
    published: Arc<Mutex<BTreeMap<u64, Bytes>>>,
    live: BTreeSet<String>,
    /// Actors that left and did not come back.
    left: BTreeSet<String>,
    /// The run's actors (`actors.count`): an epoch waits for this many markers, less those that left.
    expected: usize,
    epoch_timeout: Duration,
    interrupt: Interrupt,
    /// The version published and not gathered yet.
    published_last: Option<Publication>,
}

/// A publication of the policy, until its epoch is gathered: published again from the same bytes for an actor not
/// heard from, and the epoch's timeout counts from it.
struct Publication {
    version: u64,
    encoded: Bytes,
    at: Instant,
}

impl ZenohActors {
    /// Subscribes to the actors' keys of `bus`'s run. An epoch closes when every live actor, and at least `expected`
    /// actors (less those that left), said they are done; or after `epoch_timeout` with at least one marker.
    pub fn new(
        bus: Bus,
        expected: usize,
        epoch_timeout: Duration,
        interrupt: Interrupt,
    ) -> Result<Self, PortError> {
        let keys = bus.keys.clone();
        let traj = bus
            .session
            .declare_subscriber(keys.traj_all())
            .with(FifoChannel::new(TRAJ_QUEUE))
            .wait()
            .map_err(transport)?;
        let eval = bus
            .session
            .declare_subscriber(keys.eval_all())
            .with(FifoChannel::new(EVAL_QUEUE))
            .wait()
            .map_err(transport)?;
        let alive = bus
            .session
            .liveliness()
            .declare_subscriber(keys.alive("actor/*"))
            .history(true)
            .wait()
            .map_err(transport)?;
        let published: Arc<Mutex<BTreeMap<u64, Bytes>>> = Arc::default();
        let answer = published.clone();
        let policy = bus
            .session
            .declare_queryable(keys.policy())
            .callback(move |query| {
                let held = answer.lock().unwrap_or_else(|e| e.into_inner());
                let wanted = query.parameters().get("version");
                let bytes = match wanted.map(str::parse::<u64>) {
                    None => held.last_key_value().map(|(_, b)| b.clone()),
                    Some(Ok(version)) => held.get(&version).cloned(),
                    Some(Err(_)) => None,
                };
                drop(held);
                // No reply: nothing published yet, or a version no longer held (the asker logs it).
                let Some(latest) = bytes else {
                    return;
                };
                let key = query.key_expr().clone();
                if let Err(e) = query
                    .reply(key, latest)
                    .encoding(encoding_of::<PolicyUpdate>())
                    .wait()
                {
                    tracing::warn!("answering a policy query: {e}");
                }
            })
            .wait()
            .map_err(transport)?;
        Ok(ZenohActors {
            bus,
            traj,
            eval,
            alive,
            _policy: policy,
            published,
            live: BTreeSet::new(),
            left: BTreeSet::new(),
            expected,
            epoch_timeout,
            interrupt,
            published_last: None,
        })
    }

    /// The bus, to close it at the end.
    pub fn into_bus(self) -> Bus {
        self.bus
    }

    /// One message of `traj/*`: checked against its key, a segment to `store`, a marker to the gate.
    fn take_in(
        &self,
        sample: &Sample,
        version: u64,
        gate: &mut EpochGate,
        heard: &mut BTreeSet<String>,
        store: &mut dyn FnMut(Segment),
    ) {
        let bytes = sample.payload().to_bytes();
        let key = sample.key_expr().as_str();
        let message =
            decode_sample::<TrajMessage>(key, &bytes, &self.bus.rejects).filter(
                |m| match check_traj(key, m) {
                    Ok(()) => true,
                    Err(why) => {
                        self.bus.rejects.refuse(key, &why);
                        false
                    }
                },
            );
        match message {
            Some(TrajMessage::Segment(segment)) => {
                if segment.policy_version == version {
                    heard.insert(segment.actor.clone());
                }
                store(segment)
            }
            Some(TrajMessage::EpochDone(marker)) => {
                heard.insert(marker.actor.clone());
                gate.done(marker);
            }
            None => {}
        }
    }

    /// Applies the liveliness changes that arrived (to the gate too, when an epoch is open).
    fn follow_liveliness(&mut self, mut gate: Option<&mut EpochGate>) {
        while let Ok(Some(sample)) = self.alive.try_recv() {
            let Some(actor) = actor_of_token(sample.key_expr().as_str()) else {
                continue;
            };
            match sample.kind() {
                SampleKind::Put => {
                    tracing::info!(actor, "actor joined");
                    if let Some(g) = gate.as_deref_mut() {
                        g.alive(&actor);
                    }
                    self.left.remove(&actor);
                    self.live.insert(actor);
                }
                SampleKind::Delete => {
                    tracing::warn!(actor, "actor left");
                    if let Some(g) = gate.as_deref_mut() {
                        g.gone(&actor);
                    }
                    self.live.remove(&actor);
                    self.left.insert(actor);
                }
            }
        }
    }
}

impl Rollouts for ZenohActors {
    fn publish(&mut self, update: &PolicyUpdate) -> Result<(), PortError> {
        // Encoded once: held for the queryable, published, and published again, from the same buffer.
        let encoded = Bytes::from(codec::encode(update));
        {
            let mut held = self.published.lock().unwrap_or_else(|e| e.into_inner());
            held.insert(update.version, encoded.clone());
            let mut bytes: usize = held.values().map(Bytes::len).sum();
            while bytes > HELD_BYTES && held.len() > 1 {
                if let Some((_, dropped)) = held.pop_first() {
                    bytes -= dropped.len();
                }
            }
        }
        self.bus
            .put_encoded_blocking::<PolicyUpdate>(&self.bus.keys.policy(), encoded.clone())
            .map_err(transport)?;
        self.published_last = Some(Publication {
            version: update.version,
            encoded,
            at: Instant::now(),
        });
        Ok(())
    }

    fn gather(
        &mut self,
        update: &PolicyUpdate,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError> {
        let Publication {
            encoded,
            at: published_at,
            ..
        } = self
            .published_last
            .take()
            .filter(|p| p.version == update.version)
            .ok_or_else(|| {
                PortError::Transport(format!(
                    "gathering version {} before publishing it",
                    update.version
                ))
            })?;
        self.follow_liveliness(None);
        let mut gate = EpochGate::open(
            update.version,
            self.epoch_timeout,
            self.live.iter().cloned(),
            published_at,
        )
        .expecting(self.expected.saturating_sub(self.left.len()))
        .answering(update.published_unix_ms);
        let mut last_wait_log = Instant::now();
        let mut last_publish = published_at;
        let mut republish_after = REPUBLISH;
        let mut heard: BTreeSet<String> = BTreeSet::new();
        // What arrived while the learner trained (`collection.overlap`), before anything is published again.
        while let Ok(Some(sample)) = self.traj.try_recv() {
            self.take_in(&sample, update.version, &mut gate, &mut heard, store);
        }
        let closed = loop {
            if self.interrupt.is_set() {
                return Ok(None);
            }
            self.follow_liveliness(Some(&mut gate));
            if let Some(sample) = self.traj.recv_timeout(POLL).map_err(transport)? {
                self.take_in(&sample, update.version, &mut gate, &mut heard, store);
            }
            if last_publish.elapsed() >= republish_after
                && self.live.iter().any(|a| !heard.contains(a))
            {
                last_publish = Instant::now();
                republish_after *= 2;
                tracing::debug!(
                    epoch = update.version,
                    "publishing the policy again for actors not heard from"
                );
                self.bus
                    .put_encoded_blocking::<PolicyUpdate>(&self.bus.keys.policy(), encoded.clone())
                    .map_err(transport)?;
            }
            if let Some(closed) = gate.closed(Instant::now()) {
                break closed;
            }
            if last_wait_log.elapsed() > Duration::from_secs(30) {
                last_wait_log = Instant::now();
                tracing::info!(epoch = update.version, live = ?self.live, missing = ?gate.missing(), "waiting for actors");
            }
        };
        // What already arrived goes with this epoch: an actor that left may have sent its last segments just before
        // its liveliness went.
        while let Ok(Some(sample)) = self.traj.try_recv() {
            self.take_in(&sample, update.version, &mut gate, &mut heard, store);
        }
        let (missing, timed_out) = match closed {
            Closed::AllDone => (Vec::new(), false),
            Closed::Timeout { missing } => {
                tracing::warn!(
                    epoch = update.version,
                    ?missing,
                    done = gate.markers().count(),
                    "epoch closed by the timeout"
                );
                (missing, true)
            }
        };
        Ok(Some(Collected {
            steps_published: gate.markers().map(|m| m.steps).sum(),
            steps_taken: gate.markers().map(|m| m.taken).sum(),
            steps_staged: gate.markers().map(|m| m.staged).sum(),
            steps_shielded: gate.markers().map(|m| m.shielded).sum(),
            missing,
            timed_out,
            live: self.live.iter().cloned().collect(),
            times: None,
        }))
    }

    fn evaluations(&mut self) -> Vec<EvalReport> {
        let mut reports = Vec::new();
        while let Ok(Some(sample)) = self.eval.try_recv() {
            let bytes = sample.payload().to_bytes();
            let key = sample.key_expr().as_str();
            if let Some(report) = decode_sample::<EvalReport>(key, &bytes, &self.bus.rejects) {
                match check_eval(key, &report) {
                    Ok(()) => reports.push(report),
                    Err(why) => self.bus.rejects.refuse(key, &why),
                }
            }
        }
        reports
    }

    fn interrupted(&self) -> bool {
        self.interrupt.is_set()
    }

    fn stop(&mut self, reason: &str) -> Result<(), PortError> {
        let stop = cabc_proto::messages::Stop {
            reason: reason.to_string(),
        };
        self.bus
            .put_blocking(&self.bus.keys.control(), &stop)
            .map_err(transport)
    }

    fn rejected(&self) -> u64 {
        self.bus.rejects.count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actor_tokens_are_recognised() {
        assert_eq!(
            actor_of_token("cabc/r/alive/actor/actor-1").as_deref(),
            Some("actor-1")
        );
        assert_eq!(actor_of_token("cabc/r/alive/eval/e"), None);
        assert_eq!(actor_of_token("cabc/r/alive/learner"), None);
    }

    fn marker(actor: &str) -> TrajMessage {
        TrajMessage::EpochDone(cabc_proto::messages::EpochDone {
            actor: actor.into(),
            version: 1,
            published_unix_ms: 0,
            segments: 0,
            steps: 0,
            taken: 0,
            staged: 0,
            shielded: 0,
        })
    }

    fn segment(actor: &str) -> TrajMessage {
        TrajMessage::Segment(Segment {
            actor: actor.into(),
            incarnation: 0,
            env: 0,
            episode: 0,
            seq: 0,
            policy_version: 0,
            outcome: cabc_proto::messages::Outcome::Lap,
            steps: Vec::new(),
        })
    }

    fn report(actor: &str) -> EvalReport {
        EvalReport {
            actor: actor.into(),
            version: 0,
            laps: 0,
            lap_times: Vec::new(),
            end_reason: cabc_proto::messages::EndReason::Stall,
            steps: 0,
            line: Vec::new(),
            spawn_episodes: 0,
            spawn_crashes: 0,
        }
    }

    #[test]
    fn senders_are_read_from_their_keys() {
        assert_eq!(traj_sender("cabc/r/traj/actor-1"), Some("actor-1"));
        assert_eq!(traj_sender("cabc/r/traj/"), None);
        assert_eq!(traj_sender("cabc/r/traj/a/b"), None);
        assert_eq!(traj_sender("cabc/r/eval/a"), None);
        assert_eq!(eval_sender("cabc/r/eval/eval-0"), Some("eval-0"));
        assert_eq!(eval_sender("cabc/r/traj/eval-0"), None);
        assert_eq!(eval_sender("cabc/r/eval/x/y"), None);
    }

    #[test]
    fn segments_and_markers_must_come_on_their_actor_key() {
        let key = "cabc/r/traj/actor-1";
        assert!(check_traj(key, &segment("actor-1")).is_ok());
        assert!(check_traj(key, &marker("actor-1")).is_ok());
        assert!(check_traj(key, &segment("actor-2")).is_err());
        assert!(check_traj(key, &marker("actor-2")).is_err());
        assert!(check_traj("cabc/r/eval/actor-1", &segment("actor-1")).is_err());
    }

    #[test]
    fn evaluation_reports_count_only_from_their_evaluator() {
        assert!(check_eval("cabc/r/eval/eval-0", &report("eval-0")).is_ok());
        assert!(check_eval("cabc/r/eval/eval-0", &report("eval-1")).is_err());
        assert!(check_eval("cabc/r/traj/eval-0", &report("eval-0")).is_err());
    }
}
