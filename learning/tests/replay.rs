//! Replay: partition by outcome, random eviction, images, auto-labelling removal and D-, bytes round trip.

use cabc_fixtures::image;
use cabc_learning::replay::{Replay, ReplayError};
use cabc_proto::messages::{EndReason, Image, Outcome, Segment, Step};

fn step(v: f32, ok: bool, image: Option<Image>) -> Step {
    let (state, next) = ([v, 0.0, 0.0, v, 0.0, 0.0], [v + 1.0, 0.0, 0.0, v, 0.0, 0.0]);
    Step {
        image,
        expert_ok: ok,
        ..cabc_fixtures::step(state, [v, -v], [0.5 * v, 0.0], next)
    }
}

fn segment(outcome: Outcome, steps: Vec<Step>) -> Segment {
    Segment::of("a", outcome, steps)
}

#[test]
fn segments_are_partitioned_by_outcome() {
    let mut r = Replay::new(100, 0);
    let c = r
        .add_segment(&segment(
            Outcome::Lap,
            vec![step(1.0, true, None), step(2.0, false, None)],
        ))
        .unwrap();
    assert_eq!((c.plus, c.uncertain, c.dynamics_only), (1, 1, 0));
    r.add_segment(&segment(
        Outcome::Failure(EndReason::OutOfTrack),
        vec![step(3.0, true, None); 3],
    ))
    .unwrap();
    r.add_segment(&segment(
        Outcome::ExpertFailure,
        vec![step(4.0, false, None)],
    ))
    .unwrap();
    r.add_segment(&segment(
        Outcome::Incomplete,
        vec![step(5.0, true, None); 2],
    ))
    .unwrap();
    assert_eq!(
        (r.len_plus(), r.len_uncertain(), r.len_dynamics_only()),
        (1, 5, 2)
    );
    assert_eq!(r.plus.expert_actions[0], [1.0, -1.0]);
    assert_eq!(r.uncertain.states[0][0], 2.0);
    // Auto-labelling removal: D? entries move to the dynamics-only store; what D? then holds is D-.
    assert_eq!(r.len_minus(), 0, "no D- before the first labelling");
    r.apply_labels(&[0, 2]);
    assert_eq!(r.len_uncertain(), 3);
    assert_eq!(r.len_dynamics_only(), 4);
    let left: Vec<f32> = r.uncertain.states.iter().map(|s| s[0]).collect();
    assert_eq!(left, vec![3.0, 3.0, 4.0]);
    assert_eq!(r.minus(), r.uncertain.states.as_slice());
    // D? points that arrive later stay out of D- until the next labelling.
    r.add_segment(&segment(
        Outcome::Failure(EndReason::Spin),
        vec![step(6.0, true, None)],
    ))
    .unwrap();
    assert_eq!((r.len_uncertain(), r.len_minus()), (4, 3));
    r.apply_labels(&[]);
    assert_eq!(r.len_minus(), 4);
}

#[test]
fn random_eviction_keeps_capacity_and_mixes_ages() {
    let run = |seed| {
        let mut r = Replay::new(100, seed);
        for k in 0..10 {
            let steps = (0..100)
                .map(|i| step((k * 100 + i) as f32, true, None))
                .collect();
            r.add_segment(&segment(Outcome::Lap, steps)).unwrap();
        }
        r
    };
    let r = run(7);
    assert_eq!(r.len_plus(), 100);
    assert_eq!(r.added.plus, 1000);
    let ages: Vec<f32> = r.plus.states.iter().map(|s| s[0]).collect();
    // Random eviction: old entries survive with some probability, the newest batch is mostly present.
    assert!(ages.iter().any(|&a| a < 700.0), "{ages:?}");
    assert!(ages.iter().filter(|&&a| a >= 900.0).count() > 40);
    assert_eq!(run(7).plus, r.plus, "seeded eviction is reproducible");
    assert_ne!(run(8).plus, r.plus);
}

#[test]
fn images_are_stored_contiguously_and_checked() {
    let mut r = Replay::new(10, 0);
    let steps = (0..3)
        .map(|i| step(i as f32, true, Some(image(4, 2, i as u8))))
        .collect();
    r.add_segment(&segment(Outcome::Lap, steps)).unwrap();
    let images = r.plus.images.as_ref().unwrap();
    assert_eq!(images.bytes.len(), 3 * 24);
    assert_eq!(images.get(2), &[2u8; 24][..]);
    let bad = r.add_segment(&segment(
        Outcome::Lap,
        vec![step(0.0, true, Some(image(2, 2, 0)))],
    ));
    assert!(matches!(bad, Err(ReplayError::ImageSize { .. })));
    let mut short = image(4, 2, 0);
    short.rgb.pop();
    let short = r.add_segment(&segment(Outcome::Lap, vec![step(0.0, true, Some(short))]));
    assert!(matches!(
        short,
        Err(ReplayError::ImageSize { bytes: 23, .. })
    ));
    let none = r.add_segment(&segment(Outcome::Lap, vec![step(0.0, true, None)]));
    assert!(matches!(none, Err(ReplayError::ImagePresence)));
    assert_eq!(r.len_plus(), 3, "a refused segment stores nothing");
}

#[test]
fn bytes_round_trip() {
    let mut r = Replay::new(50, 3);
    for k in 0..4 {
        let steps = (0..30)
            .map(|i| step((k * 30 + i) as f32, true, Some(image(3, 3, i as u8))))
            .collect();
        r.add_segment(&segment(Outcome::Lap, steps)).unwrap();
        let steps = (0..20)
            .map(|i| step(-(i as f32), true, Some(image(3, 3, 1))))
            .collect();
        r.add_segment(&segment(Outcome::Failure(EndReason::Spin), steps))
            .unwrap();
    }
    r.apply_labels(&[1, 5]);
    let tmp = tempfile::tempdir().unwrap();
    let mut log = None;
    let bytes = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    let (mut back, _) = Replay::from_checkpoint(&bytes, tmp.path()).unwrap();
    assert_eq!(back.plus, r.plus);
    assert!(r.uncertain.images.is_none(), "only D+ keeps images");
    assert_eq!(back.uncertain, r.uncertain);
    assert_eq!(back.dynamics_only, r.dynamics_only);
    assert_eq!(back.minus(), r.minus());
    assert_eq!(back.len_minus(), 48, "D? is full (50) before two leave");
    assert_eq!(back.added, r.added);
    // The eviction RNG continues where it was.
    let more = segment(
        Outcome::Lap,
        (0..30)
            .map(|i| step(1000.0 + i as f32, true, Some(image(3, 3, 9))))
            .collect(),
    );
    r.add_segment(&more).unwrap();
    back.add_segment(&more).unwrap();
    assert_eq!(back.plus, r.plus);
    // Not a replay file, a truncated one, another version.
    assert!(matches!(
        Replay::from_bytes(b"garbage!garbage"),
        Err(ReplayError::BadMagic)
    ));
    let bytes = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert!(matches!(
        Replay::from_bytes(&bytes[..bytes.len() / 2]),
        Err(ReplayError::Decode(_))
    ));
    let mut v9 = bytes.clone();
    v9[8..12].copy_from_slice(&9u32.to_le_bytes());
    assert!(matches!(
        Replay::from_bytes(&v9),
        Err(ReplayError::Version { found: 9, .. })
    ));
}

/// The image log: a checkpoint writes only the images new since the last one; a resume restores exactly what the
/// last committed checkpoint stored (what a checkpoint appended without committing is cut off); evictions are
/// compacted into a new generation, the old one removed.
#[test]
fn checkpoints_write_only_new_images_and_resume_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let len = 4 * 4 * 3;
    let lap = |k: u32, n: u32| {
        segment(
            Outcome::Lap,
            (0..n)
                .map(|i| {
                    step(
                        (k * 1000 + i) as f32,
                        true,
                        Some(image(4, 4, (k * 7 + i) as u8)),
                    )
                })
                .collect(),
        )
    };
    let log_len = |generation| {
        std::fs::metadata(tmp.path().join(format!("replay-images-{generation}.log")))
            .map_or(0, |m| m.len())
    };
    // D+ holds 130 steps: exactly the first three laps below, then evictions.
    let mut r = Replay::with_capacities(130, 100, 5);
    let mut log = None;
    r.add_segment(&lap(0, 60)).unwrap();
    let first = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert_eq!(log_len(0), 60 * len as u64);
    // Nothing new: nothing written.
    r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert_eq!(log_len(0), 60 * len as u64);
    // 30 new steps: 30 more records, not 90.
    r.add_segment(&lap(1, 30)).unwrap();
    let second = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert_eq!(log_len(0), 90 * len as u64);
    let stored = r.clone();
    // A checkpoint that appends and then never commits (a crash before its rename): resuming from the second
    // checkpoint restores exactly what it stored and cuts the log back.
    r.add_segment(&lap(2, 40)).unwrap();
    r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert_eq!(log_len(0), 130 * len as u64);
    drop(log);
    let (back, mut log) = Replay::from_checkpoint(&second, tmp.path()).unwrap();
    assert_eq!(back.plus, stored.plus);
    assert_eq!(back.plus.images, stored.plus.images);
    assert_eq!(back.added, stored.added);
    assert_eq!(log_len(0), 90 * len as u64);
    // The first checkpoint still reads back too (its records were never overwritten).
    let (older, _) = Replay::from_checkpoint(&first, tmp.path()).unwrap();
    assert_eq!(older.len_plus(), 60);
    assert_eq!(older.plus.images.as_ref().unwrap().get(59), &[59u8; 48][..]);
    // Evictions leave dead records until the log is compacted into generation 1.
    let mut r = back;
    for k in 3..40 {
        r.add_segment(&lap(k, 50)).unwrap();
        r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    }
    let generation = log.as_ref().unwrap().generation();
    assert!(generation >= 1, "no compaction");
    log.as_ref().unwrap().prune().unwrap();
    assert_eq!(
        log_len(0),
        0,
        "the old generation is removed after the commit"
    );
    let bytes = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    let (back, _) = Replay::from_checkpoint(&bytes, tmp.path()).unwrap();
    assert_eq!(back.plus, r.plus);
}

/// `replay.max_bytes`: D+ holds what fits beside the other stores and evicts beyond it, so the replay never holds
/// more than its budget; a budget too small for one batch is refused with the key at fault.
#[test]
fn a_replay_over_its_byte_budget_evicts_and_a_tiny_budget_is_refused() {
    use cabc_proto::config::{ObservationKind, RunConfig, REPLAY_STEP_BYTES};
    let mut config = RunConfig::load("smoke").unwrap();
    config.observation.kind = ObservationKind::Camera;
    (config.observation.width, config.observation.height) = (16, 16);
    config.replay.capacity = 1000;
    let reserve = 2 * 1000 * REPLAY_STEP_BYTES + 1000 * 24;
    let per_step = REPLAY_STEP_BYTES + 16 * 16 * 3;
    config.replay.max_bytes = reserve + 150 * per_step;
    config.validate("test").unwrap();
    assert_eq!(config.plus_capacity(), 150);
    let mut r = Replay::from_config(&config);
    for k in 0..5 {
        let steps = (0..100)
            .map(|i| step((k * 100 + i) as f32, true, Some(image(16, 16, i as u8))))
            .collect();
        r.add_segment(&segment(Outcome::Lap, steps)).unwrap();
        let failed = (0..100)
            .map(|i| step(i as f32, true, Some(image(16, 16, 1))))
            .collect();
        r.add_segment(&segment(Outcome::Failure(EndReason::Spin), failed))
            .unwrap();
    }
    assert_eq!(r.len_plus(), 150, "D+ evicts at its budgeted capacity");
    assert_eq!(r.added.plus, 500);
    assert!(r.uncertain.images.is_none(), "D? keeps no images");
    assert!(
        r.bytes() as u64 <= config.replay.max_bytes,
        "{} bytes",
        r.bytes()
    );
    config.replay.max_bytes = reserve + 10 * per_step;
    let e = config.validate("test").unwrap_err().to_string();
    assert!(
        e.contains("replay.max_bytes") && e.contains("at least"),
        "{e}"
    );
}

/// Issue 18 (4): without a dynamics-only store (the reference) unfinished laps are dropped and the points
/// auto-labelling removes are deleted.
#[test]
fn without_a_dynamics_only_store_nothing_is_kept_for_f_hat_alone() {
    let mut r = Replay::new(100, 0).with_dynamics_only(false);
    let c = r
        .add_segment(&segment(
            Outcome::Incomplete,
            vec![step(5.0, true, None); 2],
        ))
        .unwrap();
    assert_eq!((c.plus, c.uncertain, c.dynamics_only), (0, 0, 0));
    r.add_segment(&segment(
        Outcome::Failure(EndReason::OutOfTrack),
        vec![step(3.0, true, None), step(4.0, true, None)],
    ))
    .unwrap();
    r.apply_labels(&[0]);
    assert_eq!(
        (r.len_uncertain(), r.len_minus(), r.len_dynamics_only()),
        (1, 1, 0)
    );
    assert_eq!(r.uncertain.states[0][0], 4.0);
}

/// A camera policy that clones D? too (`training.clone_uncertain`): D? keeps its images within the byte budget
/// (D+ gives up the room), auto-labelling keeps each image with its step (the points it moves to the dynamics-only
/// store leave theirs behind), and D+'s and D?'s images share the image log: checkpointed, compacted, resumed.
#[test]
fn d_uncertain_keeps_its_images_for_a_camera_policy_that_clones_it() {
    use cabc_proto::config::{ObservationKind, RunConfig, REPLAY_STEP_BYTES};
    let mut config = RunConfig::load("smoke").unwrap();
    config.observation.kind = ObservationKind::Camera;
    (config.observation.width, config.observation.height) = (16, 16);
    config.training.clone_uncertain = true;
    config.replay.capacity = 100;
    let len = 16 * 16 * 3;
    let reserve = 2 * 100 * REPLAY_STEP_BYTES + 100 * 24 + 100 * len as u64;
    config.replay.max_bytes = reserve + 100 * (REPLAY_STEP_BYTES + len as u64);
    config.validate("test").unwrap();
    assert_eq!(config.plus_capacity(), 100, "D?'s images set aside");
    config.replay.max_bytes -= 50 * (REPLAY_STEP_BYTES + len as u64);
    assert_eq!(config.plus_capacity(), 50);
    let mut r = Replay::from_config(&config);
    // Step v carries an image filled with v % 256: D+ gets laps, D? failures.
    let run = |outcome: Outcome, from: u32, n: u32| {
        let steps = (from..from + n)
            .map(|v| step(v as f32, true, Some(image(16, 16, v as u8))))
            .collect();
        segment(outcome, steps)
    };
    let failure = || Outcome::Failure(EndReason::OutOfTrack);
    r.add_segment(&run(Outcome::Lap, 0, 30)).unwrap();
    r.add_segment(&run(failure(), 100, 40)).unwrap();
    let images = r.uncertain.images.as_ref().expect("D? keeps images");
    assert!(images.get(7).iter().all(|&b| b == 107));
    // Auto-labelling removes D? entries 0-9: each remaining image stays with its step.
    r.apply_labels(&(0..10).collect::<Vec<_>>());
    assert_eq!(r.len_uncertain(), 30);
    let images = r.uncertain.images.as_ref().unwrap();
    for (i, s) in r.uncertain.states.iter().enumerate() {
        assert_eq!(images.get(i)[0], s[0] as u8, "entry {i}");
    }
    assert_eq!(r.len_dynamics_only(), 10);
    assert!(r.dynamics_only.images.is_none(), "no images for f_hat");
    // One log for both stores.
    let tmp = tempfile::tempdir().unwrap();
    let log_len = || {
        std::fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().metadata().unwrap().len())
            .sum::<u64>()
    };
    let mut log = None;
    let bytes = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    assert_eq!(log_len(), (30 + 30) * len as u64);
    let (back, _) = Replay::from_checkpoint(&bytes, tmp.path()).unwrap();
    assert_eq!(back.uncertain, r.uncertain);
    assert_eq!(back.plus, r.plus);
    // Evictions in both stores until the log is compacted; the compacted log reads back both.
    for k in 0..30 {
        r.add_segment(&run(Outcome::Lap, 1000 + 60 * k, 30))
            .unwrap();
        r.add_segment(&run(failure(), 1030 + 60 * k, 30)).unwrap();
        r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    }
    assert_eq!((r.len_plus(), r.len_uncertain()), (50, 100));
    let log = log.unwrap();
    assert!(log.generation() >= 1, "no compaction");
    log.prune().unwrap();
    let mut log = Some(log);
    let bytes = r.checkpoint_bytes(tmp.path(), &mut log).unwrap();
    let (back, _) = Replay::from_checkpoint(&bytes, tmp.path()).unwrap();
    assert_eq!(back.plus, r.plus);
    assert_eq!(back.uncertain, r.uncertain);
    let images = back.uncertain.images.as_ref().unwrap();
    for (i, s) in back.uncertain.states.iter().enumerate() {
        assert_eq!(images.get(i)[0], s[0] as u32 as u8, "entry {i}");
    }
    assert!(
        r.bytes() as u64 <= config.replay.max_bytes,
        "{} bytes",
        r.bytes()
    );
}
