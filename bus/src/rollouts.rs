//! The learner's port over zenoh: [`ZenohActors`] publishes each policy version on `policy` (and answers late
//! joiners from a queryable on the same key), takes segments from `traj/*` until the epoch's [`EpochGate`] closes,
//! follows the actors' liveliness, and keeps the evaluation reports of `eval/*` until the learner asks for them.
//! What arrives while the learner trains waits in the subscriptions' queues: nothing is dropped.
//!
//! The epoch follows the live set (issue 64): each publication deals the epoch's steps (`collection.steps_per_epoch`)
//! over the actors alive or still expected, so that one actor collects the whole epoch when it is the only one left
//! and a joiner takes its share from the next publication; an actor that leaves before its marker is not waited for,
//! and the part of its share it had not delivered is published again, to the live actors, as a further round of the
//! same version ([`Round`]), until the epoch holds its budget or no actor is left. With no live actor the learner
//! warns and, after `bus.no_actor_timeout_s`, ends with [`PortError::NoActors`] (its checkpoint stays). It also warns
//! while no evaluator is alive: no evaluation, no early stop.
//!
//! Each message is held to the key it came on ([`check_traj`], [`check_eval`]): a segment or marker whose `actor`
//! is not the `<actor>` of its `traj/<actor>` key, or an evaluation report not from `eval/<id>` with `actor == id`,
//! is refused and counted with the codec's refusals ([`crate::Rejects`]).
//!
//! Each segment is acknowledged to its actor as it arrives ([`crate::receipts`]), so that the actor's outbox forgets
//! it; what is not acknowledged the actor publishes again, and the learner's ledger drops the copies.
//!
//! The queues are bounded in messages: [`TRAJ_QUEUE`] segments and markers (a full epoch of every actor waits there
//! while the learner trains; when full, zenoh's reliable delivery holds the publishers back rather than dropping),
//! [`EVAL_QUEUE`] reports. Each message is at most [`crate::MAX_MESSAGE`] bytes (zenoh reassembles nothing larger).

use crate::gate::{share, undone, Closed, EpochGate};
use crate::interrupt::Interrupt;
use crate::membership::Membership;
use crate::publications::Publications;
use crate::receipts::Receipts;
pub use crate::receipts::TRAJ_QUEUE;
pub use crate::senders::{
    actor_of_token, check_eval, check_traj, eval_sender, evaluator_of_token, traj_sender,
};
use crate::{decode_sample, Bus};
use bytes::Bytes;
use cabc_proto::codec;
use cabc_proto::messages::{EpochDone, EvalReport, PolicyUpdate, Segment, SegmentId};
use cabc_proto::ports::{Collected, PortError, Rollouts};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};
use zenoh::handlers::{FifoChannel, FifoChannelHandler};
use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Wait;

/// Evaluation reports that may wait (one per version per evaluator; the learner takes them every epoch).
pub const EVAL_QUEUE: usize = 256;
/// How long one wait for a segment lasts before the gate and the interrupt are looked at again.
const POLL: Duration = Duration::from_millis(250);
/// While a live actor has sent nothing for the open epoch, the policy is published again, after this long and then
/// at doubling intervals: an actor that missed the first publication (it was reconnecting to a restarted learner)
/// still gets it, and actors ignore a publication they already have.
const REPUBLISH: Duration = Duration::from_secs(3);
/// A live actor that has sent nothing for this long without its marker may have had its marker lost (a link cut
/// longer than zenoh's lease): the policy is published again as for an actor not heard from, and an actor that
/// already answered the publication sends its marker again (`cabc_bus::ports::MarkerEcho`).
const QUIET: Duration = Duration::from_secs(10);
/// How long the first epoch a learner gathers waits for the actors of `actors.count` it has not seen alive yet (they
/// are starting) before the live set alone counts; at most the epoch's timeout.
const JOIN_GRACE: Duration = Duration::from_secs(60);

/// How long a learner that stops the run says so again while actors or evaluators are still alive: one that joined
/// late may have declared its `control` subscription after the first Stop went out, and would wait for a learner that
/// is gone (seen: an evaluator over TLS from another network namespace, issue 64).
const STOP_LINGER: Duration = Duration::from_secs(10);

/// How long an actor or evaluator's own stopping may take before the learner says Stop again.
const STOP_AGAIN: Duration = Duration::from_millis(500);

fn transport(e: impl std::fmt::Display) -> PortError {
    PortError::Transport(e.to_string())
}

/// The actors of a run, as the learner sees them over zenoh.
pub struct ZenohActors {
    bus: Bus,
    /// Every actor's segments and markers, decoded and acknowledged as they arrived.
    traj: Receipts,
    eval: Subscriber<FifoChannelHandler<Sample>>,
    alive: Subscriber<FifoChannelHandler<Sample>>,
    evaluators_alive: Subscriber<FifoChannelHandler<Sample>>,
    /// The encoded publications of the last versions (the queryable's answers): the latest for late joiners, any
    /// held version for an evaluator that missed it (`policy?version=<v>`).
    published: Publications,
    /// Who the epochs are dealt to (the first epoch this learner gathers waits for `actors.count` markers, less
    /// those that left, for [`JOIN_GRACE`] at most; later epochs follow the live set).
    membership: Membership,
    /// The evaluators alive.
    evaluators: BTreeSet<String>,
    /// The run's evaluators (`actors.evaluators`): none alive is warned about once they could have joined.
    evaluators_expected: usize,
    /// The share of the last publication (a change is logged).
    last_share: Option<u64>,
    /// Whether the learner has said that no evaluator is alive (said once until one is back).
    warned_no_evaluator: bool,
    /// The steps of epoch j, all actors together (`RunConfig::epoch_steps`).
    budget: Box<dyn Fn(u64) -> u64 + Send>,
    epoch_timeout: Duration,
    no_actor_timeout: Duration,
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
    /// Its time, which markers answer.
    published_unix_ms: u64,
    /// Each actor's steps (`steps_per_actor`).
    share: u64,
    /// The actors alive when it was published (with none alive, those alive last), whom it was dealt to: the round
    /// waits for each of them, also when it left before the round's gathering began and came back (a router
    /// restarting right before or after the publication).
    members: BTreeSet<String>,
}

/// The timing of the learner's waits, from the run configuration's `bus` section.
#[derive(Clone, Copy, Debug)]
pub struct Waits {
    /// `bus.epoch_timeout_s`: how long an epoch waits for a live actor's marker once another one's came.
    pub epoch_timeout: Duration,
    /// `bus.no_actor_timeout_s`: how long an epoch waits with no live actor before the run ends.
    pub no_actor_timeout: Duration,
}

/// One round of an epoch's collection, as it closed.
struct RoundClosed {
    markers: Vec<EpochDone>,
    missing: Vec<String>,
    timed_out: bool,
    /// The steps the actors that left before their marker did not deliver.
    undone: u64,
    /// The steps of this version the actors that left before their marker did deliver (stored; no marker counts
    /// them).
    delivered_by_lost: u64,
    lost: Vec<String>,
}

impl RoundClosed {
    /// What `gate` holds as it closed (`closed`), the round's `share` and the steps `heard` from each actor.
    fn of(gate: &EpochGate, closed: Closed, share: u64, heard: &BTreeMap<String, u64>) -> Self {
        let (missing, timed_out) = match closed {
            Closed::AllDone => (Vec::new(), false),
            Closed::Timeout { missing } => {
                tracing::warn!(
                    epoch = gate.version(),
                    ?missing,
                    done = gate.markers().count(),
                    "epoch closed by the timeout"
                );
                (missing, true)
            }
        };
        let lost: Vec<String> = gate.lost().map(str::to_string).collect();
        RoundClosed {
            markers: gate.markers().cloned().collect(),
            missing,
            timed_out,
            undone: undone(lost.iter().map(String::as_str), share, heard),
            delivered_by_lost: lost.iter().filter_map(|a| heard.get(a)).sum(),
            lost,
        }
    }
}

impl ZenohActors {
    /// Subscribes to the actors' keys of `bus`'s run. An epoch closes when every live actor, and at least `expected`
    /// actors (less those that left), said they are done; or after `epoch_timeout` with at least one marker.
    pub fn new(
        bus: Bus,
        config: &cabc_proto::config::RunConfig,
        waits: Waits,
        interrupt: Interrupt,
    ) -> Result<Self, PortError> {
        let expected = config.actors.count as usize;
        let budget_of = config.clone();
        let budget = Box::new(move |epoch| budget_of.epoch_steps(epoch));
        let keys = bus.keys.clone();
        let traj = Receipts::subscribe(&bus)?;
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
        let evaluators_alive = bus
            .session
            .liveliness()
            .declare_subscriber(keys.alive("eval/*"))
            .history(true)
            .wait()
            .map_err(transport)?;
        let published = Publications::declare(&bus)?;
        Ok(ZenohActors {
            bus,
            traj,
            eval,
            alive,
            evaluators_alive,
            published,
            membership: Membership::new(expected),
            evaluators: BTreeSet::new(),
            evaluators_expected: config.actors.evaluators as usize,
            warned_no_evaluator: false,
            last_share: None,
            budget,
            epoch_timeout: waits.epoch_timeout,
            no_actor_timeout: waits.no_actor_timeout,
            interrupt,
            published_last: None,
        })
    }

    /// Where the subscription to `traj/*` spent its time so far ([`crate::receipts::ReceiptClock`]).
    pub fn receipt_times(&self) -> crate::receipts::ReceiptTimes {
        self.traj.clock.read()
    }

    /// The bus, to close it at the end.
    /// This learner process's incarnation, which its receipts carry.
    pub fn incarnation(&self) -> u64 {
        self.traj.learner
    }

    /// The segments that arrived after the last epoch closed (the run is over): received, never stored.
    pub fn unstored(&mut self) -> Vec<SegmentId> {
        let mut unstored = Vec::new();
        while let Ok(arrival) = self.traj.arrivals.try_recv() {
            if let Some(message) = arrival.message {
                unstored.extend(message.segments().iter().map(SegmentId::of));
            }
        }
        unstored
    }

    pub fn into_bus(self) -> Bus {
        self.bus
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
                    self.membership.joined(&actor);
                }
                SampleKind::Delete => {
                    tracing::warn!(actor, "actor left");
                    if let Some(g) = gate.as_deref_mut() {
                        g.gone(&actor, Instant::now());
                    }
                    self.membership.left(&actor);
                }
            }
        }
        self.membership.settled();
    }

    /// Applies the evaluators' liveliness changes; warns (once, until one is back) while none of the run's evaluators
    /// is alive after `epoch` 0: no version is evaluated then, so the run cannot reach its early stop.
    fn follow_evaluators(&mut self, epoch: u64) {
        while let Ok(Some(sample)) = self.evaluators_alive.try_recv() {
            let Some(id) = evaluator_of_token(sample.key_expr().as_str()) else {
                continue;
            };
            match sample.kind() {
                SampleKind::Put => {
                    tracing::info!(evaluator = id, "evaluator joined");
                    self.evaluators.insert(id);
                    self.warned_no_evaluator = false;
                }
                SampleKind::Delete => {
                    tracing::warn!(evaluator = id, "evaluator left");
                    self.evaluators.remove(&id);
                }
            }
        }
        if self.evaluators_expected > 0
            && epoch > 0
            && self.evaluators.is_empty()
            && !self.warned_no_evaluator
        {
            self.warned_no_evaluator = true;
            tracing::warn!(
                epoch,
                "no evaluator is alive: no version is evaluated, so the run cannot reach its early stop until one \
                 is back (start one: actor --eval)"
            );
        }
    }

    /// Publishes `encoded` (version `version`), holds it for the queryable, and remembers it as the round to gather.
    fn put_publication(
        &mut self,
        version: u64,
        encoded: Bytes,
        published_unix_ms: u64,
        share: u64,
    ) -> Result<(), PortError> {
        self.published.hold(version, encoded.clone());
        self.bus
            .put_encoded_blocking::<PolicyUpdate>(&self.bus.keys.policy(), encoded.clone())
            .map_err(transport)?;
        self.published_last = Some(Publication {
            version,
            encoded,
            at: Instant::now(),
            published_unix_ms,
            share,
            members: self.membership.dealt_to(),
        });
        Ok(())
    }

    /// The gate of `round`: its members, those of them not alive now lost until they come back (they left before
    /// the publication, or since it), and who left or joined since the publication (the learner trained meanwhile
    /// under `collection.overlap`).
    fn open_gate(&mut self, round: &Publication, expecting: usize) -> EpochGate {
        let mut gate = EpochGate::open(
            round.version,
            self.epoch_timeout,
            round.members.iter().cloned(),
            round.at,
        )
        .expecting(expecting, JOIN_GRACE.min(self.epoch_timeout))
        .answering(round.published_unix_ms);
        let live = self.membership.live();
        for member in round.members.iter().filter(|m| !live.contains(*m)) {
            gate.gone(member, Instant::now());
        }
        self.follow_liveliness(Some(&mut gate));
        gate
    }

    /// One round of epoch `version`'s collection: from `round`'s publication until every live actor answered it (or
    /// the timeout), storing what arrives. None on an interrupt.
    fn gather_round(
        &mut self,
        round: &Publication,
        expecting: usize,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<RoundClosed>, PortError> {
        let version = round.version;
        let mut gate = self.open_gate(round, expecting);
        let mut last_wait_log = Instant::now();
        let mut last_publish = round.at;
        let mut republish_after = REPUBLISH;
        let mut warned_nobody = false;
        let mut heard: BTreeMap<String, u64> = BTreeMap::new();
        // What arrived while the learner trained (`collection.overlap`), before anything is published again.
        while let Ok(arrival) = self.traj.arrivals.try_recv() {
            arrival.take_in(version, &mut gate, &mut heard, store);
        }
        let closed = loop {
            if self.interrupt.is_set() {
                return Ok(None);
            }
            self.follow_liveliness(Some(&mut gate));
            match self.traj.arrivals.recv_timeout(POLL) {
                Ok(arrival) => arrival.take_in(version, &mut gate, &mut heard, store),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(transport("the subscription to traj/* closed"))
                }
            }
            if last_publish.elapsed() >= republish_after
                && self.membership.live().iter().any(|a| {
                    !heard.contains_key(a) || gate.quiet_without_marker(a, Instant::now(), QUIET)
                })
            {
                last_publish = Instant::now();
                republish_after *= 2;
                tracing::debug!(
                    epoch = version,
                    "publishing the policy again for actors not heard from"
                );
                self.bus
                    .put_encoded_blocking::<PolicyUpdate>(
                        &self.bus.keys.policy(),
                        round.encoded.clone(),
                    )
                    .map_err(transport)?;
            }
            let now = Instant::now();
            if let Some(closed) = gate.closed(now) {
                break closed;
            }
            if self.membership.live().is_empty() && gate.markers().next().is_none() {
                if !warned_nobody {
                    warned_nobody = true;
                    tracing::warn!(
                        epoch = version,
                        wait_s = self.no_actor_timeout.as_secs_f64(),
                        "no live actor: waiting for one (the run ends if none comes; its checkpoint stays)"
                    );
                }
                if gate.abandoned(now, self.no_actor_timeout) {
                    return Err(PortError::NoActors {
                        epoch: version,
                        waited_s: self.no_actor_timeout.as_secs_f64(),
                    });
                }
            } else if warned_nobody && !self.membership.live().is_empty() {
                warned_nobody = false;
                tracing::warn!(epoch = version, live = ?self.membership.live(), "an actor is back");
            }
            if last_wait_log.elapsed() > Duration::from_secs(30) {
                last_wait_log = Instant::now();
                tracing::info!(epoch = version, live = ?self.membership.live(), missing = ?gate.missing(), "waiting for actors");
            }
        };
        // What already arrived goes with this epoch: an actor that left may have sent its last segments just before
        // its liveliness went.
        while let Ok(arrival) = self.traj.arrivals.try_recv() {
            arrival.take_in(version, &mut gate, &mut heard, store);
        }
        Ok(Some(RoundClosed::of(&gate, closed, round.share, &heard)))
    }
}

impl Rollouts for ZenohActors {
    fn publish(&mut self, update: &PolicyUpdate) -> Result<(), PortError> {
        self.follow_liveliness(None);
        self.follow_evaluators(update.version);
        // The epoch's steps dealt over the actors there are now (the learner's update assumes `actors.count`).
        let share = share((self.budget)(update.version), self.membership.members());
        if self.last_share != Some(share) {
            self.last_share = Some(share);
            tracing::info!(
                epoch = update.version,
                live = ?self.membership.live(),
                share,
                "the epoch's steps dealt over the live actors"
            );
        }
        // Encoded once: held for the queryable, published, and published again, from the same buffer.
        let encoded = if share == update.steps_per_actor {
            Bytes::from(codec::encode(update))
        } else {
            Bytes::from(codec::encode(&PolicyUpdate {
                steps_per_actor: share,
                ..update.clone()
            }))
        };
        self.put_publication(update.version, encoded, update.published_unix_ms, share)
    }

    fn gather(
        &mut self,
        update: &PolicyUpdate,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError> {
        let mut round = self
            .published_last
            .take()
            .filter(|p| p.version == update.version)
            .ok_or_else(|| {
                PortError::Transport(format!(
                    "gathering version {} before publishing it",
                    update.version
                ))
            })?;
        // After this epoch the live set alone says who collects.
        let mut expecting = self.membership.take_expected();
        let mut markers = Vec::new();
        let mut delivered_by_lost = 0;
        let mut missing;
        let mut timed_out = false;
        loop {
            let Some(closed) = self.gather_round(&round, expecting, store)? else {
                return Ok(None);
            };
            markers.extend(closed.markers);
            delivered_by_lost += closed.delivered_by_lost;
            missing = closed.missing;
            timed_out |= closed.timed_out;
            if closed.undone == 0 {
                break;
            }
            // The share the lost actors did not deliver, dealt to the live ones: the same version published again
            // (a new publication time, which their markers answer). With none alive (a router restarting, a cut:
            // they all left at once, one after its marker), to as many as were alive last, whom the round waits for
            // as they come back (or, with none back for `bus.no_actor_timeout_s`, the run ends).
            let members = self.membership.dealt_again();
            let again = share(closed.undone, members);
            tracing::warn!(
                epoch = update.version,
                lost = ?closed.lost,
                undone = closed.undone,
                live = ?self.membership.live(),
                share = again,
                "actors left before their share was collected: the rest dealt to the live actors"
            );
            let published_unix_ms = crate::unix_ms().max(round.published_unix_ms + 1);
            let encoded = Bytes::from(codec::encode(&PolicyUpdate {
                steps_per_actor: again,
                published_unix_ms,
                ..update.clone()
            }));
            self.put_publication(update.version, encoded, published_unix_ms, again)?;
            round = self.published_last.take().ok_or_else(|| {
                PortError::Transport("a round published and not held".to_string())
            })?;
            expecting = members;
        }
        Ok(Some(Collected {
            // An actor lost before its marker counts with the steps it was heard to deliver: its marker (what it
            // published and took) is gone, and the rounds after it dealt only the rest of its share again.
            steps_published: markers.iter().map(|m| m.steps).sum::<u64>() + delivered_by_lost,
            steps_taken: markers.iter().map(|m| m.taken).sum::<u64>() + delivered_by_lost,
            steps_staged: markers.iter().map(|m| m.staged).sum(),
            steps_shielded: markers.iter().map(|m| m.shielded).sum(),
            missing,
            timed_out,
            live: self.membership.live().iter().cloned().collect(),
            times: None,
        }))
    }

    fn commit(&mut self, segments: &[SegmentId]) {
        self.traj.commit(segments);
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
        self.published.evaluated(&reports);
        reports
    }

    fn interrupted(&self) -> bool {
        self.interrupt.is_set()
    }

    fn stop(&mut self, reason: &str) -> Result<(), PortError> {
        let stop = cabc_proto::messages::Stop {
            reason: reason.to_string(),
        };
        let until = Instant::now() + STOP_LINGER;
        loop {
            self.bus
                .put_blocking(&self.bus.keys.control(), &stop)
                .map_err(transport)?;
            std::thread::sleep(STOP_AGAIN);
            self.follow_liveliness(None);
            // Epoch 0: the evaluators are followed, not warned about.
            self.follow_evaluators(0);
            let heard = self.membership.live().is_empty() && self.evaluators.is_empty();
            if heard || self.interrupt.is_set() || Instant::now() >= until {
                if !heard {
                    tracing::warn!(
                        actors = ?self.membership.live(),
                        evaluators = ?self.evaluators,
                        "stopped the run; these were still alive when the learner stopped saying so"
                    );
                }
                return Ok(());
            }
        }
    }

    fn rejected(&self) -> u64 {
        self.bus.rejects.count()
    }
}
