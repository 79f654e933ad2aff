//! Epoch records and old checkpoints (issue 19): a learner state written by the code before records (rows as
//! objects of `EpochRow`'s fields, one of them from older code still, without the fields added since) loads, and
//! the `metrics.csv` and `evals.csv` it gives are the ones that code wrote, byte for byte; saved again in the new
//! format, the same; a resumed run's new metrics append columns and leave the old lines as they were.

use cabc_learning::checkpoint::{Checkpoint, CheckpointWriter};
use cabc_learning::record::Record;
use cabc_learning::state::LearnerState;
use cabc_outputs::rundir::RunDir;
use std::path::Path;

fn fixture(name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Tables of `state` as the run folder writes them: (metrics.csv, evals.csv).
fn tables(state: &LearnerState) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let run = RunDir::create(dir.path()).unwrap();
    run.write_tables(&state.rows, &state.evaluations.evals)
        .unwrap();
    let read = |name| std::fs::read_to_string(dir.path().join(name)).unwrap();
    (read("metrics.csv"), read("evals.csv"))
}

#[test]
fn an_old_checkpoint_gives_the_same_tables_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("checkpoint");
    CheckpointWriter::new(&ck)
        .file("state.json", fixture("state-2f28af3.json"))
        .commit()
        .unwrap();
    let state = LearnerState::load(&Checkpoint::open(&ck).unwrap()).unwrap();
    assert_eq!((state.next_epoch, state.rows.len()), (12, 12));
    assert_eq!(state.evaluations.successes, 1);
    let old_metrics = String::from_utf8(fixture("metrics-2f28af3.csv")).unwrap();
    let old_evals = String::from_utf8(fixture("evals-2f28af3.csv")).unwrap();
    let (metrics, evals) = tables(&state);
    assert_eq!(metrics, old_metrics);
    assert_eq!(evals, old_evals);

    // Saved again (records as lists of entries) and loaded: the same tables.
    state.save(&ck, Vec::<(&str, Vec<u8>)>::new()).unwrap();
    let again = LearnerState::load(&Checkpoint::open(&ck).unwrap()).unwrap();
    assert_eq!(again.rows, state.rows);
    assert_eq!(tables(&again), (old_metrics.clone(), old_evals));

    // The run goes on with a metric the old code did not have: a column at the end, the old lines unchanged.
    let mut resumed = again;
    let mut next = Record::new(12);
    next.real("beta", 0.25, 6).exact("lr_policy", 1e-4);
    resumed.rows.push(next);
    let (metrics, _) = tables(&resumed);
    let (old_header, old_rows) = old_metrics.split_once('\n').unwrap();
    let (header, rows) = metrics.split_once('\n').unwrap();
    assert_eq!(header, format!("{old_header},lr_policy"));
    let old_width = old_header.split(',').count();
    for (line, old) in rows.lines().zip(old_rows.lines()) {
        assert_eq!(line, format!("{old},"));
        assert_eq!(line.split(',').count(), old_width + 1);
    }
    let last = rows.lines().last().unwrap();
    assert!(last.starts_with("12,0.250000,"), "{last}");
    assert!(last.ends_with(",0.0001"), "{last}");
}

#[test]
fn a_bad_row_is_an_error_that_names_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("checkpoint");
    let state = r#"{"next_epoch":1,"rows":[{"epoch":0,"d_plus":"many"}],"evals":[],"successes":0,
        "ledger":{"duplicates":0,"seen":{},"stored_segments":0,"stored_steps":0},"expert_lap_times":[],"stopped":null}"#;
    CheckpointWriter::new(&ck)
        .file("state.json", state.as_bytes().to_vec())
        .commit()
        .unwrap();
    let err = LearnerState::load(&Checkpoint::open(&ck).unwrap()).unwrap_err();
    assert!(err.to_string().contains("d_plus"), "{err}");
}
