//! What the learner refuses from the bus (issue 13, item 2): segments whose images are not of the run's observation
//! size, and evaluation reports of versions not published yet; both counted in `summary.json`.

use cabc_fixtures::step_ahead as step;
use cabc_learning::replay::{Frames, Replay, ReplayError};
use cabc_outputs::rundir::RunDir;
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{image_bytes, EndReason, Image, Outcome, Segment, Step};
use cabc_proto::ports::Collected;

fn segment(seq: u64, steps: Vec<Step>) -> Segment {
    cabc_fixtures::segment("actor-0", seq, Outcome::Lap, steps)
}

fn image(w: u16, h: u16, len: usize) -> Option<Image> {
    Some(Image {
        width: w,
        height: h,
        rgb: vec![7; len],
    })
}

#[test]
fn images_are_held_to_the_run_observation_size() {
    let mut config = RunConfig::load("smoke").unwrap();
    config.observation.kind = ObservationKind::Camera;
    config.observation.width = 16;
    config.observation.height = 16;
    let mut replay = Replay::from_config(&config);
    assert_eq!(
        Frames::of(&config),
        Frames::Rgb {
            width: 16,
            height: 16
        }
    );
    let (ok, small) = (image_bytes(16, 16), image_bytes(8, 8));
    for bad in [
        vec![step(image(16, 16, ok)), step(image(8, 8, small))],
        vec![step(image(8, 8, small))],
        vec![step(image(16, 16, ok - 1))],
        vec![step(None)],
    ] {
        let err = replay.add_segment(&segment(0, bad)).unwrap_err();
        assert!(
            matches!(
                err,
                ReplayError::ImageSize { .. } | ReplayError::ImagePresence
            ),
            "{err}"
        );
    }
    assert_eq!(replay.len_plus(), 0);
    replay
        .add_segment(&segment(0, vec![step(image(16, 16, ok)); 2]))
        .unwrap();
    assert_eq!(replay.len_plus(), 2);
    // A full-state run takes no images at all.
    let mut state = Replay::from_config(&RunConfig::load("smoke").unwrap());
    assert!(matches!(
        state.add_segment(&segment(0, vec![step(image(16, 16, ok))])),
        Err(ReplayError::ImagePresence)
    ));
}

#[test]
fn bad_segments_and_unpublished_evaluations_are_refused_and_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let config = RunConfig::load("smoke").unwrap();
    let run_dir = RunDir::create(tmp.path()).unwrap();
    let mut learner = cabc_outputs::learner(config, run_dir, false).unwrap();
    let report =
        |version| cabc_fixtures::eval_report("eval-0", version, &[], EndReason::OutOfTrack, 3);
    // Nothing published yet: no report counts.
    learner.on_eval(report(0));
    let _ = learner.policy_update(0);
    learner.on_eval(report(1));
    learner.on_eval(report(u64::MAX));
    learner.on_eval(report(0));
    assert_eq!(learner.evaluations().evals.len(), 1);
    // A state run: a segment with an image is refused before the ledger sees it (its seq stays free).
    learner.begin_epoch(0);
    learner.store(segment(0, vec![step(image(2, 1, 6))]));
    learner.store(segment(0, vec![step(None)]));
    learner.partition(&Collected::default());
    learner.autolabel(false);
    learner.end_epoch().unwrap();
    let record = learner.rows().last().unwrap();
    assert_eq!(record.u64("steps_collected"), Some(1));
    assert_eq!(record.u64("segments"), Some(1));
    assert_eq!(record.u64("segments_not_stored"), Some(1));
    let summary = learner.finish("test", true, 0).unwrap();
    assert_eq!(summary.segments_not_stored, 1, "{summary:?}");
    assert_eq!(summary.refused_evals, 3, "{summary:?}");
}
