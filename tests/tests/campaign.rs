//! deploy/claim.sh, how the campaign's lanes share its slices: concurrent lanes take every slice exactly once, a
//! slice that ended is not taken again, and a claim left by a lane that died mid-slice is taken over by one lane.

use std::path::{Path, PathBuf};
use std::process::Command;

fn claim_sh() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/claim.sh")
}

/// Writes a lane, a script named campaign.sh as the real lanes are (claim.sh looks for that name), that claims
/// slices s0..s{n-1} in order, records each one it takes in `taken`, "runs" it and marks it done, unless told to die
/// there (`DIE_AT`) or to leave it undone and go on (`ABANDON`, slices between spaces), as a lane killed mid-slice
/// leaves its claim.
fn lane(dir: &Path, n: usize) -> PathBuf {
    let script = dir.join("campaign.sh");
    std::fs::write(
        &script,
        format!(
            "#!/usr/bin/env bash\nset -euo pipefail\nclaims=claims\nsource {}\n\
             for i in $(seq 0 {}); do\n  claim \"s$i\" || continue\n  echo \"s$i $$\" >> taken\n  \
             sleep 0.0$((RANDOM % 3))\n  [ \"${{DIE_AT:-}}\" = \"s$i\" ] && exit 0\n  \
             [[ \" ${{ABANDON:-}} \" == *\" s$i \"* ]] && continue\n  touch \"$(lock_of \"s$i\")/done\"\ndone\n",
            claim_sh().display(),
            n - 1
        ),
    )
    .unwrap();
    script
}

/// Runs `lanes` lanes at once in `dir`, each with its environment; returns the slices taken, in order.
fn run_lanes(dir: &Path, lanes: &[&[(&str, &str)]]) -> Vec<String> {
    let _ = std::fs::remove_file(dir.join("taken"));
    let children: Vec<_> = lanes
        .iter()
        .map(|env| {
            Command::new("bash")
                .arg("campaign.sh")
                .current_dir(dir)
                .envs(env.iter().copied())
                .spawn()
                .unwrap()
        })
        .collect();
    for mut c in children {
        assert!(c.wait().unwrap().success());
    }
    let mut taken: Vec<String> = std::fs::read_to_string(dir.join("taken"))
        .unwrap_or_default()
        .lines()
        .map(|l| l.split(' ').next().unwrap().to_string())
        .collect();
    taken.sort_by_key(|s| s[1..].parse::<u32>().unwrap());
    taken
}

#[test]
fn lanes_take_each_slice_once_and_take_over_a_dead_lanes_slice() {
    let tmp = cabc_tests::test_dir();
    let dir = tmp.path();
    lane(dir, 20);
    let all: Vec<String> = (0..20).map(|i| format!("s{i}")).collect();
    // Three lanes at once: every slice exactly once.
    assert_eq!(run_lanes(dir, &[&[], &[], &[]]), all);
    // Everything is done: a new session's lanes take nothing.
    assert!(run_lanes(dir, &[&[], &[]]).is_empty());
    // A lane dies in s25 (its claim stays, not done): the next session's lanes take s25 over, once, and nothing
    // else that ended.
    lane(dir, 30);
    let died = run_lanes(dir, &[&[("DIE_AT", "s25")]]);
    assert_eq!(died, (20..26).map(|i| format!("s{i}")).collect::<Vec<_>>());
    let resumed = run_lanes(dir, &[&[], &[], &[]]);
    assert_eq!(
        resumed,
        (25..30).map(|i| format!("s{i}")).collect::<Vec<_>>()
    );
    // Many stale claims at once, each raced for by four lanes: every one is taken over exactly once (a lane that
    // saw a claim stale must not move aside the claim that another lane has put in its place since).
    lane(dir, 60);
    let abandon: Vec<String> = (30..60).map(|i| format!("s{i}")).collect();
    let abandon = abandon.join(" ");
    assert_eq!(run_lanes(dir, &[&[("ABANDON", &abandon)]]).len(), 30);
    let lanes: &[&[(&str, &str)]] = &[&[], &[], &[], &[]];
    assert_eq!(
        run_lanes(dir, lanes),
        (30..60).map(|i| format!("s{i}")).collect::<Vec<_>>()
    );
    // Stale claims in the older format (the pid alone, in `pid`, as lanes before the token wrote them): taken over
    // exactly once too.
    let old = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "claims=claims; source {}; for i in $(seq 60 69); do d=$(lock_of s$i); mkdir -p $d; \
             echo 999999999 > $d/pid; done",
            claim_sh().display()
        ))
        .current_dir(dir)
        .status()
        .unwrap();
    assert!(old.success());
    lane(dir, 70);
    assert_eq!(
        run_lanes(dir, lanes),
        (60..70).map(|i| format!("s{i}")).collect::<Vec<_>>()
    );
}
