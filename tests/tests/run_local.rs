//! `deploy/run-local.sh`, the README's first command, on the release binaries (`CABC_BIN`: nothing is built): it
//! trains a run to its summary with every process's log in the run folder and says its wall clock (with no expert
//! server when the actors solve their own relabellings), and a bus endpoint that another run already holds stops it
//! before any of its processes starts. On a terminal it draws the learner's progress bar instead of its log lines,
//! which go to the log file all the same; not on a terminal, the lines as the log.

use std::net::TcpListener;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The arguments of `bash deploy/run-local.sh smoke ARGS` for a run named `name` in `runs` on loopback port `port`.
fn run_local_args(runs: &Path, name: &str, port: u16, args: &[&str]) -> Vec<String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/run-local.sh");
    let endpoint = format!("[\"tcp/127.0.0.1:{port}\"]");
    let mut all = vec![script.display().to_string()];
    for set in [
        format!("bus.listen={endpoint}"),
        format!("bus.connect={endpoint}"),
        format!("run.runs_dir={:?}", runs.display().to_string()),
        format!("run.name=\"{name}\""),
        "training.device=\"cpu\"".to_string(),
    ] {
        all.extend(["--set".to_string(), set]);
    }
    all.push("smoke".into());
    all.extend(args.iter().map(|a| a.to_string()));
    all
}

/// `deploy/run-local.sh smoke ARGS` for a run named `name` in `runs` on loopback port `port`, to its end (at most
/// 300 s).
fn run_local(runs: &Path, name: &str, port: u16, args: &[&str]) -> Output {
    let mut command = Command::new("bash");
    command
        .args(run_local_args(runs, name, port, args))
        .env("CABC_BIN", cabc_tests::bin_dir())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    wait(command)
}

/// Runs `command` to its end (at most 300 s).
fn wait(mut command: Command) -> Output {
    let mut child = command.spawn().expect("bash deploy/run-local.sh");
    let start = Instant::now();
    while child
        .try_wait()
        .expect("waiting for run-local.sh")
        .is_none()
    {
        if start.elapsed() > Duration::from_secs(300) {
            let _ = child.kill();
            panic!("run-local.sh ran past 300 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().expect("run-local.sh's output")
}

#[test]
fn run_local_trains_a_run_to_its_summary() {
    let tmp = cabc_tests::test_dir();
    let out = run_local(
        tmp.path(),
        "local",
        cabc_tests::free_port(),
        &["--set", "run.max_epochs=2"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let run = tmp.path().join("local");
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["epochs"], 2, "{summary:#}");
    // What the networks trained on and in (issue 56): CI has no GPU, and bf16 applies on CUDA alone.
    let (device, precision) = (&summary["device"], &summary["precision"]);
    assert!(
        device == "cpu" || device.as_str().is_some_and(|d| d.starts_with("cuda:")),
        "{summary:#}"
    );
    if device == "cpu" {
        assert_eq!(precision, "fp32", "{summary:#}");
    }
    // Not a terminal: the learner's lines as its log (issue 59 item 4).
    assert!(stderr.contains("epoch done: epoch=1"), "{stderr}");
    // The run's wall clock, said when it ends (issue 46: the figure a user compares).
    let end = stderr
        .lines()
        .find(|l| l.contains("learner finished"))
        .unwrap_or_else(|| panic!("no end line: {stderr}"));
    assert!(
        end.contains("(exit 0) after ") && end.contains(" min ") && end.contains(" s; summary: "),
        "{end}"
    );
    // The smoke preset: two actors, one evaluator, one expert server, each with its log.
    for log in ["learner", "expert-server-0", "actor-0", "actor-1", "eval"] {
        let path = run.join("logs").join(format!("{log}.log"));
        assert!(path.exists(), "{} missing; {stderr}", path.display());
    }
}

/// Under `expert.placement = "in-actor"` (issue 46) the script starts no expert server: the actors solve their own
/// relabellings, and the run trains to its summary all the same.
#[test]
fn run_local_starts_no_expert_server_for_actors_that_solve_their_own() {
    let tmp = cabc_tests::test_dir();
    let placement = "expert.placement=\"in-actor\"";
    let args = ["--set", "run.max_epochs=2", "--set", placement];
    let out = run_local(tmp.path(), "in-actor", cabc_tests::free_port(), &args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let run = tmp.path().join("in-actor");
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["epochs"], 2, "{summary:#}");
    for log in ["learner", "actor-0", "actor-1", "eval"] {
        assert!(
            run.join("logs").join(format!("{log}.log")).exists(),
            "{log}: {stderr}"
        );
    }
    assert!(!run.join("logs/expert-server-0.log").exists(), "{stderr}");
}

#[test]
fn run_local_refuses_a_bus_endpoint_another_run_holds() {
    let tmp = cabc_tests::test_dir();
    let held = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = held.local_addr().unwrap().port();
    let out = run_local(tmp.path(), "second", port, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("127.0.0.1:{port} (bus.listen) is in use")),
        "{stderr}"
    );
    // Refused before any process started: no process's log, and no checkpoint.
    let run = tmp.path().join("second");
    let logs: Vec<_> = std::fs::read_dir(run.join("logs"))
        .map(|d| d.map(|e| e.unwrap().file_name()).collect())
        .unwrap_or_default();
    assert!(logs.is_empty(), "{logs:?}");
    assert!(!run.join("checkpoint").exists());
}

#[test]
fn run_local_stops_when_the_learner_ends_before_its_bus_opens() {
    let tmp = cabc_tests::test_dir();
    // An argument the learner refuses: it exits (2) at once.
    let out = run_local(
        tmp.path(),
        "refused",
        cabc_tests::free_port(),
        &["--", "--no-such-flag"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("learner ended (exit 2) before its bus opened"),
        "{stderr}"
    );
    let logs = tmp.path().join("refused").join("logs");
    assert!(logs.join("learner.log").exists());
    assert!(!logs.join("actor-0.log").exists(), "no actor started");
}

/// `arg` quoted for a shell.
fn sh(arg: &str) -> String {
    format!("'{}'", arg.replace('\'', "'\\''"))
}

/// Issue 59 item 4: on a terminal (a pseudo-terminal from `script`, util-linux) the main job draws the learner's
/// progress bar (the epoch of the budget, the time per epoch) instead of its log lines, and the learner's log file
/// keeps every line; `--verbose` brings the lines back to the terminal.
#[test]
fn run_local_on_a_terminal_draws_a_progress_bar_and_keeps_the_log() {
    let tmp = cabc_tests::test_dir();
    for (name, verbose) in [("terminal", false), ("verbose", true)] {
        let mut args = vec!["--set", "run.max_epochs=3"];
        if verbose {
            args.push("--verbose");
        }
        let line = run_local_args(tmp.path(), name, cabc_tests::free_port(), &args)
            .iter()
            .map(|a| sh(a))
            .collect::<Vec<_>>()
            .join(" ");
        let mut command = Command::new("script");
        command
            .args(["-qefc", &format!("bash {line}"), "/dev/null"])
            .env("CABC_BIN", cabc_tests::bin_dir())
            .env_remove("RUST_LOG")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let out = wait(command);
        let terminal = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{terminal}");
        let log = std::fs::read_to_string(tmp.path().join(name).join("logs/learner.log")).unwrap();
        for epoch in 0..3 {
            let done = format!("epoch done: epoch={epoch} ");
            assert!(
                log.contains(&done),
                "{name}: the log file keeps every line: {log}"
            );
            assert_eq!(terminal.contains(&done), verbose, "{name}: {terminal}");
        }
        if !verbose {
            assert!(
                terminal.contains("/3 "),
                "the epoch of the budget: {terminal}"
            );
            assert!(terminal.contains(" s/epoch"), "{terminal}");
        }
        assert!(terminal.contains("learner finished (exit 0)"), "{terminal}");
    }
}
