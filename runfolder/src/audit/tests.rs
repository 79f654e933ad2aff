//! The audit on run folders written by hand through the journal's own writers.

use super::*;
use crate::journal::{ActorJournal, LearnerJournal};

fn published(journal: &ActorJournal, seq: u64, steps: u64) {
    journal.record(&ActorEvent::Published {
        seq,
        version: 0,
        steps,
    });
}

fn receipt(journal: &ActorJournal, learner: u64, seqs: &[u64], committed: bool) {
    journal.record(&ActorEvent::Acknowledged {
        learner,
        seqs: seqs.to_vec(),
        committed,
    });
}

/// A run of two learner processes (1 killed, 2 resumed) and three actor processes, with the final ledger
/// holding `stored` ("actor/incarnation" -> seqs) and counting `steps` stored.
fn run(stored: &[(&str, &[u64])], steps: u64) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let journal = dir.path().join(journal::JOURNAL);
    let learner = LearnerJournal::open(&journal).unwrap();
    learner.record(&LearnerJournal::began(1, false));
    learner.record(&LearnerJournal::began(2, true));
    learner.record(&LearnerEvent::Refused {
        actor: "actor-0".into(),
        incarnation: 10,
        seq: 3,
        why: "a policy version this learner has not published".into(),
    });
    learner.record(&LearnerEvent::Ended {
        reason: "max_epochs".into(),
    });
    // actor-0 lived to the end: seq 0 and 1 stored, 2 received by the killed learner and published again to
    // the resumed one (stored), 3 refused.
    let a = ActorJournal::begin(&journal, "actor-0", 10).unwrap();
    for seq in 0..4 {
        published(&a, seq, 10);
    }
    receipt(&a, 1, &[0, 1, 2], false);
    receipt(&a, 1, &[0, 1], true);
    receipt(&a, 2, &[2, 3], false);
    a.taken(45);
    a.record(&ActorEvent::Ended {
        reason: journal::STOPPED.into(),
    });
    // actor-1, killed: seq 0 stored, 1 received by the killed learner only, 2 never received.
    let b = ActorJournal::begin(&journal, "actor-1", 20).unwrap();
    for seq in 0..3 {
        published(&b, seq, 5);
    }
    receipt(&b, 1, &[0, 1], false);
    receipt(&b, 1, &[0], true);
    b.taken(19);
    let mut seen = serde_json::Map::new();
    let mut count = 0;
    for (key, seqs) in stored {
        count += seqs.len();
        seen.insert(key.to_string(), serde_json::json!(seqs));
    }
    let state = serde_json::json!({"ledger": {
        "seen": seen, "duplicates": 1, "stored_segments": count, "stored_steps": steps,
    }});
    std::fs::create_dir_all(dir.path().join(CHECKPOINT)).unwrap();
    std::fs::write(
        dir.path().join(CHECKPOINT).join("state.json"),
        state.to_string(),
    )
    .unwrap();
    dir
}

#[test]
fn each_published_segment_gets_its_fate() {
    let dir = run(&[("actor-0/10", &[0, 1, 2]), ("actor-1/20", &[0])], 35);
    let audit = Audit::of(dir.path()).unwrap();
    assert!(audit.ok(), "{audit}");
    let c = |fate| audit.count(fate);
    assert_eq!(
        c(Fate::Stored),
        Count {
            segments: 4,
            steps: 35
        }
    );
    assert_eq!(
        c(Fate::Refused),
        Count {
            segments: 1,
            steps: 10
        }
    );
    assert_eq!(c(Fate::HeldByALearnerThatStopped).segments, 1);
    assert_eq!(c(Fate::InFlightAtItsActorsEnd).segments, 1);
    assert_eq!(c(Fate::Lost).segments, 0);
    assert_eq!(
        audit.published(),
        Count {
            segments: 7,
            steps: 55
        }
    );
    // actor-0 took 45 and published 40: 5 staged at its end; actor-1 took 19, published 15: 4 in flight.
    assert_eq!(audit.never_published(), (5, 4));
}

#[test]
fn a_segment_missing_from_the_ledger_is_lost_and_fails_the_audit() {
    // actor-0's seq 2 went again to the resumed learner, which received it and never stored it: lost.
    let dir = run(&[("actor-0/10", &[0, 1]), ("actor-1/20", &[0])], 25);
    let audit = Audit::of(dir.path()).unwrap();
    assert!(!audit.ok());
    assert_eq!(audit.count(Fate::Lost).segments, 1);
    let actor = audit.actors.iter().find(|a| a.actor == "actor-0").unwrap();
    assert_eq!(actor.lost, [2]);
    assert!(audit
        .to_string()
        .contains("PROBLEM: 1 segments (10 steps) lost"));
}

#[test]
fn a_ledger_that_counts_other_steps_than_the_journals_fails_the_audit() {
    let dir = run(&[("actor-0/10", &[0, 1, 2]), ("actor-1/20", &[0])], 45);
    let audit = Audit::of(dir.path()).unwrap();
    assert!(!audit.ok());
    assert!(
        audit
            .problems
            .iter()
            .any(|p| p.contains("45 steps stored, the journals 35")),
        "{audit}"
    );
}
