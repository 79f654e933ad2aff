//! `cabc campaign`: lanes share a plan's slices (concurrent lanes run every slice exactly once, a slice that ended is
//! not run again, a claim left by a lane that died mid-slice is taken over by one lane; what tests/tests/campaign.rs
//! checked of deploy/claim.sh), each slice reaches the runner with the bash campaign's arguments, and `list`, `status`
//! and `tables` on a plan. The runner is a fake deploy/reproduce.sh that records its calls.

use cabc_campaign::claims::Claims;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn cabc(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cabc"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// A root with a plan of `n` slices (`--seeds k-k p`, k = 1..n), a bin folder with a `learner`, and a runner that
/// records each call (`s<k> <its parent, the lane> <the bus's listen setting>` in `taken`), sleeps a little, and
/// dies with its lane at slice `DIE_AT` (killing it, as a lane killed mid-slice leaves its claim) or fails at the
/// slices of `ABANDON` (between spaces; the lane goes on).
fn setup(dir: &Path, n: usize) {
    let seeds: Vec<String> = (1..=n).map(|k| k.to_string()).collect();
    std::fs::write(
        dir.join("plan.toml"),
        format!(
            "[[block]]\nseeds = [{}]\nslices = [{{ preset = \"p\" }}]\n",
            seeds.join(", ")
        ),
    )
    .unwrap();
    std::fs::create_dir_all(dir.join("bin")).unwrap();
    executable(&dir.join("bin/learner"), "#!/bin/sh\n");
    executable(
        &dir.join("runner.sh"),
        "#!/usr/bin/env bash\nset -eu\nk=s${6%-*}\necho \"$k $PPID $2\" >> taken\nsleep 0.0$((RANDOM % 3))\n\
         if [ \"${DIE_AT:-}\" = \"$k\" ]; then kill -9 $PPID; exit 0; fi\n\
         if [[ \" ${ABANDON:-} \" == *\" $k \"* ]]; then exit 1; fi\n",
    );
}

fn executable(path: &Path, text: &str) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::write(path, text).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// Runs lanes at once in `dir` (lane i of max(2, lanes): a single lane claims too), each with its environment;
/// returns the slices taken, in order. Checks that each call ran on its lane's port.
fn run_lanes(dir: &Path, lanes: &[&[(&str, &str)]]) -> Vec<String> {
    let _ = std::fs::remove_file(dir.join("taken"));
    let count = lanes.len().max(2);
    let children: Vec<_> = lanes
        .iter()
        .enumerate()
        .map(|(i, env)| {
            let lane = format!("{i}/{count}");
            let args = [
                "campaign",
                "run",
                "--plan",
                "plan.toml",
                "--lane",
                &lane,
                "--bin",
                "bin",
                "--runner",
                "runner.sh",
            ];
            Command::new(env!("CARGO_BIN_EXE_cabc"))
                .args(args)
                .current_dir(dir)
                .envs(env.iter().copied())
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    let ports: HashMap<String, usize> = children
        .iter()
        .enumerate()
        .map(|(i, c)| (c.id().to_string(), 7447 + i))
        .collect();
    for (mut c, env) in children.into_iter().zip(lanes) {
        let status = c.wait().unwrap();
        // A lane fails when a slice failed, and dies with DIE_AT.
        assert!(status.success() || !env.is_empty(), "{status}");
    }
    let mut taken = vec![];
    for line in std::fs::read_to_string(dir.join("taken"))
        .unwrap_or_default()
        .lines()
    {
        let [slice, pid, listen] = line.split(' ').collect::<Vec<_>>()[..] else {
            panic!("{line}")
        };
        assert_eq!(
            listen,
            format!("bus.listen=[\"tcp/127.0.0.1:{}\"]", ports[pid]),
            "{line}"
        );
        taken.push(slice.to_string());
    }
    taken.sort_by_key(|s| s[1..].parse::<u32>().unwrap());
    taken
}

fn slices(range: std::ops::Range<usize>) -> Vec<String> {
    range.map(|k| format!("s{k}")).collect()
}

#[test]
fn lanes_take_each_slice_once_and_take_over_a_dead_lanes_slice() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    setup(dir, 20);
    // Three lanes at once: every slice exactly once.
    assert_eq!(run_lanes(dir, &[&[], &[], &[]]), slices(1..21));
    // Everything is done: a new session's lanes take nothing.
    assert!(run_lanes(dir, &[&[], &[]]).is_empty());
    // A lane dies in s25 (its claim stays, not done): the next session's lanes take s25 over, once, and nothing
    // else that ended.
    setup(dir, 30);
    assert_eq!(run_lanes(dir, &[&[("DIE_AT", "s25")]]), slices(21..26));
    assert_eq!(run_lanes(dir, &[&[], &[], &[]]), slices(25..31));
    // Many stale claims at once, each raced for by four lanes: every one is taken over exactly once (a lane that
    // saw a claim stale must not move aside the claim that another lane has put in its place since).
    setup(dir, 60);
    let abandon = slices(31..61).join(" ");
    assert_eq!(run_lanes(dir, &[&[("ABANDON", &abandon)]]).len(), 30);
    let lanes: &[&[(&str, &str)]] = &[&[], &[], &[], &[]];
    assert_eq!(run_lanes(dir, lanes), slices(31..61));
    // Stale claims in the older format of the bash lanes (the pid alone, in `pid`): taken over exactly once too.
    let claims = Claims::new(dir.join("runs/campaign-claims"));
    for k in 61..71 {
        let lock = claims.lock_of(&format!("--seeds {k}-{k} p"));
        std::fs::create_dir_all(&lock).unwrap();
        std::fs::write(lock.join("pid"), "999999999\n").unwrap();
    }
    setup(dir, 70);
    assert_eq!(run_lanes(dir, lanes), slices(61..71));
    // A claim of a live bash lane (its command line names campaign.sh) is left alone; a done one too.
    let live = Command::new("bash")
        .args(["-c", "sleep 30; true", "campaign.sh"])
        .spawn()
        .unwrap();
    let lock = claims.lock_of("--seeds 71-71 p");
    std::fs::create_dir_all(&lock).unwrap();
    std::fs::write(
        lock.join("owner"),
        format!("{} {}-1-2\n", live.id(), live.id()),
    )
    .unwrap();
    setup(dir, 72);
    assert_eq!(run_lanes(dir, &[&[], &[]]), ["s72"]);
    let mut live = live;
    live.kill().unwrap();
    live.wait().unwrap();
    assert_eq!(run_lanes(dir, &[&[], &[]]), ["s71"]);
}

/// One lane claims nothing and runs every slice; `--only N` runs slice N alone, `--only N,M` those two. The runner gets the bus's settings
/// and the slice's words as bash's eval made them (quotes removed), CABC_BIN, and the root as its directory; the
/// lane's log has the slices and the runner's output.
#[test]
fn a_lane_passes_the_slices_arguments() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    setup(dir, 1);
    std::fs::write(
        dir.join("plan.toml"),
        "[keys]\nclip = ['training.clip_scope=\"policy\"', 'n=[0.3,0.05]']\n[[block]]\nseeds = [3, 1]\nepochs = 200\n\
         slices = [{ preset = \"v-b-ref\", methods = [\"proposed\"], tag = \"abl-clip\", keys = [\"clip\"] }]\n",
    )
    .unwrap();
    executable(
        &dir.join("runner.sh"),
        "#!/usr/bin/env bash\nprintf '%s\\n' \"$PWD\" \"$CABC_BIN\" \"$@\" >> calls\necho runner output\n",
    );
    let run = |extra: &[&str]| {
        let mut args = vec![
            "campaign",
            "run",
            "--plan",
            "plan.toml",
            "--bin",
            "bin",
            "--runner",
            "runner.sh",
        ];
        args.extend(extra);
        let out = cabc(dir, &args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::read_to_string(dir.join("calls")).unwrap()
    };
    let root = std::fs::canonicalize(dir).unwrap().display().to_string();
    let call = |k: u32| {
        format!(
            "{root}\n{root}/bin\n--set\nbus.listen=[\"tcp/127.0.0.1:7449\"]\n--set\nbus.connect=[\"tcp/127.0.0.1:7449\"]\n\
             --seeds\n{k}-{k}\n--epochs\n200\n--methods\nproposed\n--tag\nabl-clip\n--set\ntraining.clip_scope=policy\n\
             --set\nn=[0.3,0.05]\nv-b-ref\n"
        )
    };
    assert_eq!(run(&["--lane", "2/3", "--only", "1"]), call(1));
    std::fs::remove_file(dir.join("calls")).unwrap();
    // Several, in the plan's order whatever the order given.
    assert_eq!(run(&["--lane", "2/3", "--only", "1,0"]), call(3) + &call(1));
    std::fs::remove_file(dir.join("calls")).unwrap();
    // One lane: everything, unclaimed (a second time too), on port 7447.
    for _ in 0..2 {
        let calls = run(&[]);
        let port = |c: String| c.replace("7449", "7447");
        assert_eq!(calls, port(call(3)) + &port(call(1)));
        std::fs::remove_file(dir.join("calls")).unwrap();
    }
    assert!(!dir.join("runs/campaign-claims").exists());
    let log = std::fs::read_to_string(dir.join("runs/campaign.log")).unwrap();
    assert!(log.contains("lane 0/1, port 7447"), "{log}");
    assert!(
        log.contains(
            "slice 1: --seeds 1-1 --epochs 200 --methods proposed --tag abl-clip --set \
         training.clip_scope=\"policy\" --set n=[0.3,0.05] v-b-ref\nrunner output\n"
        ),
        "{log}"
    );
    assert!(std::fs::read_to_string(dir.join("runs/campaign-lane2.log"))
        .unwrap()
        .contains("lane 2/3, port 7449"));
    // No binaries, a slice out of the plan, a bad lane: refused with the reason.
    for (args, why) in [
        (vec!["--bin", "nothing"], "no pinned binaries"),
        (
            vec!["--bin", "bin", "--only", "0,2"],
            "the plan has slices 0 to 1",
        ),
        (vec!["--bin", "bin", "--lane", "2/2"], "I < N"),
    ] {
        let mut all = vec![
            "campaign",
            "run",
            "--plan",
            "plan.toml",
            "--runner",
            "runner.sh",
        ];
        all.extend(args);
        let out = cabc(dir, &all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(why), "{all:?}: {err}");
    }
}

/// `list` and `status` of the repository's own plans (the list as the bash campaign printed it).
#[test]
fn list_and_status_of_the_plans() {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let out = cabc(&root, &["campaign", "list", "--plan", "issue-18"]);
    let fixture =
        std::fs::read_to_string(root.join("campaign/tests/fixtures/issue-18.list")).unwrap();
    assert_eq!(String::from_utf8(out.stdout).unwrap(), fixture);
    // Issue 18's campaign ended: every run has its results in docs/reproduction/ (and runs/ does not change that).
    let out = cabc(&root, &["campaign", "status", "--plan", "issue-18"]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.ends_with("runs: 71 ended, 0 in progress, 0 not started\n"),
        "{text}"
    );
    assert!(
        text.starts_with("slice 0: --seeds 1-1 --epochs 200 v-b-ref\n  v-b-ref-s1: ended, "),
        "{text}"
    );
    let out = cabc(&root, &["campaign", "list", "--plan", "nothing"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("deploy/campaign/nothing.toml"));
}

/// `tables`: each group with a table redrawn from its run folders, each view with --by-group, and the view's rows
/// put between its markers in docs/REPRODUCTION.md.
#[test]
fn tables_redraw_groups_and_views() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let out = dir.join("docs/reproduction");
    for run in ["g-s1", "g-s1-baseline", "g-s2", "h-s1", "h-x-s1"] {
        std::fs::create_dir_all(out.join(run)).unwrap();
        std::fs::write(out.join(run).join("metrics.csv"), "").unwrap();
    }
    std::fs::write(out.join("g-table.md"), "old").unwrap();
    std::fs::create_dir_all(dir.join("deploy/campaign")).unwrap();
    std::fs::write(
        dir.join("deploy/campaign/a.toml"),
        "[[view]]\nname = \"gh-view\"\ngroups = [\"h\", \"g\"]\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("docs/REPRODUCTION.md"),
        "text\n<!-- gh-view-table: refreshed -->\n| old |\n<!-- end gh-view-table -->\nmore\n",
    )
    .unwrap();
    executable(
        &dir.join("compare.sh"),
        "#!/bin/sh\necho \"A table of:\"\necho \"| $* |\"\n",
    );
    let o = cabc(dir, &["campaign", "tables", "--compare", "./compare.sh"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read_to_string(out.join("g-table.md")).unwrap(),
        "A table of:\n| --out docs/reproduction/g docs/reproduction/g-s1 docs/reproduction/g-s1-baseline \
         docs/reproduction/g-s2 |\n"
    );
    let view = "| --by-group --out docs/reproduction/gh-view docs/reproduction/h-s1 docs/reproduction/g-s1 \
                docs/reproduction/g-s1-baseline docs/reproduction/g-s2 |";
    assert_eq!(
        std::fs::read_to_string(out.join("gh-view-table.md")).unwrap(),
        format!("A table of:\n{view}\n")
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("docs/REPRODUCTION.md")).unwrap(),
        format!(
            "text\n<!-- gh-view-table: refreshed -->\n{view}\n<!-- end gh-view-table -->\nmore\n"
        )
    );
    assert!(!out.join("h-table.md").exists());
}
