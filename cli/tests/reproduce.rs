//! `cabc reproduce`, the campaign's per-run step (what deploy/reproduce.sh did in bash): the runs' names, seeds and
//! arguments reach deploy/run-local.sh, an ended run is skipped, one with a checkpoint resumed, a failure or an
//! interruption fails the step, the results are copied (the small files alone, no plots or GIFs), and the group's
//! table is drawn over its own folders only. deploy/run-local.sh and the drawing `cabc compare` (--compare, not the runs' binaries: a
//! campaign's pinned ones predate a column) are fakes that record their calls.

use std::path::Path;
use std::process::{Command, Output};

fn executable(path: &Path, text: &str) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// A root whose run-local.sh records `<mode> <args> (CABC_BIN)` and writes an ended run folder (failing for a run
/// named in `FAIL`), and whose tools/cabc draws a "table" naming the folders it was given (bin/, the runs' binaries,
/// holds a cabc that fails: the drawing is --compare's).
fn setup(dir: &Path) {
    executable(
        &dir.join("deploy/run-local.sh"),
        r#"#!/usr/bin/env bash
set -eu
echo "$* ($CABC_BIN)" >> calls
name=""
for a in "$@"; do case "$a" in run.name=*) name=${a#run.name=} ;; esac; done
[ "$name" != "${FAIL:-}" ] || exit 3
mkdir -p "runs/$name/plots/sub"
echo '{"ended": "max-epochs"}' > "runs/$name/summary.json"
if [ "$name" = "${INTERRUPT:-}" ]; then
  mkdir -p "runs/$name/checkpoint"
  echo '{"ended": "interrupted"}' > "runs/$name/summary.json"
fi
echo "epoch" > "runs/$name/metrics.csv"
echo "png" > "runs/$name/plots/sub/laps.png"
echo "gif" > "runs/$name/plots/eval-v3.gif"
echo "gif" > "runs/$name/best-policy.gif"
"#,
    );
    executable(&dir.join("bin/cabc"), "#!/usr/bin/env bash\nexit 8\n");
    executable(
        &dir.join("tools/cabc"),
        "#!/usr/bin/env bash\n[ \"$1\" = compare ] && [ \"$2\" = --out ] || exit 9\nshift 3\n\
         for f in \"$@\"; do echo \"| ${f##*/} |\"; done\n",
    );
}

fn reproduce(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cabc"))
        .arg("reproduce")
        .args(["--bin", "bin", "--compare", "tools/cabc"])
        .args(args)
        .current_dir(dir)
        .envs(env.iter().copied())
        .env_remove("CABC_BIN")
        .output()
        .unwrap()
}

fn calls(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("calls"))
        .unwrap_or_default()
        .lines()
        .map(str::to_string)
        .collect()
}

#[test]
fn runs_are_named_seeded_skipped_resumed_copied_and_drawn() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    setup(dir);
    // Another group whose name starts like ours: not in our table.
    std::fs::create_dir_all(dir.join("docs/reproduction/p-t-x-s1")).unwrap();
    std::fs::write(
        dir.join("docs/reproduction/p-t-x-s1/metrics.csv"),
        "epoch\n",
    )
    .unwrap();

    let out = reproduce(
        dir,
        &[
            "--seeds",
            "2",
            "--tag",
            "t",
            "--epochs",
            "3",
            "--set",
            "a.b=\"c d\"",
            "p",
        ],
        &[],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bin = std::fs::canonicalize(dir).unwrap().join("bin");
    let tail = |name: &str, seed: u32| {
        format!(
            "--set run.seed={seed} --set run.name={name} --set run.max_epochs=3 p ({})",
            bin.display()
        )
    };
    assert_eq!(
        calls(dir),
        [
            format!("--fresh --set a.b=\"c d\" {}", tail("p-t-s1", 42)),
            format!(
                "--fresh --set a.b=\"c d\" --baseline {}",
                tail("p-t-s1-baseline", 42)
            ),
            format!("--fresh --set a.b=\"c d\" {}", tail("p-t-s2", 43)),
            format!(
                "--fresh --set a.b=\"c d\" --baseline {}",
                tail("p-t-s2-baseline", 43)
            ),
        ]
    );
    let results = dir.join("docs/reproduction");
    // The results are the small files alone: no plots/ or GIFs (issue 47; `cabc plots RUN` redraws the plots).
    for run in ["p-t-s1", "p-t-s1-baseline", "p-t-s2", "p-t-s2-baseline"] {
        let mut copied: Vec<String> = std::fs::read_dir(results.join(run))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        copied.sort();
        assert_eq!(copied, ["metrics.csv", "summary.json"], "{run}");
    }
    let table = std::fs::read_to_string(results.join("p-t-table.md")).unwrap();
    assert_eq!(
        table,
        "| p-t-s1 |\n| p-t-s1-baseline |\n| p-t-s2 |\n| p-t-s2-baseline |\n"
    );
    assert_eq!(String::from_utf8_lossy(&out.stdout), table);

    // Again: every run ended, here or only in the results (runs/ of another machine): nothing runs.
    std::fs::remove_file(dir.join("calls")).unwrap();
    std::fs::remove_dir_all(dir.join("runs/p-t-s1")).unwrap();
    let out = reproduce(dir, &["--seeds", "2", "--tag", "t", "p"], &[]);
    assert!(out.status.success());
    assert_eq!(calls(dir), Vec::<String>::new());

    // A run with a checkpoint is resumed; the proposed method alone.
    std::fs::create_dir_all(dir.join("runs/p-t-s3/checkpoint")).unwrap();
    let out = reproduce(
        dir,
        &["--seeds", "3-3", "--tag", "t", "--methods", "proposed", "p"],
        &[],
    );
    assert!(out.status.success());
    assert_eq!(calls(dir).len(), 1);
    assert!(calls(dir)[0].starts_with("--resume --set run.seed=44 --set run.name=p-t-s3 p"));

    // A failed run fails the step, before the runs after it.
    std::fs::remove_file(dir.join("calls")).unwrap();
    let out = reproduce(dir, &["--seeds", "4-5", "q"], &[("FAIL", "q-s4-baseline")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("q-s4-baseline"));
    assert_eq!(calls(dir).len(), 2);

    // A run stopped by Ctrl-C (run-local.sh exits 0, the run resumable): the step fails, so that a lane does not
    // mark its slice done, and the same call resumes it.
    std::fs::remove_file(dir.join("calls")).unwrap();
    let args = ["--seeds", "6-6", "--methods", "proposed", "u"];
    let out = reproduce(dir, &args, &[("INTERRUPT", "u-s6")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("u-s6: interrupted"));
    let out = reproduce(dir, &args, &[]);
    assert!(out.status.success());
    assert!(calls(dir)[1].starts_with("--resume --set run.seed=47 --set run.name=u-s6 u"));

    // A dry run runs and copies nothing.
    std::fs::remove_file(dir.join("calls")).unwrap();
    let out = reproduce(dir, &["--dry-run", "--seeds", "7-7", "r"], &[]);
    assert!(out.status.success());
    assert_eq!(calls(dir), Vec::<String>::new());
    assert!(!results.join("r-s7").exists());
    assert!(String::from_utf8_lossy(&out.stderr).contains("r-s7-baseline: run-local.sh --fresh"));
}

#[test]
fn bad_arguments_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    setup(tmp.path());
    for args in [
        &["--seeds", "0", "p"][..],
        &["--seeds", "2-x", "p"],
        &["--methods", "proposed other", "p"],
        &["--set", "novalue", "p"],
        &["--tag", "a b", "p"],
        &["--epochs", "0", "p"],
    ] {
        let out = reproduce(tmp.path(), args, &[]);
        assert!(!out.status.success(), "{args:?}");
    }
    assert_eq!(calls(tmp.path()), Vec::<String>::new());
}
