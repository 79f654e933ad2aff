//! `cabc campaign run`: one lane of a campaign, running its slices one after the other, each as one call of the
//! per-run step, `cabc reproduce` ([`crate::reproduce`]: skips an ended run, resumes one with a checkpoint, starts
//! any other fresh, and copies its results to docs/reproduction/).
//!
//! Lane I of N listens on its own loopback port, 7447 + I (`--set bus.listen=["tcp/127.0.0.1:<port>"]` and
//! `bus.connect`, before the slice's own arguments: a run's numbers do not depend on its port), and with N > 1 takes
//! the next slice that no other lane has claimed ([`crate::claims`]), so that the lanes stay busy until the last
//! slice; a slice that ended well is marked done, one that failed keeps its claim until its lane ends (a later
//! session's lane takes it over). With one lane, or `--only`, nothing is claimed; `--only 17,41` runs those slices
//! alone, in the plan's order (a second lane given what the first will not reach soon). The runs use the binaries of
//! `CABC_BIN` (the pinned ones, `.deps/campaign-bin/current`). Logs: the lane's own in `runs/campaign.log` (one lane)
//! or `runs/campaign-lane<I>.log`, with the per-run step's output; each run's in `runs/<run>/logs/`.

use crate::claims::{Claims, CLAIMS_DIR};
use crate::plan::Plan;
use anyhow::{bail, Context, Result};
use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{SystemTime, UNIX_EPOCH};

/// The first lane's loopback port; lane I listens on `BASE_PORT + I`.
pub const BASE_PORT: u16 = 7447;

/// A lane: I of N.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Lane {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Lane {
    type Err = String;

    /// `I/N` with I < N.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("--lane needs I/N with I < N, not {s:?}");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (u32, u32) =
            (i.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
        if index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

/// What a lane runs, and with what.
#[derive(Debug, Clone)]
pub struct LaneOptions {
    /// The repository's root: the runner runs there, `runs/` is there.
    pub root: PathBuf,
    pub lane: Lane,
    /// Runs these slices alone (their indices in the plan), in the plan's order, without claiming them; empty: all.
    pub only: Vec<usize>,
    /// The binaries of the runs (`CABC_BIN`): must hold `learner`.
    pub bin: PathBuf,
    /// The per-run step, its program and first arguments, called with the bus's settings and a slice's arguments:
    /// `cabc reproduce` ([`crate::reproduce`]).
    pub runner: Vec<std::ffi::OsString>,
}

/// The time as `date -u +%FT%TZ` prints it.
pub fn utc_now() -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (days, rest) = ((secs / 86_400) as i64, secs % 86_400);
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rest / 3600,
        rest / 60 % 60,
        rest % 60
    )
}

/// Runs a lane over the plan; the number of slices that failed (each one is reported and the lane goes on).
pub fn run_lane(plan: &Plan, opts: &LaneOptions) -> Result<usize> {
    let learner = opts.bin.join("learner");
    if !is_executable(&learner) {
        bail!(
            "[campaign] no pinned binaries ({} is missing): run deploy/campaign.sh --pin first",
            learner.display()
        );
    }
    if let Some(only) = opts.only.iter().find(|&&i| i >= plan.slices.len()) {
        bail!(
            "--only {only}: the plan has slices 0 to {}",
            plan.slices.len().saturating_sub(1)
        );
    }
    let Lane { index, count } = opts.lane;
    let port = BASE_PORT + index as u16;
    let bus = [
        "--set".to_string(),
        format!("bus.listen=[\"tcp/127.0.0.1:{port}\"]"),
        "--set".to_string(),
        format!("bus.connect=[\"tcp/127.0.0.1:{port}\"]"),
    ];
    let runs = opts.root.join("runs");
    std::fs::create_dir_all(&runs)?;
    let log_path = match count {
        1 => runs.join("campaign.log"),
        _ => runs.join(format!("campaign-lane{index}.log")),
    };
    let log = || {
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .with_context(|| format!("opening {}", log_path.display()))
    };
    let bin = std::fs::canonicalize(&opts.bin).unwrap_or(opts.bin.clone());
    writeln!(
        log()?,
        "[campaign] {} binaries {}, lane {index}/{count}, port {port}",
        utc_now(),
        bin.display()
    )?;
    let say = |line: String| -> Result<()> {
        eprintln!("{line}");
        writeln!(log()?, "{line}")?;
        Ok(())
    };
    let claims = Claims::new(opts.root.join(CLAIMS_DIR));
    let mut failed = 0;
    for (i, slice) in plan.slices.iter().enumerate() {
        let text = slice.text();
        let claim = if !opts.only.is_empty() {
            if !opts.only.contains(&i) {
                continue;
            }
            None
        } else if count > 1 {
            match claims.claim(&text).context("claiming a slice")? {
                Some(claim) => Some(claim),
                None => continue,
            }
        } else {
            None
        };
        say(format!("[campaign] {} slice {i}: {text}", utc_now()))?;
        let out = log()?;
        let (program, first) = opts.runner.split_first().context("no runner")?;
        let status = Command::new(program)
            .args(first)
            .args(&bus)
            .args(slice.args())
            .env("CABC_BIN", &opts.bin)
            .current_dir(&opts.root)
            .stdin(Stdio::null())
            .stdout(out.try_clone()?)
            .stderr(out)
            .status()
            .with_context(|| format!("starting {}", program.to_string_lossy()))?;
        if status.success() {
            if let Some(claim) = claim {
                claim.done()?;
            }
        } else {
            failed += 1;
            say(format!(
                "[campaign] slice {i} failed (see {})",
                log_path.display()
            ))?;
        }
    }
    say(format!("[campaign] {} done", utc_now()))?;
    Ok(failed)
}

fn is_executable(path: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_parse() {
        assert_eq!("1/3".parse(), Ok(Lane { index: 1, count: 3 }));
        for bad in ["3/3", "0/0", "1", "a/2", "-1/2", "1/2/3"] {
            assert!(bad.parse::<Lane>().is_err(), "{bad}");
        }
    }

    #[test]
    fn the_date_as_date_prints_it() {
        let before = utc_now();
        let out = Command::new("date")
            .args(["-u", "+%FT%TZ"])
            .output()
            .unwrap();
        let after = utc_now();
        let date = String::from_utf8(out.stdout).unwrap();
        assert!(
            [&before, &after].contains(&&date.trim().to_string()),
            "{before} {date} {after}"
        );
    }
}
