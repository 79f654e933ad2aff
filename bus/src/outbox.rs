//! An actor's segments on `traj/<id>`, at least once (issue 64).
//!
//! Every segment an actor publishes stays in its [`Outbox`] until the learner acknowledges it on `ack/<id>`
//! ([`Ack`], put by [`crate::receipts`] as each segment arrives); what stays unacknowledged is published again: at
//! once when the session finds its router again (a link cut past zenoh's lease, a restarted router: what was in
//! flight then is gone), else after [`RESEND_AFTER`]. So a segment reaches the learner at least once on the wire, and
//! the learner's ledger, keyed by (actor, incarnation, seq), stores it exactly once: a copy is dropped there and
//! counted (`duplicate_segments`). The outbox holds at most [`MAX_OUTBOX_BYTES`]; past it the oldest segments are
//! dropped, logged and counted in `segments_lost`.
//!
//! On a plain bus anybody may put on `ack/<id>`: a forged receipt only makes the actor forget a segment it would
//! otherwise have sent again (as a forged stop ends it); under mutual TLS only the learner may (`security.rs`).

use crate::interrupt::Interrupt;
use crate::ports::{with_stats, SharedStats};
use crate::{decode_sample, encoding_of, Bus};
use bytes::Bytes;
use cabc_proto::codec;
use cabc_proto::messages::{Ack, EpochDone, Segment, TrajMessage};
use cabc_proto::ports::{PortError, SegmentSink};
use cabc_runfolder::journal::{ActorEvent, ActorJournal};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

/// A segment not acknowledged this long after it was (last) published is published again: far past the learner's
/// receipt of a segment that arrived (it acknowledges on arrival, training or not), short beside an epoch.
pub const RESEND_AFTER: Duration = Duration::from_secs(10);

/// The outbox's bound: past it the oldest segments are dropped (and counted lost). Acknowledged within
/// milliseconds, it holds a few segments; it fills only while the learner is away and the router is not.
pub const MAX_OUTBOX_BYTES: usize = 256 << 20;

/// How often the outbox looks for what to publish again.
const TICK: Duration = Duration::from_millis(250);

/// After the router is back, how long the outbox waits before publishing again (the learner's subscription has to
/// reach the router first, or zenoh drops the put for want of a subscriber).
const SETTLE: Duration = Duration::from_secs(1);

fn transport(e: impl std::fmt::Display) -> PortError {
    PortError::Transport(e.to_string())
}

fn has_router(session: &Session) -> bool {
    session.info().routers_zid().wait().next().is_some()
}

/// The segments of one incarnation not committed yet, by seq.
#[derive(Default)]
struct Held {
    incarnation: Option<u64>,
    segments: BTreeMap<u64, Unacked>,
    bytes: usize,
    /// The learner process whose receipts came last.
    learner: Option<u64>,
}

struct Unacked {
    /// The message it went in (shared by the segments of one batch).
    encoded: Bytes,
    /// The segments of that message.
    batch: usize,
    /// Its part of the message's bytes (what the outbox's bound counts).
    share: usize,
    sent: Instant,
    /// Published before the router was lost (in flight then, or dropped), or received by a learner process that is
    /// gone: it goes out again before the next marker.
    stranded: bool,
    /// The learner process that received it (its receipt on arrival), until it commits it: not published again
    /// unless another learner process takes over.
    received_by: Option<u64>,
}

impl Held {
    /// Holds the segments `seqs` of `incarnation`, published together as `encoded`; returns the seqs dropped to
    /// keep the outbox within its bound.
    fn hold(&mut self, incarnation: u64, seqs: &[u64], encoded: Bytes) -> Vec<u64> {
        self.incarnation = Some(incarnation);
        let sent = Instant::now();
        let share = encoded.len() / seqs.len().max(1);
        for &seq in seqs {
            let unacked = Unacked {
                encoded: encoded.clone(),
                batch: seqs.len(),
                share,
                sent,
                stranded: false,
                received_by: None,
            };
            self.bytes += share;
            if let Some(old) = self.segments.insert(seq, unacked) {
                self.bytes -= old.share;
            }
        }
        let mut dropped = Vec::new();
        while self.bytes > MAX_OUTBOX_BYTES && self.segments.len() > 1 {
            let Some((seq, oldest)) = self.segments.pop_first() else {
                break;
            };
            self.bytes -= oldest.share;
            dropped.push(seq);
            tracing::warn!(
                seq,
                "outbox full (the learner acknowledges nothing): the oldest segment dropped unacknowledged"
            );
        }
        dropped
    }

    /// A receipt: on arrival, the segments are received (not published again while their learner lives); committed,
    /// they are forgotten. A receipt from another learner process than the last (a learner killed and resumed from
    /// its checkpoint) releases what the last one received and never committed: it is published again.
    fn acknowledged(&mut self, ack: &Ack) {
        if self.incarnation != Some(ack.incarnation) {
            return;
        }
        if self.learner.is_some_and(|last| last != ack.learner) {
            for unacked in self.segments.values_mut() {
                if unacked.received_by.is_some_and(|by| by != ack.learner) {
                    unacked.received_by = None;
                    unacked.stranded = true;
                }
            }
        }
        self.learner = Some(ack.learner);
        for seq in &ack.seqs {
            if ack.committed {
                if let Some(gone) = self.segments.remove(seq) {
                    self.bytes -= gone.share;
                }
            } else if let Some(unacked) = self.segments.get_mut(seq) {
                unacked.received_by = Some(ack.learner);
                unacked.stranded = false;
            }
        }
    }

    /// The segments not received to publish again now: all of them (`all`), or those unacknowledged for `after`. A
    /// stranded one stays stranded: published again just after the router is back, it may reach the router before
    /// the learner's subscription does and be dropped there, so it still goes again before the next marker.
    fn due(&mut self, all: bool, after: Duration) -> Vec<Bytes> {
        let now = Instant::now();
        let due = self
            .segments
            .iter_mut()
            .filter(|(_, u)| u.received_by.is_none())
            .filter(|(_, u)| all || now.duration_since(u.sent) >= after)
            .map(|(&seq, u)| {
                u.sent = now;
                let u: &Unacked = u;
                (seq, u)
            })
            .collect();
        regroup(due)
    }

    /// The router is lost: what is held now and not received was published before, and may never have arrived.
    fn strand(&mut self) {
        for unacked in self.segments.values_mut() {
            unacked.stranded |= unacked.received_by.is_none();
        }
    }

    /// The stranded segments, in order, to publish again before a marker: the marker must not reach the learner
    /// before them, or the epoch closes without them (they would land in the next epoch's data).
    fn stranded(&mut self) -> Vec<Bytes> {
        let now = Instant::now();
        let stranded = self
            .segments
            .iter_mut()
            .filter(|(_, u)| u.stranded)
            .map(|(&seq, u)| {
                u.sent = now;
                u.stranded = false;
                let u: &Unacked = u;
                (seq, u)
            })
            .collect();
        regroup(stranded)
    }
}

/// The messages that publish again the segments `again` (in seq order): a message whose segments all go again goes
/// as it was; of a batch only some of whose segments go again, those are encoded anew (a copy of the others would
/// reach the learner's ledger, which drops it, but counts it). A batch's segments are consecutive seqs.
fn regroup(again: Vec<(u64, &Unacked)>) -> Vec<Bytes> {
    let mut messages = Vec::new();
    let mut rest = again.as_slice();
    while let Some((_, first)) = rest.first() {
        let same = rest
            .iter()
            .take_while(|(_, u)| u.encoded.as_ptr() == first.encoded.as_ptr())
            .count();
        let (group, after) = rest.split_at(same);
        rest = after;
        if group.len() == first.batch {
            messages.push(first.encoded.clone());
            continue;
        }
        // Only the actor's own encoding is decoded here, so it decodes; were it not to, the whole batch goes again.
        match codec::decode::<TrajMessage>(&first.encoded) {
            Ok(message) => {
                let seqs: Vec<u64> = group.iter().map(|(seq, _)| *seq).collect();
                let mut segments = message.into_segments();
                segments.retain(|s| seqs.contains(&s.seq));
                let message = match segments.len() {
                    1 => TrajMessage::Segment(segments.remove(0)),
                    _ => TrajMessage::Segments(segments),
                };
                messages.push(Bytes::from(codec::encode(&message)));
            }
            Err(e) => {
                tracing::warn!("a held batch does not decode ({e}): published again whole");
                messages.push(first.encoded.clone());
            }
        }
    }
    messages
}

/// An actor's segments until the learner has them (the module's doc).
pub struct Outbox {
    held: Arc<Mutex<Held>>,
    stats: SharedStats,
    journal: Option<Arc<ActorJournal>>,
    _acks: Subscriber<()>,
    stop: Arc<AtomicBool>,
    resender: Option<JoinHandle<()>>,
}

fn lock(held: &Mutex<Held>) -> std::sync::MutexGuard<'_, Held> {
    held.lock().unwrap_or_else(|e| e.into_inner())
}

impl Outbox {
    /// `actor`'s outbox on `bus`: it hears the learner's receipts on `ack/<actor>` and publishes again on
    /// `traj/<actor>` what stays unacknowledged for `resend_after` ([`RESEND_AFTER`] in a run). With a `journal`, each
    /// receipt and each segment dropped unacknowledged goes in it.
    pub fn open(
        bus: &Bus,
        actor: &str,
        stats: SharedStats,
        resend_after: Duration,
        journal: Option<Arc<ActorJournal>>,
    ) -> Result<Outbox, PortError> {
        let held: Arc<Mutex<Held>> = Arc::default();
        let (on_ack, rejects) = (held.clone(), bus.rejects.clone());
        let ack_journal = journal.clone();
        let acks = bus
            .session
            .declare_subscriber(bus.keys.ack(actor))
            .callback(move |sample| {
                let bytes = sample.payload().to_bytes();
                if let Some(ack) =
                    decode_sample::<Ack>(sample.key_expr().as_str(), &bytes, &rejects)
                {
                    lock(&on_ack).acknowledged(&ack);
                    if let Some(journal) = &ack_journal {
                        journal.record(&ActorEvent::Acknowledged {
                            learner: ack.learner,
                            seqs: ack.seqs,
                            committed: ack.committed,
                        });
                    }
                }
            })
            .wait()
            .map_err(transport)?;
        let stop = Arc::new(AtomicBool::new(false));
        let resender = {
            let (session, key) = (bus.session.clone(), bus.keys.traj(actor));
            let (held, stats, stop) = (held.clone(), stats.clone(), stop.clone());
            std::thread::Builder::new()
                .name("outbox".into())
                .spawn(move || resend(&session, &key, &held, &stats, &stop, resend_after))
                .map_err(transport)?
        };
        Ok(Outbox {
            held,
            stats,
            journal,
            _acks: acks,
            stop,
            resender: Some(resender),
        })
    }

    /// Holds the segments `seqs` of `incarnation` (as published together: `encoded`) until the learner acknowledges
    /// them.
    pub fn hold(&self, incarnation: u64, seqs: &[u64], encoded: Bytes) {
        let dropped = lock(&self.held).hold(incarnation, seqs, encoded);
        if !dropped.is_empty() {
            with_stats(&self.stats, |s| s.segments_lost += dropped.len() as u64);
        }
        if let Some(journal) = &self.journal {
            for seq in dropped {
                let why = "the outbox was full: dropped unacknowledged".to_string();
                journal.record(&ActorEvent::Unsent { seq, why });
            }
        }
    }

    /// Segments published and not received by the learner yet.
    pub fn unacknowledged(&self) -> usize {
        let held = lock(&self.held);
        held.segments
            .values()
            .filter(|u| u.received_by.is_none())
            .count()
    }

    /// Segments published and not committed by the learner yet (received or not).
    pub fn uncommitted(&self) -> usize {
        lock(&self.held).segments.len()
    }

    /// Publishes again, on `key`, the segments published before the router was last lost and not acknowledged
    /// since: what a marker must not overtake. Returns how many.
    fn publish_stranded(&self, bus: &Bus, key: &str) -> Result<u64, PortError> {
        let stranded = lock(&self.held).stranded();
        let count = stranded.len() as u64;
        if count > 0 {
            tracing::info!(
                segments = count,
                "publishing again, before the marker, the segments sent before the router was lost"
            );
        }
        for encoded in stranded {
            bus.put_encoded_blocking::<TrajMessage>(key, encoded)
                .map_err(transport)?;
            with_stats(&self.stats, |s| s.segments_resent += 1);
        }
        Ok(count)
    }
}

impl Drop for Outbox {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(resender) = self.resender.take() {
            let _ = resender.join();
        }
    }
}

/// The outbox's thread: publishes again what is due (everything once the router is back after [`SETTLE`]).
fn resend(
    session: &Session,
    key: &str,
    held: &Mutex<Held>,
    stats: &SharedStats,
    stop: &AtomicBool,
    after: Duration,
) {
    let mut lost_router: Option<Instant> = None;
    let mut back: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(TICK);
        if !has_router(session) {
            if lost_router.is_none() {
                lock(held).strand();
            }
            lost_router.get_or_insert_with(Instant::now);
            back = None;
            continue;
        }
        if lost_router.is_some() {
            let since = *back.get_or_insert_with(Instant::now);
            if since.elapsed() < SETTLE {
                continue;
            }
        }
        let all = lost_router.take().is_some();
        let due = lock(held).due(all, after);
        if due.is_empty() {
            continue;
        }
        tracing::info!(
            segments = due.len(),
            after_reconnect = all,
            "publishing again the segments the learner has not acknowledged"
        );
        for encoded in due {
            let put = session
                .put(key, encoded)
                .encoding(encoding_of::<TrajMessage>())
                .congestion_control(CongestionControl::Block)
                .wait();
            match put {
                Ok(()) => with_stats(stats, |s| s.segments_resent += 1),
                Err(e) => tracing::warn!("publishing a segment again: {e}"),
            }
        }
    }
}

/// How often an actor without a router looks again.
const RECONNECT_POLL: Duration = Duration::from_millis(200);

/// How an actor gathers its segments into messages (`bus.segment_batch_ms`, `bus.segment_batch_kib`; issue 73): the
/// learner's intake costs per message, so short segments go together. A batch goes when it is `window` old at the
/// actor's next segment, when it holds `max_bytes`, and before every marker (the learner closes an epoch at the
/// markers, so it never waits for a batch); each of its segments is held, acknowledged and journalled by its own seq.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Batching {
    pub window: Duration,
    pub max_bytes: usize,
}

impl Batching {
    /// Every segment a message of its own.
    pub const NONE: Batching = Batching {
        window: Duration::ZERO,
        max_bytes: 0,
    };

    /// The run configuration's batching.
    pub fn of(bus: &cabc_proto::config::BusSection) -> Batching {
        Batching {
            window: Duration::from_secs_f64(bus.segment_batch_ms.max(0.0) / 1e3),
            max_bytes: (bus.segment_batch_kib as usize).saturating_mul(1024),
        }
    }
}

/// A segment's bytes as encoded, roughly (what a batch's bound counts): its steps' numbers and images.
fn approx_bytes(segment: &Segment) -> usize {
    let step = |s: &cabc_proto::messages::Step| 96 + s.image.as_ref().map_or(0, |i| i.rgb.len());
    64 + segment.actor.len() + segment.steps.iter().map(step).sum::<usize>()
}

/// The segments cut and not published yet ([`Batching`]).
#[derive(Default)]
struct Pending {
    segments: Vec<Segment>,
    bytes: usize,
    since: Option<Instant>,
}

/// An actor's segments and markers on `traj/<id>`. While the session has no router (a learner restarting), a put
/// waits for it to be back: zenoh would drop a put without a router silently, and an actor has nothing else to do
/// then (its expert is out of reach too). Interrupted while waiting, the message is counted as lost, never as sent.
/// Each segment stays in the [`Outbox`] until the learner has it.
pub struct ZenohSegments<'a> {
    bus: &'a Bus,
    key: String,
    interrupt: Interrupt,
    stats: SharedStats,
    outbox: Outbox,
    /// The last marker sent ([`crate::ports::MarkerEcho`]).
    last_marker: Arc<Mutex<Option<EpochDone>>>,
    batching: Batching,
    pending: Pending,
}

impl<'a> ZenohSegments<'a> {
    pub fn new(
        bus: &'a Bus,
        actor: &str,
        interrupt: &Interrupt,
        stats: SharedStats,
    ) -> Result<Self, PortError> {
        Self::resending_after(bus, actor, interrupt, stats, RESEND_AFTER)
    }

    /// As [`ZenohSegments::new`], publishing again what stays unacknowledged for `after` (a test's short wait).
    pub fn resending_after(
        bus: &'a Bus,
        actor: &str,
        interrupt: &Interrupt,
        stats: SharedStats,
        after: Duration,
    ) -> Result<Self, PortError> {
        Self::open(bus, actor, interrupt, stats, after, None)
    }

    /// As [`ZenohSegments::new`], with the actor's journal if it keeps one: the outbox writes the learner's receipts
    /// in it (the actor's `Journaled` sink writes what it publishes).
    pub fn journaled(
        bus: &'a Bus,
        actor: &str,
        interrupt: &Interrupt,
        stats: SharedStats,
        journal: Option<Arc<ActorJournal>>,
    ) -> Result<Self, PortError> {
        Self::open(bus, actor, interrupt, stats, RESEND_AFTER, journal)
    }

    fn open(
        bus: &'a Bus,
        actor: &str,
        interrupt: &Interrupt,
        stats: SharedStats,
        after: Duration,
        journal: Option<Arc<ActorJournal>>,
    ) -> Result<Self, PortError> {
        Ok(ZenohSegments {
            bus,
            key: bus.keys.traj(actor),
            interrupt: interrupt.clone(),
            outbox: Outbox::open(bus, actor, stats.clone(), after, journal)?,
            stats,
            last_marker: Arc::default(),
            batching: Batching::NONE,
            pending: Pending::default(),
        })
    }

    /// Gathers the segments into messages as `batching` says (without: a message each).
    pub fn batching(mut self, batching: Batching) -> Self {
        self.batching = batching;
        self
    }

    /// Waits until the session has a router: zenoh would drop a put without one silently. Interrupted while
    /// waiting: an error, and the message is not sent.
    fn wait_for_router(&self) -> Result<(), PortError> {
        let mut warned = false;
        while !has_router(&self.bus.session) {
            if self.interrupt.is_set() {
                return Err(PortError::Stopped(
                    "interrupted while no router was up".into(),
                ));
            }
            if !warned {
                warned = true;
                tracing::warn!("no router: holding the segments until the learner is back");
            }
            std::thread::sleep(RECONNECT_POLL);
        }
        Ok(())
    }

    /// Publishes the pending segments as one message (one segment: as a `Segment`), held in the outbox until the
    /// learner has them. `wait`: for a router, if none is up (else, and when interrupted while waiting, they are
    /// not sent: counted lost and journalled unsent).
    fn flush(&mut self, wait: bool) -> Result<(), PortError> {
        if self.pending.segments.is_empty() {
            return Ok(());
        }
        let started = Instant::now();
        let up = if wait {
            self.wait_for_router()
        } else if has_router(&self.bus.session) {
            Ok(())
        } else {
            Err(PortError::Stopped("no router up as the actor ended".into()))
        };
        let pending = std::mem::take(&mut self.pending);
        let seqs: Vec<u64> = pending.segments.iter().map(|s| s.seq).collect();
        if let Err(e) = up {
            with_stats(&self.stats, |s| s.segments_lost += seqs.len() as u64);
            if let Some(journal) = &self.outbox.journal {
                for &seq in &seqs {
                    journal.record(&ActorEvent::Unsent {
                        seq,
                        why: e.to_string(),
                    });
                }
            }
            return Err(e);
        }
        let incarnation = pending.segments[0].incarnation;
        let mut segments = pending.segments;
        let message = match segments.len() {
            1 => TrajMessage::Segment(segments.remove(0)),
            _ => TrajMessage::Segments(segments),
        };
        let encoded = Bytes::from(codec::encode(&message));
        self.outbox.hold(incarnation, &seqs, encoded.clone());
        self.bus
            .put_encoded_blocking::<TrajMessage>(&self.key, encoded)
            .map_err(transport)?;
        with_stats(&self.stats, |s| s.transport += started.elapsed());
        Ok(())
    }

    /// The handle through which this actor's policy source sends its last marker again.
    pub fn echo(&self) -> crate::ports::MarkerEcho {
        let held = self.outbox.held.clone();
        crate::ports::MarkerEcho::new(
            self.key.clone(),
            self.last_marker.clone(),
            // Every segment not acknowledged, stranded or not (MarkerEcho's doc says why).
            Arc::new(move || lock(&held).due(true, Duration::ZERO)),
        )
    }

    /// Segments published and not received by the learner yet.
    pub fn unacknowledged(&self) -> usize {
        self.outbox.unacknowledged()
    }

    /// Segments published and not committed by the learner yet.
    pub fn uncommitted(&self) -> usize {
        self.outbox.uncommitted()
    }
}

impl SegmentSink for ZenohSegments<'_> {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        let TrajMessage::EpochDone(marker) = message else {
            for segment in message.into_segments() {
                // One batch, one incarnation (the codec refuses a batch of several).
                if self
                    .pending
                    .segments
                    .first()
                    .is_some_and(|first| first.incarnation != segment.incarnation)
                {
                    self.flush(true)?;
                }
                self.pending.bytes += approx_bytes(&segment);
                self.pending.since.get_or_insert_with(Instant::now);
                self.pending.segments.push(segment);
            }
            let full = self.pending.bytes >= self.batching.max_bytes;
            let old = self
                .pending
                .since
                .is_some_and(|since| since.elapsed() >= self.batching.window);
            return if full || old {
                self.flush(true)
            } else {
                Ok(())
            };
        };
        // The marker says the segments before it were sent: the batch goes first, and those stranded by a lost
        // router go again.
        self.flush(true)?;
        let started = Instant::now();
        self.wait_for_router()?;
        self.outbox.publish_stranded(self.bus, &self.key)?;
        self.bus
            .put_blocking(&self.key, &TrajMessage::EpochDone(marker.clone()))
            .map_err(transport)?;
        *self.last_marker.lock().unwrap_or_else(|e| e.into_inner()) = Some(marker);
        with_stats(&self.stats, |s| s.transport += started.elapsed());
        Ok(())
    }
}

/// How long an ending actor waits for the learner's receipt of its last batch.
const LAST_RECEIPT: Duration = Duration::from_secs(2);

impl Drop for ZenohSegments<'_> {
    /// A batch still pending goes now, if a router is up (an actor ending on the learner's stop: the learner journals
    /// what arrives after its run's end); else it is journalled unsent. The actor then waits (at most
    /// [`LAST_RECEIPT`]) for the learner's receipt, so that its liveliness does not leave before the batch arrives:
    /// a learner that saw every actor leave stops listening.
    fn drop(&mut self) {
        if self.pending.segments.is_empty() {
            return;
        }
        if let Err(e) = self.flush(false) {
            tracing::warn!("the last segments were not published: {e}");
            return;
        }
        let until = Instant::now() + LAST_RECEIPT;
        while self.outbox.unacknowledged() > 0 && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Learner process 1's receipt of a checkpoint: the segments are committed.
    fn ack(incarnation: u64, seqs: &[u64]) -> Ack {
        Ack {
            incarnation,
            seqs: seqs.to_vec(),
            learner: 1,
            committed: true,
        }
    }

    /// Learner process `learner`'s receipt on arrival.
    fn received(incarnation: u64, seqs: &[u64], learner: u64) -> Ack {
        Ack {
            incarnation,
            seqs: seqs.to_vec(),
            learner,
            committed: false,
        }
    }

    #[test]
    fn a_received_segment_waits_for_its_commit_and_goes_again_when_another_learner_takes_over() {
        let mut held = Held::default();
        for seq in 0..3 {
            held.hold(9, &[seq], Bytes::from(vec![0u8; 10]));
        }
        held.acknowledged(&received(9, &[0, 1], 5));
        // Received: kept, and not published again, on the timer or after a reconnection, nor stranded.
        assert_eq!(held.segments.len(), 3);
        assert_eq!(held.due(true, Duration::ZERO).len(), 1, "seq 2 only");
        held.strand();
        assert_eq!(held.stranded().len(), 1, "seq 2 only");
        // Learner 5 commits seq 0, then dies; learner 6 (resumed from its checkpoint) receives seq 2: seq 1, which 5
        // received and never committed, goes again before the next marker.
        held.acknowledged(&Ack {
            committed: true,
            ..received(9, &[0], 5)
        });
        held.acknowledged(&received(9, &[2], 6));
        assert_eq!(held.segments.keys().copied().collect::<Vec<_>>(), [1, 2]);
        assert_eq!(held.stranded().len(), 1, "seq 1, released");
        assert_eq!(held.due(false, Duration::ZERO).len(), 1);
        held.acknowledged(&Ack {
            committed: true,
            ..received(9, &[1, 2], 6)
        });
        assert!(held.segments.is_empty());
    }

    #[test]
    fn an_acknowledged_segment_leaves_the_outbox_and_no_other_does() {
        let mut held = Held::default();
        for seq in 0..4 {
            held.hold(9, &[seq], Bytes::from(vec![0u8; 10]));
        }
        held.acknowledged(&ack(9, &[1, 3, 7]));
        assert_eq!(held.segments.keys().copied().collect::<Vec<_>>(), [0, 2]);
        assert_eq!(held.bytes, 20);
        // Another incarnation's receipts (a restarted actor's predecessor) change nothing.
        held.acknowledged(&ack(8, &[0, 2]));
        assert_eq!(held.segments.len(), 2);
    }

    #[test]
    fn what_stays_unacknowledged_is_due_again_after_the_wait_or_at_once_after_a_reconnection() {
        let mut held = Held::default();
        held.hold(1, &[0], Bytes::from_static(b"a"));
        assert!(held.due(false, Duration::from_secs(60)).is_empty());
        assert_eq!(held.due(false, Duration::ZERO).len(), 1);
        assert_eq!(held.due(true, Duration::from_secs(60)).len(), 1);
        held.acknowledged(&ack(1, &[0]));
        assert!(held.due(true, Duration::ZERO).is_empty());
    }

    #[test]
    fn what_was_sent_before_the_router_was_lost_goes_again_before_the_next_marker_once() {
        let mut held = Held::default();
        held.hold(1, &[0], Bytes::from_static(b"a"));
        held.hold(1, &[1], Bytes::from_static(b"b"));
        held.acknowledged(&ack(1, &[0]));
        assert!(
            held.stranded().is_empty(),
            "no router lost: nothing stranded"
        );
        held.strand();
        // Published after the router was back: not stranded.
        held.hold(1, &[2], Bytes::from_static(b"c"));
        assert_eq!(held.stranded(), [Bytes::from_static(b"b")]);
        assert!(held.stranded().is_empty(), "published again once");
        // Published again after the reconnection by the outbox's thread: still stranded (that copy may have reached
        // the router before the learner's subscription did), until it goes before a marker or is acknowledged.
        held.strand();
        assert_eq!(held.due(true, Duration::from_secs(60)).len(), 2);
        assert_eq!(held.stranded().len(), 2);
        assert!(held.stranded().is_empty());
        held.strand();
        held.acknowledged(&ack(1, &[1, 2]));
        assert!(held.stranded().is_empty(), "acknowledged: gone");
    }

    fn batch(seqs: std::ops::Range<u64>) -> Bytes {
        let segments = seqs
            .map(|seq| Segment {
                seq,
                incarnation: 1,
                ..Segment::of("actor-0", cabc_proto::messages::Outcome::Lap, Vec::new())
            })
            .collect();
        Bytes::from(codec::encode(&TrajMessage::Segments(segments)))
    }

    fn seqs_of(encoded: &Bytes) -> Vec<u64> {
        let message = codec::decode::<TrajMessage>(encoded).unwrap();
        message.segments().iter().map(|s| s.seq).collect()
    }

    /// A batch whose segments all go again goes as it was published; of one partly acknowledged, only the rest go
    /// again, in a message of their own (no copy of what the learner has).
    #[test]
    fn a_batch_goes_again_whole_or_only_its_unacknowledged_segments() {
        let mut held = Held::default();
        let (first, second) = (batch(0..3), batch(3..5));
        held.hold(1, &[0, 1, 2], first.clone());
        held.hold(1, &[3, 4], second.clone());
        assert_eq!(held.bytes, first.len() / 3 * 3 + second.len() / 2 * 2);
        assert_eq!(held.due(true, Duration::ZERO), [first, second.clone()]);
        held.acknowledged(&ack(1, &[1]));
        held.acknowledged(&received(1, &[4], 1));
        let again = held.due(true, Duration::ZERO);
        assert_eq!(again.len(), 2);
        assert_eq!(seqs_of(&again[0]), [0, 2]);
        assert!(matches!(
            codec::decode::<TrajMessage>(&again[1]).unwrap(),
            TrajMessage::Segment(s) if s.seq == 3
        ));
        held.strand();
        assert_eq!(
            held.stranded().iter().map(seqs_of).collect::<Vec<_>>(),
            [vec![0, 2], vec![3]]
        );
        held.acknowledged(&ack(1, &[0, 2, 3, 4]));
        assert!(held.segments.is_empty());
        assert_eq!(held.bytes, 0);
    }

    #[test]
    fn a_full_outbox_drops_its_oldest_segments_and_counts_them() {
        let mut held = Held::default();
        let big = MAX_OUTBOX_BYTES / 2;
        assert!(held.hold(1, &[0], Bytes::from(vec![0u8; big])).is_empty());
        assert!(held.hold(1, &[1], Bytes::from(vec![0u8; big])).is_empty());
        assert_eq!(held.hold(1, &[2], Bytes::from(vec![0u8; big])), vec![0]);
        assert_eq!(held.segments.keys().copied().collect::<Vec<_>>(), [1, 2]);
    }
}
