//! The binaries start, answer --help and --version, and refuse bad configurations with a clear message.

use cabc_proto::config::ActorsSection;
use cabc_tests::bin;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
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

/// `command` pinned to the first CPU (what a scheduler's affinity or a cgroup's quota gives a process).
fn on_one_core(command: &mut Command) -> &mut Command {
    // SAFETY: sched_setaffinity(2) on the child itself, before exec; it touches only the set on this stack.
    unsafe {
        command.pre_exec(|| {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(0, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}

/// Issue 75: the default's `actors.count = "auto"` is resolved by the process that reads it to the cores it may run
/// on (one when its affinity gives it one), and the run folder's config.toml holds that number, which a reader with
/// other cores keeps.
#[test]
fn the_defaults_auto_count_follows_the_cores_and_the_run_folder_keeps_it() {
    let dir = cabc_tests::test_dir();
    let runs = dir.path().display().to_string();
    let prepare = |name: &str, one_core: bool| -> PathBuf {
        let mut command = Command::new(bin("learner").unwrap());
        command.args(["prepare", "--set", &format!("run.name={name}"), "--set"]);
        command.arg(format!("run.runs_dir={runs}"));
        if one_core {
            on_one_core(&mut command);
        }
        let out = command.output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
    };
    let count_in = |folder: &PathBuf| -> u32 {
        let config = std::fs::read_to_string(folder.join("config.toml")).unwrap();
        let line = config.lines().find(|l| l.starts_with("count = ")).unwrap();
        line["count = ".len()..].parse().unwrap()
    };
    let cores = std::thread::available_parallelism().unwrap().get();
    let here = prepare("auto-here", false);
    assert_eq!(count_in(&here), ActorsSection::auto_count(cores, 8, false));
    let pinned = prepare("auto-one-core", true);
    assert_eq!(count_in(&pinned), 1);
    // The folder's number, read on one core: kept.
    let config = here.join("config.toml").display().to_string();
    let out = on_one_core(Command::new(bin("cabc").unwrap()).args([
        "show",
        "--config",
        &config,
        "actors.count",
    ]))
    .output()
    .unwrap();
    assert!(out.status.success());
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        count_in(&here).to_string()
    );
}
