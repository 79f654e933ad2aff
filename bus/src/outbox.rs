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

use crate::ports::{with_stats, SharedStats};
use crate::{decode_sample, encoding_of, Bus};
use bytes::Bytes;
use cabc_proto::messages::{Ack, TrajMessage};
use cabc_proto::ports::PortError;
use cabc_runfolder::journal::{ActorEvent, ActorJournal};
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

mod held;
mod segments;

use held::Held;
pub use segments::{Batching, ZenohSegments};

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
