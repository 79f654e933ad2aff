//! The binaries start, answer --help and --version, and refuse bad configurations with a clear message.

use cabc_tests::bin;
use std::process::Command;

fn run(binary: &str, args: &[&str]) -> (bool, String) {
    let out = Command::new(bin(binary).unwrap())
        .args(args)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn every_binary_answers_help_and_version() {
    for binary in ["learner", "actor", "expert-server", "cabc-sim", "cabc"] {
        let (ok, text) = run(binary, &["--help"]);
        assert!(ok, "{binary} --help failed: {text}");
        assert!(text.contains("Usage"), "{binary} --help: {text}");
        let (ok, text) = run(binary, &["--version"]);
        assert!(ok, "{binary} --version failed: {text}");
        assert!(
            text.contains(env!("CARGO_PKG_VERSION")),
            "{binary} --version: {text}"
        );
    }
}

#[test]
fn a_bad_configuration_is_refused_with_key_and_line() {
    let dir = cabc_tests::test_dir();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, "[run]\nname = \"x\"\n\n[algorithm]\nlamda = 2.0\n").unwrap();
    let path = path.display().to_string();
    for (binary, args) in [
        ("actor", vec!["--config", path.as_str()]),
        ("expert-server", vec!["--config", path.as_str(), "serve"]),
        ("learner", vec!["prepare", "--config", path.as_str()]),
        ("cabc", vec!["show", "--config", path.as_str(), "run.name"]),
    ] {
        let (ok, text) = run(binary, &args);
        assert!(!ok, "{binary} accepted a bad configuration");
        assert!(
            text.contains("lamda") && text.contains("line 5"),
            "{binary}: {text}"
        );
    }
}

#[test]
fn an_unknown_preset_lists_the_presets() {
    let (ok, text) = run("actor", &["--config", "v-q"]);
    assert!(!ok);
    assert!(text.contains("v-b") && text.contains("smoke"), "{text}");
}
