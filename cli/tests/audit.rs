//! `cabc audit RUN` end to end, on run folders written through the journal's own writers: exit 0 with the report
//! when every segment is accounted for, exit 1 naming the lost one when the final ledger lacks it, and an error that
//! says what is missing for a folder without a journal.

use cabc_runfolder::journal::{
    ActorEvent, ActorJournal, LearnerEvent, LearnerJournal, JOURNAL, STOPPED,
};
use std::path::Path;
use std::process::{Command, Output};

/// A run of one learner process and one actor that lived to the end: segments 0 and 1 published (9 and 7 steps),
/// received and committed; the final ledger holds `stored`.
fn run(dir: &Path, stored: &[u64]) {
    let journal = dir.join(JOURNAL);
    let learner = LearnerJournal::open(&journal).unwrap();
    learner.record(&LearnerJournal::began(7, false));
    let actor = ActorJournal::begin(&journal, "actor-0", 3).unwrap();
    for (seq, steps) in [(0, 9), (1, 7)] {
        actor.record(&ActorEvent::Published {
            seq,
            version: 0,
            steps,
        });
    }
    for committed in [false, true] {
        actor.record(&ActorEvent::Acknowledged {
            learner: 7,
            seqs: vec![0, 1],
            committed,
        });
    }
    actor.taken(20);
    actor.record(&ActorEvent::Ended {
        reason: STOPPED.into(),
    });
    learner.record(&LearnerEvent::Ended {
        reason: "max_epochs 2 reached".into(),
    });
    let steps: u64 = stored.iter().map(|&s| if s == 0 { 9 } else { 7 }).sum();
    let state = serde_json::json!({"ledger": {
        "seen": {"actor-0/3": stored}, "duplicates": 0,
        "stored_segments": stored.len(), "stored_steps": steps,
    }});
    std::fs::create_dir_all(dir.join("checkpoint")).unwrap();
    std::fs::write(dir.join("checkpoint/state.json"), state.to_string()).unwrap();
}

fn audit(dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cabc"))
        .arg("audit")
        .arg(dir)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap()
}

#[test]
fn every_segment_stored_passes_the_audit() {
    let dir = tempfile::tempdir().unwrap();
    run(dir.path(), &[0, 1]);
    let out = audit(dir.path());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout.contains("segments published: 2 (16 steps)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("every published segment accounted for"),
        "{stdout}"
    );
    // 20 steps taken, 16 published: 4 staged when the actor ended on the learner's stop.
    assert!(stdout.contains("4 staged at the run's end"), "{stdout}");
}

#[test]
fn a_segment_the_ledger_lacks_is_lost_and_fails_the_audit() {
    let dir = tempfile::tempdir().unwrap();
    run(dir.path(), &[0]);
    let out = audit(dir.path());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(stdout.contains("lost seqs [1]"), "{stdout}");
    assert!(
        stdout.contains("PROBLEM: 1 segments (7 steps) lost"),
        "{stdout}"
    );
    // The JSON names it too.
    let json = Command::new(env!("CARGO_BIN_EXE_cabc"))
        .args(["audit", "--json"])
        .arg(dir.path())
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(report["fates"]["lost"]["segments"], 1, "{report}");
}

#[test]
fn a_run_without_a_journal_is_refused_with_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let out = audit(dir.path());
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("has no journal/"), "{stderr}");
}
