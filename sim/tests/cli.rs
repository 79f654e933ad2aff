//! The `cabc-sim` binary: help, rollout JSON, bad input.
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_cabc-sim"))
}

#[test]
fn help_lists_subcommands() {
    let out = bin().arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for sub in ["rollout", "render", "track", "bench"] {
        assert!(text.contains(sub), "{text}");
    }
}

#[test]
fn rollout_json() {
    let dir = std::env::temp_dir().join(format!("cabc_sim_cli_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let trace = dir.join("trace.csv");
    let out = bin()
        .args([
            "rollout", "--policy", "pid", "--spawn", "fixed", "--seed", "1", "--steps", "200",
            "--json", "--trace",
        ])
        .arg(&trace)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["steps"], 200);
    assert_eq!(v["laps"], 1);
    assert!(v["truncation"].is_null());
    assert!(v["max_abs_x_tran"].as_f64().unwrap() < 0.2);
    let csv = std::fs::read_to_string(&trace).unwrap();
    assert_eq!(csv.lines().count(), 202); // header + reset row + 200 steps
    let png = dir.join("map.png");
    let out = bin()
        .args(["track", "--out"])
        .arg(&png)
        .arg("--trace")
        .arg(&trace)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(dir);

    let out = bin()
        .args([
            "rollout",
            "--policy",
            "const:-2,0",
            "--steps",
            "50",
            "--json",
        ])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["truncation"], "Stall");
    assert_eq!(v["truncation_step"], 2);
}

#[test]
fn bad_input_is_a_clear_error_not_a_panic() {
    for args in [
        vec!["rollout", "--policy", "bogus"],
        vec!["rollout", "--policy", "const:1"],
        vec!["render", "--size", "10by10", "--out", "/tmp/x.png"],
        vec!["render", "--sun", "a,b", "--out", "/tmp/x.png"],
        vec![
            "track",
            "--out",
            "/tmp/cabc_sim_x.png",
            "--trace",
            "/nonexistent/trace.csv",
        ],
    ] {
        let out = bin().args(&args).output().unwrap();
        assert!(!out.status.success(), "{args:?} should fail");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(
            err.contains("Error") || err.contains("error"),
            "{args:?}: {err}"
        );
    }
}
