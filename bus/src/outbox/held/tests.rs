use super::*;
use cabc_proto::messages::Segment;

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
