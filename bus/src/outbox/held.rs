//! The segments an actor's outbox holds until the learner has them (`super`'s doc): by seq, each with the message it
//! went in (a batch's segments share one), and which learner process received it.

use super::MAX_OUTBOX_BYTES;
use bytes::Bytes;
use cabc_proto::codec;
use cabc_proto::messages::{Ack, TrajMessage};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// The segments of one incarnation not committed yet, by seq.
#[derive(Default)]
pub(super) struct Held {
    pub(super) incarnation: Option<u64>,
    pub(super) segments: BTreeMap<u64, Unacked>,
    pub(super) bytes: usize,
    /// The learner process whose receipts came last.
    pub(super) learner: Option<u64>,
}

pub(super) struct Unacked {
    /// The message it went in (shared by the segments of one batch).
    pub(super) encoded: Bytes,
    /// The segments of that message.
    pub(super) batch: usize,
    /// Its part of the message's bytes (what the outbox's bound counts).
    pub(super) share: usize,
    pub(super) sent: Instant,
    /// Published before the router was lost (in flight then, or dropped), or received by a learner process that is
    /// gone: it goes out again before the next marker.
    pub(super) stranded: bool,
    /// The learner process that received it (its receipt on arrival), until it commits it: not published again
    /// unless another learner process takes over.
    pub(super) received_by: Option<u64>,
}

impl Held {
    /// Holds the segments `seqs` of `incarnation`, published together as `encoded`; returns the seqs dropped to
    /// keep the outbox within its bound.
    pub(super) fn hold(&mut self, incarnation: u64, seqs: &[u64], encoded: Bytes) -> Vec<u64> {
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
    pub(super) fn acknowledged(&mut self, ack: &Ack) {
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
    pub(super) fn due(&mut self, all: bool, after: Duration) -> Vec<Bytes> {
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
    pub(super) fn strand(&mut self) {
        for unacked in self.segments.values_mut() {
            unacked.stranded |= unacked.received_by.is_none();
        }
    }

    /// The stranded segments, in order, to publish again before a marker: the marker must not reach the learner
    /// before them, or the epoch closes without them (they would land in the next epoch's data).
    pub(super) fn stranded(&mut self) -> Vec<Bytes> {
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

#[cfg(test)]
mod tests;
