//! The actor's side of `traj/<id>`: [`ZenohSegments`] puts its segments (batched, [`Batching`]) and markers, each
//! segment held in the [`Outbox`] until the learner has it.

use super::{has_router, lock, transport, Outbox, RESEND_AFTER};
use crate::interrupt::Interrupt;
use crate::ports::{with_stats, SharedStats};
use crate::Bus;
use bytes::Bytes;
use cabc_proto::codec;
use cabc_proto::messages::{EpochDone, Segment, TrajMessage};
use cabc_proto::ports::{PortError, SegmentSink};
use cabc_runfolder::journal::{ActorEvent, ActorJournal};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

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
