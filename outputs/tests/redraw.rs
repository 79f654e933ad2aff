//! `cabc plots`' library (issue 47): a run folder's plots redrawn from its small files alone (config.toml,
//! metrics.csv, evals.csv, summary.json: what docs/reproduction/<run>/ keeps) are the plots the live run drew, byte
//! for byte, valid PNGs; what is missing is said, what cannot be drawn is named, and a folder that is not a run
//! folder or a malformed table is refused with the file and line at fault.

use cabc_learning::evaluations::{EvalSummary, Taken};
use cabc_learning::record::Record;
use cabc_learning::sink::{History, Sink};
use cabc_learning::summary::{LapTime, Summary};
use cabc_outputs::plots::{LINE_PLOT, TABLE_PLOTS};
use cabc_outputs::redraw::{redraw, Kept, RedrawError};
use cabc_outputs::rundir::RunDir;
use cabc_outputs::sinks::RunFolder;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::{EndReason, EvalReport};
use std::path::Path;

fn report(version: u64, lap_times: Vec<f64>) -> EvalReport {
    EvalReport {
        line: (0..40).map(|i| [i as f32 * 0.05, 0.0]).collect(),
        spawn_episodes: 0,
        spawn_crashes: 0,
        ..cabc_fixtures::eval_report("eval", version, &lap_times, EndReason::OutOfTrack, 40)
    }
}

/// A finished run folder written by the live run's sink (its tables, plots and summary), 12 epochs with an
/// evaluation each, 3 laps to the early stop.
fn live_run(dir: &Path) {
    let mut config = RunConfig::load("smoke").unwrap();
    config.collection.eval_laps = 3;
    let run_dir = RunDir::prepare(&config, Some(dir.to_path_buf()), true).unwrap();
    let mut folder = RunFolder::new(run_dir, &config).unwrap();
    folder.open(&History::default());
    let expert = [4.8, 4.9, 4.75];
    for seconds in expert {
        folder.expert_lap(seconds);
    }
    for epoch in 0..12u64 {
        // Lap times whose mean and std are exact in evals.csv's 3 decimals (an even count alternates x and x + 0.5:
        // std 0.25), as the losses are in metrics.csv's 6: the live plots and the redrawn ones see the same numbers.
        let laps = (epoch / 3) as usize;
        let x = 5.0 + 0.25 * epoch as f64;
        let times = (0..laps)
            .map(|i| {
                x + if laps % 2 == 0 && i % 2 == 1 {
                    0.5
                } else {
                    0.0
                }
            })
            .collect();
        let evaluation = report(epoch, times);
        folder.evaluation(&Taken {
            report: &evaluation,
            summary: &EvalSummary::of(&evaluation),
            best: false,
            completed: false,
            weights: None,
        });
        let mut record = Record::new(epoch);
        record
            .real("beta", 0.5, 6)
            .real("imitation_loss", (1000 - 80 * epoch) as f64 / 1000.0, 6)
            .real("safety_loss", 0.125 * (epoch % 4) as f64, 6)
            .flag("closed_by_timeout", false);
        folder.write(&record).unwrap();
    }
    let (mean, std) = cabc_proto::stats::mean_std(&expert).unwrap();
    let summary = Summary {
        run: "redraw".into(),
        expert_lap_time: Some(LapTime {
            laps: expert.len(),
            mean,
            std,
        }),
        ..Summary::default()
    };
    folder.close(&summary, Some(b"weights")).unwrap();
}

/// Every plot of `dir` decodes as an RGB PNG of the live run's size.
fn valid_png(path: &Path) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let mut rgb = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut rgb).unwrap();
    assert_eq!(
        (info.width, info.height, info.color_type),
        (900, 500, png::ColorType::Rgb),
        "{}",
        path.display()
    );
    assert!(rgb.iter().any(|&b| b != 255), "{} is blank", path.display());
}

#[test]
fn a_kept_run_folder_gives_the_live_plots_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("runs/r-s1");
    live_run(&live);
    // The kept copy: the four small files, as the campaign copies them.
    let kept = tmp.path().join("docs/reproduction/r-s1");
    cabc_fixtures::keep(&live, &kept);
    let redrawn = redraw(&kept, None).unwrap();
    assert_eq!(
        redrawn.drawn,
        TABLE_PLOTS.map(|name| kept.join("plots").join(name))
    );
    assert!(redrawn.notes.is_empty(), "{:?}", redrawn.notes);
    for (plot, path) in TABLE_PLOTS.iter().zip(&redrawn.drawn) {
        valid_png(path);
        let drawn_live = std::fs::read(live.join("plots").join(plot)).unwrap();
        assert!(
            std::fs::read(path).unwrap() == drawn_live,
            "{plot} differs from the live run's"
        );
    }
    // The line and the videos are named with the commands that make them, and not drawn.
    assert!(!kept.join("plots").join(LINE_PLOT).exists());
    let left_out: Vec<String> = redrawn.left_out.iter().map(|l| l.to_string()).collect();
    assert!(left_out[0].starts_with("line.png") && left_out[0].contains("cabc video RUN"));
    assert!(left_out[1].contains(".gif") && left_out[1].contains("cabc show RUN --gif"));

    // Elsewhere with --out; the laps' early-stop line comes from config.toml.
    let out = tmp.path().join("elsewhere/plots");
    let redrawn = redraw(&kept, Some(&out)).unwrap();
    assert_eq!(redrawn.drawn[0], out.join("laps.png"));
    assert_eq!(Kept::read(&kept).unwrap().eval_laps, 3);
}

#[test]
fn a_run_in_progress_is_drawn_without_what_it_lacks() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("r");
    live_run(&run);
    std::fs::remove_file(run.join("summary.json")).unwrap();
    std::fs::remove_file(run.join("config.toml")).unwrap();
    let redrawn = redraw(&run, Some(&tmp.path().join("out"))).unwrap();
    for path in &redrawn.drawn {
        valid_png(path);
    }
    let notes = redrawn.notes.join("\n");
    assert!(
        notes.contains("no summary.json") && notes.contains("no expert band"),
        "{notes}"
    );
    assert!(notes.contains("at the default, 50"), "{notes}");
    // The live run's lap-time plot had the expert's band: this one does not.
    assert_ne!(
        std::fs::read(&redrawn.drawn[2]).unwrap(),
        std::fs::read(run.join("plots/lap_times.png")).unwrap()
    );
}

#[test]
fn what_is_not_a_run_folder_or_malformed_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let nowhere = tmp.path().join("nowhere");
    let message = |e: RedrawError| e.to_string();
    let e = message(redraw(&nowhere, None).unwrap_err());
    assert!(e.contains("is not a run folder (no such folder)"), "{e}");
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = message(redraw(&empty, None).unwrap_err());
    assert!(e.contains("not a run folder (no metrics.csv)"), "{e}");
    assert!(!empty.join("plots").exists(), "nothing written");

    let run = tmp.path().join("r");
    live_run(&run);
    let metrics = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let cases = [
        (
            "metrics.csv",
            format!("{metrics}12,0.5\n"),
            "metrics.csv: line 14: 2 cells",
        ),
        (
            "metrics.csv",
            "epoch,beta\n0,half\n".into(),
            "beta: \"half\" is not a number",
        ),
        (
            "evals.csv",
            "version,laps\n0\n".into(),
            "evals.csv: line 2: 1 cells",
        ),
        (
            "config.toml",
            "[collection\n".into(),
            "config.toml: not TOML",
        ),
        (
            "config.toml",
            "[collection]\neval_laps = -1\n".into(),
            "eval_laps = -1",
        ),
        ("summary.json", "{".into(), "summary.json: not JSON"),
        (
            "summary.json",
            r#"{"expert_lap_time": {"mean": 1}}"#.into(),
            "expert_lap_time.std",
        ),
    ];
    for (file, text, what) in cases {
        let kept = tmp.path().join(format!("bad-{file}"));
        cabc_fixtures::keep(&run, &kept);
        std::fs::write(kept.join(file), &text).unwrap();
        let e = message(redraw(&kept, None).unwrap_err());
        assert!(e.contains(what), "{file} {text:?}: {e}");
        std::fs::remove_dir_all(&kept).unwrap();
    }
}
