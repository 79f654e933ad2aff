//! Algorithm 1 in one process: the learner's loop over the in-process actors (`LocalActors`) and the PID expert
//! answering directly (`Relabeller`), no zenoh. Checks what each epoch did to D+, D? and D-, the policy versions
//! evaluated, and that the critic trains on D+ against D- only, whatever the schedules.

use cabc_actor::local::LocalActors;
use cabc_expert::relabel::{Expert, Relabeller};
use cabc_learning::algorithm::{self, Ending};
use cabc_learning::learner::Learner;
use cabc_learning::record::{Record, Value};
use cabc_outputs::rundir::RunDir;
use cabc_proto::config::RunConfig;

fn smoke(epochs: u64) -> RunConfig {
    let mut config = RunConfig::load("smoke").unwrap();
    config.run.max_epochs = epochs;
    config
}

fn run(config: &RunConfig, dir: &std::path::Path) -> (Learner, Ending) {
    let expert = Relabeller::new(
        Expert::Pid(config.expert.pid_target_speed),
        config.expert.max_streams,
        config.expert.max_batch,
    );
    let mut actors = LocalActors::new(config, expert, true).unwrap();
    let run_dir = RunDir::create(dir).unwrap();
    let mut learner = cabc_outputs::learner(config.clone(), run_dir, false).unwrap();
    let ending = algorithm::run(&mut learner, &mut actors).unwrap();
    (learner, ending)
}

#[test]
fn three_epochs_of_algorithm_1_in_process() {
    let tmp = cabc_tests::test_dir();
    let mut config = smoke(4);
    // The critic trains every epoch, auto-labelling only every other: between labellings D? holds points that are
    // not labelled, and the critic must not see them.
    config.training.critic_every = 1;
    config.algorithm.autolabel_every = 2;
    // New episodes every epoch (the reference's collection): their random spawns fail often enough that D? grows
    // in every epoch of these four (episodes carried on rarely fail under the PID expert at beta near 1).
    config.collection.episodes = cabc_proto::config::Episodes::Reset;
    let (learner, ending) = run(&config, tmp.path());
    assert_eq!(ending, Ending::MaxEpochs);
    let rows = learner.rows();
    // A metric of an epoch's record, by its metrics.csv name.
    let n = |r: &Record, name: &str| r.u64(name).unwrap_or_else(|| panic!("{name} in {r}"));
    assert_eq!(
        rows.iter().map(Record::epoch).collect::<Vec<_>>(),
        [0, 1, 2, 3]
    );
    for r in rows {
        // Every step collected is stored once, and the epoch's budget is spent exactly (what is not published yet
        // is staged: episodes go on across epochs).
        assert_eq!(n(r, "steps_collected"), n(r, "steps_published"), "{r}");
        assert_eq!(n(r, "steps_taken"), config.epoch_steps(r.epoch()), "{r}");
        assert_eq!(r.get("closed_by_timeout"), Some(Value::Flag(false)));
    }
    let stored: u64 = rows.iter().map(|r| n(r, "steps_collected")).sum();
    let last = rows.last().unwrap();
    assert_eq!(
        n(last, "d_plus") + n(last, "d_uncertain") + n(last, "dynamics_only"),
        stored,
        "every stored step is in D+, D? or the dynamics-only store (with the points labelled likely safe)"
    );
    // D+ fills: the PID expert drives whole laps at beta = 1.
    assert!(n(&rows[0], "d_plus") > 0, "{rows:?}");
    // D- is made by labelling (epochs 0 and 2) and held until the next one.
    for r in rows {
        let j = r.epoch() as usize;
        if j.is_multiple_of(2) {
            assert_eq!(
                n(r, "d_minus"),
                n(r, "d_uncertain"),
                "{r}: right after labelling D- is D?"
            );
        } else {
            assert_eq!(n(r, "d_minus"), n(&rows[j - 1], "d_minus"), "{r}: D- held");
        }
        // The critic's training set is D+ and D-, never the unlabelled part of D?.
        if let Some(points) = r.u64("critic_points") {
            assert_eq!(points, n(r, "d_plus") + n(r, "d_minus"), "{r}");
        }
    }
    // The case the schedules make: the critic trained while D? held points the last labelling did not see.
    assert!(
        rows.iter()
            .any(|r| r.u64("critic_points").is_some() && n(r, "d_uncertain") > n(r, "d_minus")),
        "{rows:#?}"
    );
    // Each policy version was evaluated once.
    let versions: Vec<u64> = learner
        .evaluations()
        .evals
        .iter()
        .map(|e| e.version)
        .collect();
    assert_eq!(versions, [0, 1, 2, 3]);
    assert!(tmp.path().join("checkpoint").exists());
    assert!(tmp.path().join("metrics.csv").exists());
}

/// The shield in collection (`collection.shield`, issue 45) through Algorithm 1: the learner sends f_hat and p_hat
/// with each update once the critic has trained (not before), and the epochs' records count the steps the shield
/// gave the expert: under a threshold of 0.999 almost no action is that safe, so every epoch after the critic's
/// first fit has some. Without a shield the column is absent.
#[test]
fn the_shield_travels_with_the_policy_once_the_critic_has_trained() {
    let tmp = cabc_tests::test_dir();
    let mut config = smoke(4);
    config.training.critic_every = 1;
    config.training.critic_min_uncertain = 0;
    config.collection.episodes = cabc_proto::config::Episodes::Reset;
    config.collection.shield = 0.999;
    let (mut learner, _) = run(&config, tmp.path());
    let rows = learner.rows();
    let shielded: Vec<u64> = rows
        .iter()
        .map(|r| r.u64("steps_shielded").unwrap())
        .collect();
    let trained: Vec<bool> = rows
        .iter()
        .map(|r| r.u64("critic_points").is_some())
        .collect();
    eprintln!("steps shielded per epoch {shielded:?}, critic trained {trained:?}");
    assert_eq!(shielded[0], 0, "epoch 0: no critic yet, no networks");
    let first = trained.iter().position(|&t| t).expect("the critic trains");
    assert!(
        shielded[first + 1..].iter().all(|&n| n > 0),
        "after the critic's first fit every epoch's update carries the shield: {shielded:?}"
    );
    let update = learner.policy_update(4);
    assert!(update.shield.is_some(), "the networks travel");
    let off = tmp.path().join("off");
    let (learner, _) = run(&smoke(2), &off);
    assert!(learner
        .rows()
        .iter()
        .all(|r| r.get("steps_shielded").is_none()));
}

/// Collection overlapping training (`collection.overlap`, issue 46): epoch 0 is Algorithm 1's (nothing to train on
/// before it collects), and from epoch 1 on an epoch trains before its D_new comes in, on the data of the epochs
/// before it. So epoch 1 collects with the same pi_1 as the synchronous run (the same data), trains on epoch 0's data
/// alone, and epoch 2 trains on the very rows the synchronous run's epoch 1 trained on, with the last collection as
/// the critic's held-out set.
#[test]
fn an_overlapped_epoch_trains_on_the_data_of_the_epochs_before_it() {
    let tmp = cabc_tests::test_dir();
    let mut config = smoke(3);
    config.training.critic_every = 1;
    config.training.critic_min_uncertain = 0;
    config.collection.episodes = cabc_proto::config::Episodes::Reset;
    // Enough laps for whole mini-batches of D+ from epoch 0 on.
    (
        config.collection.initial_steps,
        config.collection.steps_per_epoch,
    ) = (1024, 1024);
    let (sync, _) = run(&config, &tmp.path().join("sync"));
    config.collection.overlap = true;
    let (overlap, ending) = run(&config, &tmp.path().join("overlap"));
    assert_eq!(ending, Ending::MaxEpochs);
    let (a, b) = (sync.rows(), overlap.rows());
    let n = |r: &Record, name: &str| r.get(name).unwrap_or_else(|| panic!("{name} in {r}"));
    let collection = [
        "steps_collected",
        "segments",
        "d_plus",
        "d_uncertain",
        "d_minus",
    ];
    let training = [
        "policy_samples",
        "dynamics_samples",
        "critic_points",
        "critic_heldout_points",
    ];
    for name in collection
        .iter()
        .chain(&training[..3])
        .chain(&["imitation_loss"])
    {
        assert_eq!(n(&a[0], name), n(&b[0], name), "epoch 0, {name}");
    }
    for name in collection {
        assert_eq!(
            n(&a[1], name),
            n(&b[1], name),
            "epoch 1 collects with pi_1: {name}"
        );
    }
    let samples = |r: &Record| r.u64("policy_samples").unwrap();
    assert!(
        samples(&b[1]) < samples(&a[1]),
        "epoch 1 trains on epoch 0's data alone: {} against {}",
        samples(&b[1]),
        samples(&a[1])
    );
    for name in training {
        assert_eq!(
            n(&b[2], name),
            n(&a[1], name),
            "epoch 2 trains on what epoch 1 trained on in Algorithm 1's order: {name}"
        );
    }
    assert_ne!(n(&b[2], "imitation_loss"), n(&a[1], "imitation_loss"));
    let versions: Vec<u64> = overlap
        .evaluations()
        .evals
        .iter()
        .map(|e| e.version)
        .collect();
    assert_eq!(versions, [0, 1, 2], "each version evaluated once");
}

/// A run of the in-process actors resumed from its checkpoint stores what the resumed epochs collect: their
/// collectors start a new incarnation (the version they start with), so their segments, numbered from 0 again, are
/// not taken for the first incarnation's (issue 56: a resumed `learner run --local` dropped them all as duplicates).
#[test]
fn a_resumed_in_process_run_stores_what_it_collects() {
    let tmp = cabc_tests::test_dir();
    let config = smoke(2);
    let (first, ending) = run(&config, tmp.path());
    assert_eq!(ending, Ending::MaxEpochs);
    drop(first);
    let config = smoke(4);
    let expert = Relabeller::new(
        Expert::Pid(config.expert.pid_target_speed),
        config.expert.max_streams,
        config.expert.max_batch,
    );
    let mut actors = LocalActors::new(&config, expert, true).unwrap();
    let run_dir = RunDir::create(tmp.path()).unwrap();
    let mut learner = cabc_outputs::learner(config.clone(), run_dir, true).unwrap();
    assert_eq!(learner.next_epoch(), 2);
    let ending = algorithm::run(&mut learner, &mut actors).unwrap();
    assert_eq!(ending, Ending::MaxEpochs);
    let rows = learner.rows();
    assert_eq!(rows.len(), 4, "{rows:?}");
    for r in &rows[2..] {
        let collected = r.u64("steps_collected").unwrap();
        assert!(collected > 0, "{r}");
        assert_eq!(Some(collected), r.u64("steps_published"), "{r}");
    }
    let summary = learner.finish("max_epochs", false, 0).unwrap();
    assert_eq!(summary.duplicate_segments, 0, "{summary:?}");
}
