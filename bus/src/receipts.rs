//! The learner's side of `traj/*` (issue 64): each message is decoded and held to the key it came on as it arrives,
//! in the subscription's callback, and each segment is acknowledged at once on `ack/<actor>` ([`Ack`]: the learner
//! has it, training or not), so that the actor's outbox (`crate::outbox`) forgets it; then the message waits in a
//! queue of at most [`TRAJ_QUEUE`] for the epoch's gathering. A full queue holds the callback back, and zenoh's
//! reliable delivery the publishers, rather than dropping anything. A copy of a segment (published again because its
//! receipt was lost) is acknowledged again; the ledger drops it.
//!
//! The callback keeps its own clock ([`ReceiptClock`]): the time it spends decoding, acknowledging and waiting for
//! room in the queue, so that a load test (`cabc bench-bus`) can say which stage of the learner's intake bends first.

use crate::gate::EpochGate;
use crate::senders::{check_traj, traj_sender};
use crate::{decode_sample, encoding_of, Bus};
use cabc_proto::codec;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{Ack, Segment, SegmentId, TrajMessage};
use cabc_proto::ports::PortError;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

/// Segments (and markers) that may wait while the learner trains.
pub const TRAJ_QUEUE: usize = 1 << 16;

/// A message of `traj/*` as it arrived: who sent it (the `<actor>` of its key) and the message, when it decoded and is
/// that actor's ([`check_traj`]; a refusal is counted with the bus's rejects).
pub struct Arrival {
    pub sender: Option<String>,
    pub message: Option<TrajMessage>,
}

impl Arrival {
    /// Takes this message of `traj/*` into epoch `version`'s gathering: a segment to `store` (its steps of `version`
    /// counted in `heard` by actor), a marker to the gate.
    pub(crate) fn take_in(
        self,
        version: u64,
        gate: &mut EpochGate,
        heard: &mut BTreeMap<String, u64>,
        store: &mut dyn FnMut(Segment),
    ) {
        if let Some(sender) = &self.sender {
            gate.heard_from(sender, Instant::now());
        }
        match self.message {
            Some(TrajMessage::EpochDone(marker)) => {
                heard.entry(marker.actor.clone()).or_default();
                gate.done(marker);
            }
            Some(message) => {
                for segment in message.into_segments() {
                    if segment.policy_version == version {
                        *heard.entry(segment.actor.clone()).or_default() +=
                            segment.steps.len() as u64;
                    }
                    store(segment)
                }
            }
            None => {}
        }
    }
}

/// The learner's subscription to every actor's `traj/<actor>`: the arrivals come out of the receiver.
pub struct Receipts {
    _subscriber: Subscriber<()>,
    pub arrivals: Receiver<Arrival>,
    /// Where the subscription's callback spent its time so far.
    pub clock: Arc<ReceiptClock>,
    /// This learner process's incarnation (the time it subscribed, in microseconds), in every receipt it puts.
    pub learner: u64,
    acknowledger: Arc<Acknowledger>,
}

/// The subscription callback's counts and times since it was declared (nanoseconds; zenoh's threads run it, so its
/// time is theirs): a few clock readings a message, beside a decode of microseconds.
#[derive(Debug, Default)]
pub struct ReceiptClock {
    messages: AtomicU64,
    bytes: AtomicU64,
    decode_ns: AtomicU64,
    ack_ns: AtomicU64,
    queue_ns: AtomicU64,
}

/// A reading of a [`ReceiptClock`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReceiptTimes {
    /// Messages of `traj/*` taken (segments and markers, refused ones too).
    pub messages: u64,
    /// Their payloads' bytes.
    pub bytes: u64,
    /// Making the payload contiguous, decoding and validating it ([`codec::decode`]) and holding it to its key
    /// ([`check_traj`]).
    pub decode_ns: u64,
    /// Putting the receipts ([`acknowledge`]).
    pub ack_ns: u64,
    /// Handing the message to the queue of [`TRAJ_QUEUE`], waiting there for room while the gathering is behind
    /// (backpressure, not work).
    pub queue_ns: u64,
}

impl ReceiptClock {
    /// The counts and times so far.
    pub fn read(&self) -> ReceiptTimes {
        ReceiptTimes {
            messages: self.messages.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            decode_ns: self.decode_ns.load(Ordering::Relaxed),
            ack_ns: self.ack_ns.load(Ordering::Relaxed),
            queue_ns: self.queue_ns.load(Ordering::Relaxed),
        }
    }

    fn add(counter: &AtomicU64, since: Instant) -> Instant {
        let now = Instant::now();
        counter.fetch_add((now - since).as_nanos() as u64, Ordering::Relaxed);
        now
    }
}

impl ReceiptTimes {
    /// What was added between `earlier` and this reading.
    pub fn since(&self, earlier: &ReceiptTimes) -> ReceiptTimes {
        ReceiptTimes {
            messages: self.messages.saturating_sub(earlier.messages),
            bytes: self.bytes.saturating_sub(earlier.bytes),
            decode_ns: self.decode_ns.saturating_sub(earlier.decode_ns),
            ack_ns: self.ack_ns.saturating_sub(earlier.ack_ns),
            queue_ns: self.queue_ns.saturating_sub(earlier.queue_ns),
        }
    }
}

impl Receipts {
    pub fn subscribe(bus: &Bus) -> Result<Receipts, PortError> {
        let (to_gather, arrivals) = sync_channel(TRAJ_QUEUE);
        let rejects = bus.rejects.clone();
        let learner = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        let acknowledger = Arc::new(Acknowledger::new(
            bus.session.clone(),
            bus.keys.clone(),
            learner,
        ));
        let receipts = acknowledger.clone();
        let clock = Arc::new(ReceiptClock::default());
        let times = clock.clone();
        let subscriber = bus
            .session
            .declare_subscriber(bus.keys.traj_all())
            .callback(move |sample| {
                let started = Instant::now();
                let key = sample.key_expr().as_str();
                let bytes = sample.payload().to_bytes();
                times.messages.fetch_add(1, Ordering::Relaxed);
                times.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
                let message = decode_sample::<TrajMessage>(key, &bytes, &rejects).filter(|m| {
                    check_traj(key, m)
                        .map_err(|why| rejects.refuse(key, &why))
                        .is_ok()
                });
                let sender = traj_sender(key).map(str::to_string);
                let decoded = ReceiptClock::add(&times.decode_ns, started);
                // One receipt for every segment of the message (a batch is of one incarnation).
                if let (Some(actor), Some(message)) = (&sender, &message) {
                    if let Some(first) = message.segments().first() {
                        let seqs = message.segments().iter().map(|s| s.seq).collect();
                        receipts.acknowledge(actor, first.incarnation, seqs);
                    }
                }
                let acknowledged = ReceiptClock::add(&times.ack_ns, decoded);
                // The receiver is gone only when the learner is closing.
                let _ = to_gather.send(Arrival { sender, message });
                ReceiptClock::add(&times.queue_ns, acknowledged);
            })
            .wait()
            .map_err(|e| PortError::Transport(e.to_string()))?;
        Ok(Receipts {
            _subscriber: subscriber,
            arrivals,
            clock,
            learner,
            acknowledger,
        })
    }

    /// The committed receipts of `segments` (the checkpoint holds them), one message per actor's incarnation.
    pub fn commit(&self, segments: &[SegmentId]) {
        let mut by: BTreeMap<(&str, u64), Vec<u64>> = BTreeMap::new();
        for s in segments {
            by.entry((&s.actor, s.incarnation)).or_default().push(s.seq);
        }
        for ((actor, incarnation), seqs) in by {
            self.acknowledger.commit(actor, incarnation, seqs);
        }
    }
}

/// Receipts from each actor's publisher on `ack/<actor>`, declared at its first segment: zenoh routes a declared
/// publisher's put from a cache, where a put on a key matches the key against every subscription anew (with one
/// receipt a segment, that matching was a third of the learner's CPU per step; issue 73, `cabc bench-bus`).
struct Acknowledger {
    session: Session,
    keys: Keys,
    learner: u64,
    publishers: Mutex<HashMap<String, Arc<Publisher<'static>>>>,
}

/// Actors whose receipts' publishers are held; past it they are all dropped and declared again as segments come (a
/// flood of made-up actor names costs declarations, not memory).
const ACK_PUBLISHERS: usize = 4096;

impl Acknowledger {
    fn new(session: Session, keys: Keys, learner: u64) -> Self {
        Acknowledger {
            session,
            keys,
            learner,
            publishers: Mutex::default(),
        }
    }

    /// [`acknowledge`], through `actor`'s publisher (declared now if it is not yet).
    fn acknowledge(&self, actor: &str, incarnation: u64, seqs: Vec<u64>) {
        let publisher = {
            let mut publishers = self.publishers.lock().unwrap_or_else(|e| e.into_inner());
            match publishers.get(actor) {
                Some(p) => Some(p.clone()),
                None => {
                    let declared = self
                        .session
                        .declare_publisher(self.keys.ack(actor))
                        .encoding(encoding_of::<Ack>())
                        .congestion_control(CongestionControl::Drop)
                        .priority(Priority::DataHigh)
                        .wait();
                    match declared {
                        Ok(p) => {
                            if publishers.len() >= ACK_PUBLISHERS {
                                publishers.clear();
                            }
                            let p = Arc::new(p);
                            publishers.insert(actor.to_string(), p.clone());
                            Some(p)
                        }
                        Err(e) => {
                            tracing::debug!(actor, "declaring the receipts' publisher: {e}");
                            None
                        }
                    }
                }
            }
        };
        let ack = Ack {
            incarnation,
            seqs,
            learner: self.learner,
            committed: false,
        };
        let Some(publisher) = publisher else {
            return put_ack(&self.session, &self.keys, actor, &ack);
        };
        if let Err(e) = publisher.put(codec::encode(&ack)).wait() {
            tracing::debug!(actor, seqs = ?ack.seqs, "acknowledging segments: {e}");
        }
    }

    /// The committed receipt of `actor`'s segments `seqs` of `incarnation`, reliably: put from the learner's own
    /// thread after its checkpoint (never from a zenoh callback), it waits for room rather than be dropped, as one
    /// dropped would leave the segments in the actor's outbox until another learner process takes over.
    fn commit(&self, actor: &str, incarnation: u64, seqs: Vec<u64>) {
        let ack = Ack {
            incarnation,
            seqs,
            learner: self.learner,
            committed: true,
        };
        let put = self
            .session
            .put(self.keys.ack(actor), codec::encode(&ack))
            .encoding(encoding_of::<Ack>())
            .congestion_control(CongestionControl::Block)
            .priority(Priority::DataHigh)
            .wait();
        if let Err(e) = put {
            tracing::warn!(actor, segments = ack.seqs.len(), "committing segments: {e}");
        }
    }
}

/// Puts learner `learner`'s receipt of `actor`'s segment `seq` of `incarnation`; a receipt lost under congestion or a failure costs a
/// copy of the segment later, never the segment, so it is dropped rather than waited for. It goes at a priority of its
/// own ([`Priority::DataHigh`]): this runs on the zenoh thread that reads the link, and zenoh queues a link's messages
/// per priority behind one lock, which a reliable put waiting for room (the policy, at `Data`) holds; a receipt
/// queued behind it stopped the learner reading, and through a standalone router at saturation the router and the
/// learner then waited on each other until zenoh closed the link (issue 73, `cabc bench-bus`).
pub fn acknowledge(
    session: &Session,
    keys: &Keys,
    actor: &str,
    incarnation: u64,
    seq: u64,
    learner: u64,
) {
    let ack = Ack {
        incarnation,
        seqs: vec![seq],
        learner,
        committed: false,
    };
    put_ack(session, keys, actor, &ack)
}

fn put_ack(session: &Session, keys: &Keys, actor: &str, ack: &Ack) {
    let put = session
        .put(keys.ack(actor), codec::encode(ack))
        .encoding(encoding_of::<Ack>())
        .congestion_control(CongestionControl::Drop)
        .priority(Priority::DataHigh)
        .wait();
    if let Err(e) = put {
        tracing::debug!(actor, seqs = ?ack.seqs, "acknowledging segments: {e}");
    }
}
