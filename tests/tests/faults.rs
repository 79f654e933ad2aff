//! Faults in a running distributed run (real binaries on loopback, smoke-sized): processes killed with SIGKILL and
//! started again. Each run must go on to its last epoch with every step the actors said they published for an epoch
//! stored, none twice (`metrics.csv`: `steps_collected` against `steps_published`; `summary.json`: duplicates).

use cabc_tests::{csv_column, Cluster};
use std::time::Duration;

fn wait_for_epochs(cluster: &Cluster, epochs: usize) {
    cluster.wait_for_epochs(epochs, "learner");
}

fn finish(cluster: &mut Cluster, learner: &str, epochs: u64) -> serde_json::Value {
    let summary = cluster.summary(learner);
    let metrics = cluster.dir.join("metrics.csv");
    assert_eq!(
        csv_column(&metrics, "epoch"),
        (0..epochs).collect::<Vec<_>>()
    );
    summary
}

/// After a learner restart with the actors up: no epoch stored less than the actors published, and every epoch
/// closed with both actors' markers (its full budget). Returns (stored, published) per epoch.
fn assert_nothing_lost(cluster: &Cluster) -> (Vec<u64>, Vec<u64>) {
    print!("{}", cluster.audit());
    // The actors lived through every learner: what a killed learner received and never committed they published
    // again to the resumed one, so every segment they published is stored, once.
    cluster.assert_each_step_stored_once();
    cluster.assert_nothing_lost(256)
}

#[test]
fn an_actor_and_the_expert_server_restarted_mid_run_lose_nothing() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "restart", 8, "").unwrap();
    cluster.start_all(2, false).unwrap();
    let config = cluster.config.display().to_string();
    wait_for_epochs(&cluster, 2);
    cluster.kill("actor-1").unwrap();
    cluster.kill("expert-server").unwrap();
    cluster
        .start(
            "actor-1-again",
            "actor",
            &["--config", &config, "--id", "actor-1"],
        )
        .unwrap();
    cluster
        .start(
            "expert-server-again",
            "expert-server",
            &["--config", &config, "serve", "--id", "0"],
        )
        .unwrap();
    let summary = finish(&mut cluster, "learner", 8);
    assert_eq!(summary["duplicate_segments"], 0, "{summary:#}");
    assert_eq!(summary["segments_not_stored"], 0, "{summary:#}");
    let metrics = cluster.dir.join("metrics.csv");
    let stored = csv_column(&metrics, "steps_collected");
    let published = csv_column(&metrics, "steps_published");
    // The epoch in flight at the kill may hold the killed actor's partial segments without its marker, and the next
    // one the restarted actor's first segments (it joined after that epoch was dealt, so the epoch did not wait for
    // its marker); every other epoch stores exactly what the actors published, the restarted actor's share included.
    let unequal: Vec<usize> = (0..8).filter(|&e| stored[e] != published[e]).collect();
    assert!(
        stored.iter().zip(&published).all(|(s, p)| s >= p),
        "{stored:?} vs {published:?}"
    );
    assert!(
        unequal.len() <= 1 || (unequal.len() == 2 && unequal[1] == unequal[0] + 1),
        "{stored:?} vs {published:?}"
    );
    assert_eq!(
        &csv_column(&metrics, "steps_taken")[6..],
        &[256, 256],
        "both actors publish their share at the end"
    );
    // One by one: the killed actor's segments the learner did not have are in flight at its end, nothing is lost.
    let audit = cluster.audit();
    assert_eq!(
        audit.actors.iter().filter(|a| a.ended.is_none()).count(),
        1,
        "{audit}"
    );
    println!("faults: actor-1 and expert-server killed (SIGKILL) and restarted; stored {stored:?}, published {published:?}");
    print!("{audit}");
}

/// The learner is killed with SIGKILL mid-run and resumed from its checkpoint while the actors, the evaluator and
/// the expert server stay up: the resumed learner publishes its policy until every live actor follows it, and every
/// epoch in the run's record stores what the actors published for it.
#[test]
fn the_learner_killed_and_resumed_while_actors_run_loses_nothing() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "resume", 10, "").unwrap();
    cluster.start_all(2, false).unwrap();
    wait_for_epochs(&cluster, 3);
    cluster.kill("learner").unwrap();
    let checkpointed = std::fs::read_to_string(cluster.dir.join("metrics.csv"))
        .unwrap()
        .lines()
        .count()
        - 1;
    cluster.start_learner("learner-resumed", true).unwrap();
    let summary = finish(&mut cluster, "learner-resumed", 10);
    // Copies may come (a learner killed between its checkpoint and its committed receipts: the actors publish again
    // what its checkpoint already holds); the ledger drops them, and the audit checks each segment stored once.
    let (stored, published) = assert_nothing_lost(&cluster);
    println!(
        "faults: learner killed (SIGKILL) after {checkpointed} recorded epochs and resumed with actors up; \
         stored {stored:?}, published {published:?}; {} copies dropped",
        summary["duplicate_segments"]
    );
}

/// `--resume` on a run folder without a checkpoint refuses instead of starting a fresh run.
#[test]
fn resume_without_a_checkpoint_refuses() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "nothing", 2, "").unwrap();
    cluster.start_learner("learner", true).unwrap();
    let (status, _) = cluster.wait("learner", Duration::from_secs(60)).unwrap();
    assert!(!status.success());
    let log = std::fs::read_to_string(cluster.dir.join("learner.log")).unwrap();
    assert!(log.contains("no checkpoint to resume"), "{log}");
    assert!(!cluster.dir.join("checkpoint").exists());
}

/// The learner is killed with SIGKILL five times at moments spread over its epochs (some land while it commits a
/// checkpoint: `checkpoint.tmp/` or `checkpoint.old/` is left behind) and resumed each time with the actors up: the
/// run still ends with every recorded epoch holding what the actors published for it.
#[test]
fn the_learner_killed_again_and_again_resumes_from_what_it_committed() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "kills", 14, "").unwrap();
    cluster.start_all(2, false).unwrap();
    let mut label = "learner".to_string();
    let mut during_commit = 0;
    for kill in 0..5u64 {
        wait_for_epochs(&cluster, 2 + 2 * kill as usize);
        // A delay that moves through the epoch from one kill to the next.
        std::thread::sleep(Duration::from_millis(37 * kill * kill));
        cluster.kill(&label).unwrap();
        if ["checkpoint.tmp", "checkpoint.old"]
            .iter()
            .any(|d| cluster.dir.join(d).exists())
        {
            during_commit += 1;
        }
        label = format!("learner-{kill}");
        cluster.start_learner(&label, true).unwrap();
    }
    let summary = finish(&mut cluster, &label, 14);
    // Copies may come (a kill between a checkpoint and its committed receipts); the audit checks each stored once.
    let (stored, published) = assert_nothing_lost(&cluster);
    println!(
        "faults: learner killed 5 times (SIGKILL), {during_commit} of them during a checkpoint commit; \
         stored {stored:?}, published {published:?}; {} copies dropped",
        summary["duplicate_segments"]
    );
}

/// The learner dies in the middle of a checkpoint commit, between its two renames (`CABC_FAULT` aborts it there, as
/// a SIGKILL would): no `checkpoint/` exists, only `checkpoint.old/`. `--resume` continues from that previous
/// checkpoint with the actors still up, and the run ends with nothing lost.
#[test]
fn the_learner_killed_during_a_checkpoint_resumes_from_the_previous_one() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "commit", 8, "").unwrap();
    let config = cluster.config.display().to_string();
    let run_dir = cluster.dir.display().to_string();
    let learner = ["run", "--config", &config, "--run-dir", &run_dir];
    cluster
        .start_in(
            "learner",
            &["env", "CABC_FAULT=checkpoint-between-renames:4"],
            "learner",
            &learner,
        )
        .unwrap();
    cluster
        .start(
            "expert-server",
            "expert-server",
            &["--config", &config, "serve", "--id", "0"],
        )
        .unwrap();
    for id in ["actor-0", "actor-1"] {
        cluster
            .start(id, "actor", &["--config", &config, "--id", id])
            .unwrap();
    }
    let (status, _) = cluster.wait("learner", Duration::from_secs(120)).unwrap();
    assert!(!status.success(), "the fault point aborts the learner");
    assert!(cluster
        .log_tail("learner")
        .contains("CABC_FAULT: aborting at checkpoint-between-renames"));
    assert!(
        !cluster.dir.join("checkpoint").exists(),
        "between the renames"
    );
    assert!(cluster.dir.join("checkpoint.old/state.json").exists());
    let mut resumed = learner.to_vec();
    resumed.push("--resume");
    cluster
        .start("learner-resumed", "learner", &resumed)
        .unwrap();
    let summary = finish(&mut cluster, "learner-resumed", 8);
    assert_eq!(summary["duplicate_segments"], 0, "{summary:#}");
    let (stored, published) = assert_nothing_lost(&cluster);
    assert!(
        !cluster.dir.join("checkpoint.old").exists(),
        "the next commit clears it"
    );
    println!(
        "faults: learner aborted between the renames of its 4th checkpoint, resumed from checkpoint.old; \
         stored {stored:?}, published {published:?}"
    );
}
