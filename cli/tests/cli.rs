//! `cabc`: --help and --version like the other binaries, and `cabc export`'s errors name what is wrong (a run
//! exported end to end: export/tests/export.rs and python/tests/test_export.py).

use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

/// `cabc ARGS`: whether it succeeded, its stdout and its stderr.
fn cabc<S: AsRef<OsStr>>(args: &[S]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cabc"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
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
