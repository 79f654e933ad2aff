//! `cabc robust` on a run folder made by hand (the smoke configuration and an untrained policy): one seed gives one
//! report, on stdout and in OUT/robust.json, with its figure; bad input is refused with a message that names it.

use cabc_models::{Network, Policy, PolicyArch};
use cabc_proto::config::RunConfig;
use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

/// `cabc ARGS`: whether it succeeded, its stdout and its stderr.
fn cabc<S: AsRef<OsStr>>(args: &[S]) -> (bool, String, String) {
    cabc_fixtures::output(Command::new(env!("CARGO_BIN_EXE_cabc")).args(args))
}

/// A run folder with the smoke configuration and an untrained policy as its final one.
fn run_folder(dir: &Path) -> std::path::PathBuf {
    let run = dir.join("run");
    let config = RunConfig::load("smoke").unwrap();
    cabc_fixtures::run_folder(&run, &config);
    let policy = Policy::new(PolicyArch::from_config(&config), tch::Device::Cpu, 3);
    std::fs::write(run.join("final-policy.safetensors"), policy.to_bytes()).unwrap();
    run
}

#[test]
fn robust_drives_a_track_the_policy_never_saw() {
    let tmp = tempfile::tempdir().unwrap();
    let run = run_folder(tmp.path());
    let args = |track: &str| {
        vec![
            "robust".to_string(),
            run.display().to_string(),
            "--policy".into(),
            "final".into(),
            "--spawns".into(),
            "3".into(),
            "--levels".into(),
            "0".into(),
            "--laps".into(),
            "1".into(),
            "--track".into(),
            track.into(),
        ]
    };
    let (ok, stdout, stderr) = cabc(&args("oval"));
    assert!(ok, "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(summary["track"], "tracks/oval.toml, scale 1");
    let json = std::fs::read_to_string(run.join("robust-oval").join("robust.json")).unwrap();
    let full: serde_json::Value = serde_json::from_str(&json).unwrap();
    // The spawns lie on the oval (straights y = 0 and y = 3 for x in [0, 4], half circles of 1.5 m about (0, 1.5)
    // and (4, 1.5)), within half its half-width of the centre line.
    let from_centre = |x: f64, y: f64| {
        let c = if x < 0.0 { 0.0 } else { 4.0 };
        if (0.0..=4.0).contains(&x) {
            y.abs().min((y - 3.0).abs())
        } else {
            ((x - c).hypot(y - 1.5) - 1.5).abs()
        }
    };
    for p in full["spawn_points"].as_array().unwrap() {
        let (x, y) = (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap());
        assert!(from_centre(x, y) <= 0.5 * 0.55 + 1e-9, "{p}");
    }
    assert!(!run.join("robust").exists());
    // A track that is not one is refused, naming it.
    let (ok, _, stderr) = cabc(&args("monza"));
    assert!(!ok && stderr.contains("monza"), "{stderr}");
}

#[test]
fn robust_reports_a_policy_as_json_and_a_figure() {
    let tmp = tempfile::tempdir().unwrap();
    let run = run_folder(tmp.path());
    let robust = |policy: &str, out: &str| {
        let out = tmp.path().join(out);
        let (ok, stdout, stderr) = cabc(&[
            "robust".as_ref(),
            run.as_os_str(),
            "--policy".as_ref(),
            policy.as_ref(),
            "--spawns".as_ref(),
            "5".as_ref(),
            "--laps".as_ref(),
            "1".as_ref(),
            "--action-noise".as_ref(),
            "0.3,0.1".as_ref(),
            "--state-noise".as_ref(),
            "0.01".as_ref(),
            "--levels".as_ref(),
            "0,1,2".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(ok, "{stderr}");
        let json = std::fs::read_to_string(out.join("robust.json")).unwrap();
        let png = std::fs::metadata(out.join("robust.png")).unwrap().len();
        assert!(png > 5000, "robust.png is {png} bytes");
        (stdout, json)
    };
    let (stdout, json) = robust("final", "a");
    let file = run.join("final-policy.safetensors");
    let (again, json_again) = robust(file.to_str().unwrap(), "b");
    // The same seed, the same weights: the same report (the policy named by its file either way).
    assert_eq!((&stdout, &json), (&again, &json_again));
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let full: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(summary["policy"], file.display().to_string());
    assert_eq!(
        (summary["spawns"].as_u64(), summary["laps"].as_u64()),
        (Some(5), Some(1))
    );
    assert_eq!(
        summary["state_noise"],
        serde_json::json!([0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
    );
    let levels = summary["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 3);
    for (level, want) in levels.iter().zip([0.0, 1.0, 2.0]) {
        assert_eq!(level["level"].as_f64(), Some(want));
        assert_eq!(level["episodes"].as_u64(), Some(5));
        let share = level["crash_share"].as_f64().unwrap();
        let ci = level["crash_share_95"].as_array().unwrap();
        assert!(ci[0].as_f64().unwrap() <= share && share <= ci[1].as_f64().unwrap());
        assert!(level.get("outcomes").is_none());
    }
    assert_eq!(levels[2]["action_std"], serde_json::json!([0.6, 0.2]));
    // The file holds the spawns and every outcome besides.
    assert_eq!(full["spawn_points"].as_array().unwrap().len(), 5);
    assert_eq!(full["levels"][1]["outcomes"].as_array().unwrap().len(), 5);
}

#[test]
fn robust_refuses_bad_input_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let run = run_folder(tmp.path());
    let out = tmp.path().join("out");
    let refused = |args: &[&OsStr], message: &str| {
        let (ok, _, stderr) = cabc(args);
        assert!(!ok, "{args:?} succeeded");
        assert!(stderr.contains(message), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    };
    let r = |s: &'static str| -> &OsStr { s.as_ref() };
    let o = out.as_os_str();
    // The run's best policy is missing (an untrained run folder has only the final one here).
    refused(
        &[r("robust"), run.as_os_str(), r("--out"), o],
        "no policy file",
    );
    refused(
        &[
            r("robust"),
            run.as_os_str(),
            r("--policy"),
            r("nowhere.safetensors"),
            r("--out"),
            o,
        ],
        "no policy file nowhere.safetensors",
    );
    // Not a policy's weights.
    let junk = tmp.path().join("junk.safetensors");
    std::fs::write(&junk, b"not weights").unwrap();
    refused(
        &[
            r("robust"),
            run.as_os_str(),
            r("--policy"),
            junk.as_os_str(),
            r("--out"),
            o,
        ],
        "junk.safetensors",
    );
    // Bad flag values.
    let bad_flags: [(&[&str], &str); 4] = [
        (
            &["--action-noise", "-1"],
            "--action-noise: -1 is not a finite number >= 0",
        ),
        (&["--spawns", "0"], "--spawns: at least one spawn is needed"),
        (
            &["--state-noise", "0.1,0.2"],
            "--state-noise: 2 values given",
        ),
        (&["--levels", "x"], "invalid value 'x'"),
    ];
    for (flags, message) in bad_flags {
        let mut args = vec![r("robust"), run.as_os_str(), r("--policy"), r("final")];
        args.extend(flags.iter().map(|f| -> &OsStr { f.as_ref() }));
        refused(&args, message);
    }
    // Not a run folder, and a malformed configuration.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    refused(&[r("robust"), empty.as_os_str()], "is not a run folder");
    std::fs::write(run.join("config.toml"), "[run\nseed = ").unwrap();
    refused(
        &[r("robust"), run.as_os_str(), r("--policy"), r("final")],
        "is not a run folder",
    );
}
