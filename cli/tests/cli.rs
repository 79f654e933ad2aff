//! `cabc`: --help and --version like the other binaries, `cabc export`'s errors name what is wrong (a run exported
//! end to end: export/tests/export.rs and python/tests/test_export.py), and `cabc plots` on a kept run folder.

use cabc_outputs::rundir::EVALS_HEADER;
use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

/// `cabc ARGS`: whether it succeeded, its stdout and its stderr.
fn cabc<S: AsRef<OsStr>>(args: &[S]) -> (bool, String, String) {
    cabc_fixtures::output(Command::new(env!("CARGO_BIN_EXE_cabc")).args(args))
}

#[test]
fn help_and_version() {
    let (ok, text, _) = cabc(&["--help"]);
    assert!(
        ok && text.contains("Usage") && text.contains("export"),
        "{text}"
    );
    let (ok, text, _) = cabc(&["export", "--help"]);
    assert!(ok && text.contains("--out"), "{text}");
    let (ok, text, _) = cabc(&["--version"]);
    assert!(ok && text.contains(env!("CARGO_PKG_VERSION")), "{text}");
}

#[test]
fn export_refuses_what_is_not_a_run() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let nowhere = tmp.path().join("nowhere");
    let cases: [(&Path, &str); 2] = [(&nowhere, "not a run folder"), (tmp.path(), "config.toml")];
    for (run, message) in cases {
        let args = [
            OsStr::new("export"),
            run.as_os_str(),
            OsStr::new("--out"),
            out.as_os_str(),
        ];
        let (ok, stdout, stderr) = cabc(&args);
        assert!(!ok && stdout.is_empty(), "{stdout}");
        assert!(
            stderr.contains("exporting") && stderr.contains(message),
            "{stderr}"
        );
    }
    assert!(!out.exists());
}

/// A kept run folder as docs/reproduction/<run>/ holds it: config.toml, metrics.csv, evals.csv, summary.json.
fn kept_run(dir: &Path) {
    let mut config = cabc_proto::config::RunConfig::load("smoke").unwrap();
    config.collection.eval_laps = 2;
    cabc_fixtures::run_folder(dir, &config);
    let mut metrics = String::from("epoch,beta,imitation_loss,safety_loss,epoch_s\n");
    let mut evals = format!("{EVALS_HEADER}\n");
    for e in 0..6 {
        metrics.push_str(&format!(
            "{e},0.500000,{:.6},0.010000,1.000\n",
            0.5 / (e + 1) as f64
        ));
        match e {
            0..=2 => evals.push_str(&format!("{e},0,,,,,out-of-track,{}\n", 10 + e)),
            _ => evals.push_str(&format!("{e},2,5.250,0.250,5.000,5.500,max-laps,120\n")),
        }
    }
    std::fs::write(dir.join("metrics.csv"), metrics).unwrap();
    std::fs::write(dir.join("evals.csv"), evals).unwrap();
    std::fs::write(
        dir.join("summary.json"),
        r#"{"expert_lap_time": {"laps": 4, "mean": 4.8, "std": 0.05}}"#,
    )
    .unwrap();
}

/// `cabc plots RUN [--out DIR]` redraws a kept run folder's plots (PNG files, their paths on stdout), names what it
/// cannot draw with the commands that can, and refuses what is not a run folder or a malformed table with the file
/// and line (the drawing itself: outputs/tests/redraw.rs).
#[test]
fn plots_redraws_a_kept_run_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("docs/reproduction/p-s1");
    kept_run(&run);
    for (out, dir) in [
        (None, run.join("plots")),
        (Some(tmp.path().join("o")), tmp.path().join("o")),
    ] {
        let mut args = vec![OsStr::new("plots"), run.as_os_str()];
        if let Some(out) = &out {
            args.extend([OsStr::new("--out"), out.as_os_str()]);
        }
        let (ok, stdout, stderr) = cabc(&args);
        assert!(ok, "{stderr}");
        let written: Vec<&str> = stdout.lines().collect();
        let expected: Vec<String> = ["laps.png", "losses.png", "lap_times.png"]
            .iter()
            .map(|f| dir.join(f).display().to_string())
            .collect();
        assert_eq!(written, expected);
        for path in written {
            let bytes = std::fs::read(path).unwrap();
            // A PNG: its signature, then the IHDR chunk with the live plots' 900x500.
            assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{path}");
            assert_eq!(&bytes[12..16], b"IHDR", "{path}");
            assert_eq!(&bytes[16..24], [0, 0, 3, 132, 0, 0, 1, 244], "{path}");
            assert!(bytes.len() > 5000, "{path}: {} bytes", bytes.len());
        }
        assert!(
            stderr.contains("left out: line.png") && stderr.contains("cabc video RUN"),
            "{stderr}"
        );
        assert!(stderr.contains("cabc show RUN --gif"), "{stderr}");
        assert!(!stderr.contains("note:"), "{stderr}");
    }

    let nowhere = tmp.path().join("nowhere");
    let (ok, stdout, stderr) = cabc(&[OsStr::new("plots"), nowhere.as_os_str()]);
    assert!(!ok && stdout.is_empty(), "{stdout}");
    assert!(
        stderr.contains("redrawing the plots of") && stderr.contains("is not a run folder"),
        "{stderr}"
    );
    std::fs::write(run.join("metrics.csv"), "epoch,imitation_loss\n0,0.5,1\n").unwrap();
    let (ok, _, stderr) = cabc(&[OsStr::new("plots"), run.as_os_str()]);
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("metrics.csv: line 2: 3 cells, the header has 2 columns"),
        "{stderr}"
    );
}
