//! `cabc export`: a hand-built camera run (laps, a failure, D-, an unfinished lap, two epochs) read back from its
//! parquet: every row, the derived episodes and policy versions, the PNG images; the run folder untouched, even its
//! image log's uncommitted tail; errors that name what is wrong.

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use cabc_export::{export, ExportError};
use cabc_learning::checkpoint::CheckpointWriter;
use cabc_learning::replay::{ImageLog, Replay};
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use std::fs::File;
use std::io::Write;
use std::path::Path;

const W: u16 = 16;
const H: u16 = 16;

/// `n` chained steps of environment `env` from state value `from` (each next state is the following step's state);
/// every image filled with its step's value.
fn steps(from: f32, n: usize) -> Vec<Step> {
    (0..n)
        .map(|k| {
            let v = from + k as f32;
            let (state, next) = (
                [v, 0.0, 0.0, v, 0.1, 0.0],
                [v + 1.0, 0.0, 0.0, v + 1.0, 0.1, 0.0],
            );
            Step {
                image: Some(cabc_fixtures::image(W, H, v as u8)),
                ..cabc_fixtures::step(state, [v, -v], [0.5 * v, 0.0], next)
            }
        })
        .collect()
}

fn segment(env: u32, seq: u64, version: u64, outcome: Outcome, steps: Vec<Step>) -> Segment {
    Segment {
        env,
        policy_version: version,
        ..cabc_fixtures::segment("actor-0", seq, outcome, steps)
    }
}

/// The run folder: epoch 0 stores env 0's two laps (chained), env 1's failure (D?, then D- after a labelling) and an
/// unfinished lap; epoch 1 env 1's lap and a failure.
fn make_run(dir: &Path) {
    let mut config = RunConfig::load("smoke-camera").unwrap();
    config.observation.kind = ObservationKind::Camera;
    config.observation.width = W;
    config.observation.height = H;
    cabc_fixtures::run_folder(dir, &config);
    let mut replay = Replay::from_config(&config);
    let fail = Outcome::Failure(EndReason::OutOfTrack);
    for s in [
        segment(0, 0, 0, Outcome::Lap, steps(10.0, 3)),
        segment(0, 1, 0, Outcome::Lap, steps(13.0, 2)),
        segment(1, 2, 0, fail, steps(50.0, 2)),
        segment(2, 3, 0, Outcome::Incomplete, steps(70.0, 2)),
    ] {
        replay.add_segment(&s).unwrap();
    }
    replay.apply_labels(&[]);
    for s in [
        segment(1, 4, 1, Outcome::Lap, steps(30.0, 2)),
        segment(1, 5, 1, fail, steps(90.0, 1)),
    ] {
        replay.add_segment(&s).unwrap();
    }
    let mut log = None;
    let bytes = replay.checkpoint_bytes(dir, &mut log).unwrap();
    CheckpointWriter::new(dir.join("checkpoint"))
        .file("replay.bin", bytes)
        .commit()
        .unwrap();
    std::fs::write(
        dir.join("metrics.csv"),
        "epoch,beta,d_plus,d_uncertain,d_minus,dynamics_only,autolabel_removed\n\
         0,1.0,5,2,2,2,0\n1,0.9,7,3,2,2,0\n",
    )
    .unwrap();
    // A live run's next checkpoint, begun and not committed: records past the committed length.
    let mut tail = std::fs::OpenOptions::new()
        .append(true)
        .open(ImageLog::path(dir, 0))
        .unwrap();
    tail.write_all(&[7u8; W as usize * H as usize * 3]).unwrap();
}

/// A (small) parquet file as one batch.
fn read(path: &Path) -> RecordBatch {
    let mut batches: Vec<RecordBatch> =
        ParquetRecordBatchReaderBuilder::try_new(File::open(path).unwrap())
            .unwrap()
            .with_batch_size(1 << 20)
            .build()
            .unwrap()
            .map(|b| b.unwrap())
            .collect();
    assert_eq!(batches.len(), 1);
    batches.remove(0)
}

fn ints(batch: &RecordBatch, name: &str) -> Vec<i64> {
    batch
        .column_by_name(name)
        .unwrap()
        .as_primitive::<Int64Type>()
        .values()
        .to_vec()
}

fn strings(batch: &RecordBatch, name: &str) -> Vec<String> {
    let column = batch.column_by_name(name).unwrap();
    column
        .as_string::<i32>()
        .iter()
        .map(|s| s.unwrap().to_string())
        .collect()
}

/// The folder's files with their sizes and contents' lengths, to see that nothing was written.
fn listing(dir: &Path) -> Vec<(String, u64)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            } else {
                let modified = e.metadata().unwrap().modified().unwrap();
                let stamp = modified
                    .duration_since(std::time::UNIX_EPOCH)
                    .unwrap()
                    .as_nanos() as u64;
                out.push((
                    e.path().display().to_string(),
                    e.metadata().unwrap().len() ^ stamp,
                ));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn a_camera_run_exports_every_step_with_its_episode_version_and_image() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    std::fs::create_dir(&run).unwrap();
    make_run(&run);
    let before = listing(&run);
    let out = tmp.path().join("dataset");
    let report = export(&run, &out).unwrap();
    assert_eq!(
        listing(&run),
        before,
        "the run folder is read, never written"
    );
    assert_eq!(
        (report.frames, report.episodes, report.data_files),
        (12, 5, 1)
    );
    assert_eq!(report.versions_known, [true, true, true]);

    let batch = read(&out.join("data/chunk-000/file-000.parquet"));
    assert_eq!(batch.num_rows(), 12);
    // D+ (env 0's two laps chained, env 1's lap), D? (D- first), dynamics-only.
    assert_eq!(
        strings(&batch, "store"),
        [
            "D+",
            "D+",
            "D+",
            "D+",
            "D+",
            "D+",
            "D+",
            "D-",
            "D-",
            "D?",
            "dynamics-only",
            "dynamics-only"
        ]
    );
    assert_eq!(
        ints(&batch, "episode_index"),
        [0, 0, 0, 0, 0, 1, 1, 2, 2, 3, 4, 4]
    );
    assert_eq!(
        ints(&batch, "frame_index"),
        [0, 1, 2, 3, 4, 0, 1, 0, 1, 0, 0, 1]
    );
    assert_eq!(
        ints(&batch, "policy_version"),
        [0, 0, 0, 0, 0, 1, 1, 0, 0, 1, 0, 0]
    );
    assert_eq!(ints(&batch, "index"), (0..12).collect::<Vec<i64>>());
    let timestamps = batch
        .column_by_name("timestamp")
        .unwrap()
        .as_primitive::<Float32Type>();
    assert_eq!(timestamps.value(4), 0.4);
    let state = batch
        .column_by_name("observation.state")
        .unwrap()
        .as_fixed_size_list();
    let first: Vec<f32> = state
        .value(5)
        .as_primitive::<Float32Type>()
        .values()
        .to_vec();
    assert_eq!(first, [30.0, 0.0, 0.0, 30.0, 0.1, 0.0]);
    let action = batch.column_by_name("action").unwrap().as_fixed_size_list();
    assert_eq!(
        action
            .value(1)
            .as_primitive::<Float32Type>()
            .values()
            .to_vec(),
        [11.0, -11.0]
    );

    // Images: in D+ rows only, PNGs of the stored pixels.
    let images = batch
        .column_by_name("observation.image")
        .unwrap()
        .as_struct();
    let bytes = images.column_by_name("bytes").unwrap().as_binary::<i32>();
    for row in 0..12 {
        assert_eq!(images.is_valid(row), row < 7, "row {row}");
    }
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes.value(3).to_vec()));
    let mut reader = decoder.read_info().unwrap();
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).unwrap();
    assert_eq!((info.width, info.height), (W as u32, H as u32));
    assert_eq!(pixels, vec![13u8; W as usize * H as usize * 3]);

    let episodes = read(&out.join("meta/episodes/chunk-000/file-000.parquet"));
    assert_eq!(ints(&episodes, "length"), [5, 2, 2, 1, 2]);
    assert_eq!(ints(&episodes, "dataset_from_index"), [0, 5, 7, 9, 10]);
    assert_eq!(ints(&episodes, "dataset_to_index"), [5, 7, 9, 10, 12]);
    assert_eq!(
        strings(&episodes, "store"),
        ["D+", "D+", "D-", "D?", "dynamics-only"]
    );
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(info["codebase_version"], "v3.0");
    assert_eq!(info["fps"], 10);
    assert_eq!(info["total_frames"], 12);
    assert_eq!(
        info["features"]["observation.image"]["shape"],
        serde_json::json!([H, W, 3])
    );
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("meta/stats.json")).unwrap()).unwrap();
    assert_eq!(stats["action"]["count"], serde_json::json!([12]));
    assert_eq!(stats["observation.state"]["min"][0], 10.0);
    assert!(out.join("meta/tasks.parquet").is_file());
}

#[test]
fn what_is_not_a_run_is_refused_with_its_reason() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let err = |run: &Path| export(run, &out).unwrap_err();
    assert!(matches!(
        err(&tmp.path().join("none")),
        ExportError::NotARun { .. }
    ));
    let run = tmp.path().join("run");
    std::fs::create_dir(&run).unwrap();
    let e = err(&run);
    assert!(
        matches!(e, ExportError::NotARun { .. }) && e.to_string().contains("config.toml"),
        "{e}"
    );
    std::fs::write(run.join("config.toml"), "[run\nname = ").unwrap();
    assert!(matches!(err(&run), ExportError::Config { .. }));
    make_run(&run);
    // No checkpoint.
    std::fs::rename(run.join("checkpoint"), tmp.path().join("aside")).unwrap();
    let e = err(&run);
    assert!(e.to_string().contains("no checkpoint"), "{e}");
    std::fs::rename(tmp.path().join("aside"), run.join("checkpoint")).unwrap();
    // An output folder with something in it.
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("x"), "").unwrap();
    assert!(matches!(err(&run), ExportError::OutExists { .. }));
    std::fs::remove_dir_all(&out).unwrap();
    // A short image log, then a corrupt replay.
    let log = ImageLog::path(&run, 0);
    let full = std::fs::read(&log).unwrap();
    std::fs::write(&log, &full[..10]).unwrap();
    let e = err(&run);
    assert!(e.to_string().contains("replay-images-0.log"), "{e}");
    std::fs::write(&log, &full).unwrap();
    let replay = run.join("checkpoint/replay.bin");
    let bytes = std::fs::read(&replay).unwrap();
    for cut in [3, 12, bytes.len() / 2] {
        std::fs::write(&replay, &bytes[..cut]).unwrap();
        let e = err(&run);
        assert!(matches!(e, ExportError::Replay { .. }), "{e}");
        assert!(!out.exists());
    }
    std::fs::write(&replay, &bytes).unwrap();
    export(&run, &out).unwrap();
}
