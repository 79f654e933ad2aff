//! The learner's side of `traj/*` (issue 64): each message is decoded and held to the key it came on as it arrives,
//! in the subscription's callback, and each segment is acknowledged at once on `ack/<actor>` ([`Ack`]: the learner
//! has it, training or not), so that the actor's outbox (`crate::outbox`) forgets it; then the message waits in a
//! queue of at most [`TRAJ_QUEUE`] for the epoch's gathering. A full queue holds the callback back, and zenoh's
//! reliable delivery the publishers, rather than dropping anything. A copy of a segment (published again because its
//! receipt was lost) is acknowledged again; the ledger drops it.

use crate::gate::EpochGate;
use crate::senders::{check_traj, traj_sender};
use crate::{decode_sample, encoding_of, Bus};
use cabc_proto::codec;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{Ack, Segment, TrajMessage};
use cabc_proto::ports::PortError;
use std::collections::BTreeMap;
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::Instant;
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
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
            Some(TrajMessage::Segment(segment)) => {
                if segment.policy_version == version {
                    *heard.entry(segment.actor.clone()).or_default() += segment.steps.len() as u64;
                }
                store(segment)
            }
            Some(TrajMessage::EpochDone(marker)) => {
                heard.entry(marker.actor.clone()).or_default();
                gate.done(marker);
            }
            None => {}
        }
    }
}

/// The learner's subscription to every actor's `traj/<actor>`: the arrivals come out of the receiver.
pub struct Receipts {
    _subscriber: Subscriber<()>,
    pub arrivals: Receiver<Arrival>,
}

impl Receipts {
    pub fn subscribe(bus: &Bus) -> Result<Receipts, PortError> {
        let (to_gather, arrivals) = sync_channel(TRAJ_QUEUE);
        let (session, keys, rejects) = (bus.session.clone(), bus.keys.clone(), bus.rejects.clone());
        let subscriber = bus
            .session
            .declare_subscriber(bus.keys.traj_all())
            .callback(move |sample| {
                let key = sample.key_expr().as_str();
                let bytes = sample.payload().to_bytes();
                let message = decode_sample::<TrajMessage>(key, &bytes, &rejects).filter(|m| {
                    check_traj(key, m)
                        .map_err(|why| rejects.refuse(key, &why))
                        .is_ok()
                });
                let sender = traj_sender(key).map(str::to_string);
                if let (Some(actor), Some(TrajMessage::Segment(segment))) = (&sender, &message) {
                    acknowledge(&session, &keys, actor, segment.incarnation, segment.seq);
                }
                // The receiver is gone only when the learner is closing.
                let _ = to_gather.send(Arrival { sender, message });
            })
            .wait()
            .map_err(|e| PortError::Transport(e.to_string()))?;
        Ok(Receipts {
            _subscriber: subscriber,
            arrivals,
        })
    }
}

/// Puts the receipt of `actor`'s segment `seq` of `incarnation`; a receipt lost under congestion or a failure costs a
/// copy of the segment later, never the segment, so it is dropped rather than waited for.
pub fn acknowledge(session: &Session, keys: &Keys, actor: &str, incarnation: u64, seq: u64) {
    let ack = Ack {
        incarnation,
        seqs: vec![seq],
    };
    let put = session
        .put(keys.ack(actor), codec::encode(&ack))
        .encoding(encoding_of::<Ack>())
        .congestion_control(CongestionControl::Drop)
        .wait();
    if let Err(e) = put {
        tracing::debug!(actor, seq, "acknowledging a segment: {e}");
    }
}
