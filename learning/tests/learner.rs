//! The learner's state across epochs and resumes, and what it is given at construction: the count of segments not
//! stored and the early stop go with the checkpoint (a resumed learner writes the count the run had, and one that
//! had reached its early stop ends there; in a run folder and in memory), a restore refuses to resume nothing or
//! to start over a checkpoint, a segment of a version never published is refused, and the access control's refusals
//! come from the source the bus side passes in (none in process).

use cabc_learning::algorithm::{self, Ending};
use cabc_learning::checkpointer::{Checkpointer, InMemory};
use cabc_learning::learner::{AclDenials, Learner};
use cabc_learning::record::Record;
use cabc_learning::sink::{Sink, SinkError};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EndReason, EvalReport, Outcome, PolicyUpdate, Segment};
use cabc_proto::ports::{Collected, PortError, Rollouts};
use std::cell::{Cell, RefCell};
use std::collections::BTreeMap;
use std::path::Path;
use std::rc::Rc;

/// A segment of `actor-0` with one step, with an image (refused in a full-state run) or without.
fn segment(seq: u64, image: bool) -> Segment {
    let step = cabc_fixtures::step_ahead(image.then(|| cabc_fixtures::image(2, 1, 7)));
    cabc_fixtures::segment("actor-0", seq, Outcome::Lap, vec![step])
}

/// What a sink was told, in order.
#[derive(Clone, Default)]
struct Told(Rc<RefCell<Vec<String>>>);

impl Sink for Told {
    fn collected(&mut self, epoch: u64, collected: &Collected) {
        let line = format!("collected {epoch} {:?}", collected.live);
        self.0.borrow_mut().push(line);
    }

    fn write(&mut self, record: &Record) -> Result<(), SinkError> {
        self.0
            .borrow_mut()
            .push(format!("write {}", record.epoch()));
        Ok(())
    }
}

/// The smoke run's learner, its checkpoint kept in `checkpoints`, restored (fresh, or with `resume` resumed).
fn open(checkpoints: &InMemory, sink: Told, acl_denials: AclDenials, resume: bool) -> Learner {
    let config = RunConfig::load("smoke").unwrap();
    let checkpointer = Box::new(checkpoints.clone());
    let learner = Learner::new(config, Box::new(sink), checkpointer, acl_denials).unwrap();
    learner.restore(resume).unwrap()
}

/// [`open`] with the checkpoint in the run folder `dir`.
fn open_folder(dir: &Path, sink: Told, acl_denials: AclDenials, resume: bool) -> Learner {
    let config = RunConfig::load("smoke").unwrap();
    Learner::open(config, dir.into(), Box::new(sink), acl_denials, resume).unwrap()
}

/// Epoch `j` of Algorithm 1 without actors or training: pi_j is published, `segments` arrive, the collection closes
/// with `live`.
fn epoch(learner: &mut Learner, j: u64, segments: Vec<Segment>, live: &[&str]) -> Record {
    learner.begin_epoch(j);
    let _ = learner.policy_update(j);
    segments.into_iter().for_each(|s| learner.store(s));
    learner.partition(&Collected {
        live: live.iter().map(|a| a.to_string()).collect(),
        ..Collected::default()
    });
    learner.autolabel(false);
    learner.end_epoch().unwrap();
    learner.rows().last().unwrap().clone()
}

#[test]
fn segments_not_stored_survive_a_resume() {
    let dir = tempfile::tempdir().unwrap();
    let none = || -> AclDenials { Box::new(BTreeMap::new) };
    let mut learner = open_folder(dir.path(), Told::default(), none(), false);
    let first = epoch(
        &mut learner,
        0,
        vec![segment(0, true), segment(1, false)],
        &[],
    );
    assert_eq!(first.u64("segments_not_stored"), Some(1), "{first}");
    assert_eq!(first.u64("segments"), Some(1), "{first}");
    drop(learner);
    let mut learner = open_folder(dir.path(), Told::default(), none(), true);
    assert_eq!(learner.next_epoch(), 1);
    let second = epoch(&mut learner, 1, vec![segment(2, false)], &[]);
    assert_eq!(
        second.u64("segments_not_stored"),
        Some(1),
        "the resumed learner counts from the checkpoint's count: {second}"
    );
    let third = epoch(&mut learner, 2, vec![segment(3, true)], &[]);
    assert_eq!(third.u64("segments_not_stored"), Some(2), "{third}");
    let summary = learner.finish("test", true, 0).unwrap();
    assert_eq!(summary.segments_not_stored, 2);
    assert_eq!(summary.segments_stored, 2);
}

/// Issue 57: a segment tagged with a version the learner never published (a replayed policy update with its version
/// raised) is refused and counted, and its steps never reach the replay; one of the version published, or an older
/// one, is stored.
#[test]
fn a_segment_of_a_version_never_published_is_refused() {
    let checkpoints = InMemory::default();
    let mut learner = open(
        &checkpoints,
        Told::default(),
        Box::new(BTreeMap::new),
        false,
    );
    let forged = |seq: u64, version: u64| {
        let mut s = segment(seq, false);
        s.policy_version = version;
        s
    };
    let first = epoch(&mut learner, 0, vec![forged(0, 0), forged(1, 1_004)], &[]);
    assert_eq!(first.u64("segments_not_stored"), Some(1), "{first}");
    assert_eq!(first.u64("segments"), Some(1), "{first}");
    assert_eq!(first.u64("steps_collected"), Some(1), "{first}");
    let second = epoch(
        &mut learner,
        1,
        vec![forged(2, 0), forged(3, 1), forged(4, 2)],
        &[],
    );
    assert_eq!(second.u64("segments_not_stored"), Some(2), "{second}");
    assert_eq!(second.u64("segments"), Some(2), "{second}");
    // Before any version is published, no segment is believed.
    let mut fresh = open(
        &InMemory::default(),
        Told::default(),
        Box::new(BTreeMap::new),
        false,
    );
    fresh.begin_epoch(0);
    fresh.store(forged(0, 0));
    fresh.partition(&Collected::default());
    fresh.autolabel(false);
    fresh.end_epoch().unwrap();
    let row = fresh.rows().last().unwrap();
    assert_eq!(row.u64("segments_not_stored"), Some(1), "{row}");
}

#[test]
fn the_acl_source_passed_in_shows_in_the_record_and_the_summary() {
    let checkpoints = InMemory::default();
    let refused = Rc::new(Cell::new(0));
    let source = refused.clone();
    let acl_denials: AclDenials = Box::new(move || match source.get() {
        0 => BTreeMap::new(),
        n => BTreeMap::from([("actor-9: put on cabc/r/traj/actor-0".to_string(), n)]),
    });
    let told = Told::default();
    let mut learner = open(&checkpoints, told.clone(), acl_denials, false);
    let first = epoch(&mut learner, 0, vec![segment(0, false)], &["actor-0"]);
    assert_eq!(first.u64("acl_denied"), Some(0), "{first}");
    refused.set(3);
    let second = epoch(
        &mut learner,
        1,
        vec![segment(1, false)],
        &["actor-0", "actor-1"],
    );
    assert_eq!(second.u64("acl_denied"), Some(3), "{second}");
    let summary = learner.finish("test", true, 0).unwrap();
    assert_eq!(
        summary.acl_denied,
        BTreeMap::from([("actor-9: put on cabc/r/traj/actor-0".to_string(), 3)])
    );
    // The sinks given at construction hear how each collection closed before the epoch's record.
    assert_eq!(
        *told.0.borrow(),
        [
            r#"collected 0 ["actor-0"]"#,
            "write 0",
            r#"collected 1 ["actor-0", "actor-1"]"#,
            "write 1"
        ]
    );
    // In process nothing is refused.
    let mut learner = open(
        &InMemory::default(),
        Told::default(),
        Box::new(BTreeMap::new),
        false,
    );
    let row = epoch(&mut learner, 0, vec![], &[]);
    assert_eq!(row.u64("acl_denied"), Some(0));
    assert!(learner
        .finish("test", true, 0)
        .unwrap()
        .acl_denied
        .is_empty());
}

/// Actors that are never to be asked for anything.
struct Idle;

impl Rollouts for Idle {
    fn publish(&mut self, update: &PolicyUpdate) -> Result<(), PortError> {
        panic!("version {} published", update.version)
    }

    fn gather(
        &mut self,
        update: &PolicyUpdate,
        _store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError> {
        panic!("version {} collected", update.version)
    }

    fn evaluations(&mut self) -> Vec<EvalReport> {
        Vec::new()
    }

    fn stop(&mut self, _reason: &str) -> Result<(), PortError> {
        Ok(())
    }
}

/// Issue 56: the early stop is in the checkpoint. A run interrupted in the epoch whose evaluation reached it (V-C at
/// 224x224 on a GPU: the device call's budget ran out during version 63's 50-lap evaluation, and the resumed run
/// trained an epoch more and stopped at 64) ends there when resumed, with the version that stopped it.
#[test]
fn a_run_resumed_after_its_early_stop_ends_there() {
    let checkpoints = InMemory::default();
    let none = || -> AclDenials { Box::new(BTreeMap::new) };
    let mut learner = open(&checkpoints, Told::default(), none(), false);
    let rules = learner.config().collection.clone();
    let laps = vec![19.0; rules.eval_laps as usize];
    let last = u64::from(rules.early_stop_successes.max(1)) - 1;
    for j in 0..=last {
        learner.begin_epoch(j);
        let _ = learner.policy_update(j);
        learner.partition(&Collected::default());
        learner.autolabel(false);
        learner.on_eval(cabc_fixtures::eval_report(
            "eval-0",
            j,
            &laps,
            EndReason::MaxLaps,
            100,
        ));
        learner.end_epoch().unwrap();
    }
    assert_eq!(learner.early_stop(), Some(last));
    drop(learner);
    let mut resumed = open(&checkpoints, Told::default(), none(), true);
    assert_eq!(resumed.next_epoch(), last + 1);
    assert_eq!(resumed.early_stop(), Some(last), "from the checkpoint");
    assert_eq!(
        algorithm::run(&mut resumed, &mut Idle).unwrap(),
        Ending::EarlyStop(last),
        "no epoch more"
    );
}

/// A restore starts a fresh run, or with `resume` the checkpoint's, and refuses the other two cases: resuming where
/// there is no checkpoint (nothing is saved) and starting over one.
#[test]
fn a_restore_refuses_to_resume_nothing_or_to_start_over_a_checkpoint() {
    let checkpoints = InMemory::default();
    let learner = || {
        let config = RunConfig::load("smoke").unwrap();
        let checkpointer = Box::new(checkpoints.clone());
        Learner::new(
            config,
            Box::new(Told::default()),
            checkpointer,
            Box::new(BTreeMap::new),
        )
        .unwrap()
    };
    let refused = learner().restore(true).err().unwrap().to_string();
    assert!(refused.contains("no checkpoint to resume"), "{refused}");
    assert!(!checkpoints.exists());
    let mut first = learner().restore(false).unwrap();
    epoch(&mut first, 0, vec![segment(0, false)], &[]);
    drop(first);
    let refused = learner().restore(false).err().unwrap().to_string();
    assert!(refused.contains("holds a checkpoint"), "{refused}");
    assert_eq!(learner().restore(true).unwrap().next_epoch(), 1);
}
