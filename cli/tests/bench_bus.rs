//! `cabc bench-bus` end to end: two state actors (its child process) through the learner's real intake on the
//! embedded router for about a second absorb steps, and the books balance.

use std::process::Command;

#[test]
fn bench_bus_absorbs_steps_and_loses_none() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench-bus.json");
    let output = Command::new(env!("CARGO_BIN_EXE_cabc"))
        .args(["bench-bus", "--kind", "state", "--router", "embedded"])
        .args(["--actors", "2", "--seconds", "1", "--epoch-steps", "4096"])
        .arg("--json")
        .arg(&json)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("| state | embedded | 2 |"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let m = &report["measurements"][0];
    assert!(m["steps"].as_u64().unwrap() > 0, "{m}");
    assert!(m["epochs"].as_u64().unwrap() > 0, "{m}");
    let books = &m["books"];
    assert!(books["published_segments"].as_u64().unwrap() > 0, "{books}");
    assert_eq!(
        books["published_segments"], books["stored_segments"],
        "{books}"
    );
    assert_eq!(books["published_steps"], books["stored_steps"], "{books}");
    assert_eq!(books["missing_segments"], 0, "{books}");
    assert_eq!(books["outbox_lost"], 0, "{books}");
    assert_eq!(books["not_stored"], 0, "{books}");
    assert_eq!(report["rows"][0]["lost"], 0, "{report}");
    assert!(m["broadcast"]["epochs"].as_u64().unwrap() > 0, "{m}");
}
