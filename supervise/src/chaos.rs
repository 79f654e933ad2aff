//! Chaos (issue 64): a supervised run under a seeded schedule of faults, and what they cost. [`Chaos::run`] runs the
//! run's supervisor ([`Supervisor`], the same roster as `cabc supervise`) in this process, as a [`Watcher`] in its
//! loop: every `gap` seconds (drawn from the seed) it strikes one of the processes the supervisor runs (drawn too, among the roles asked for) with a fault of a kind drawn among those asked for
//! ([`FaultKind`]): a kill (SIGKILL; the supervisor restarts it) or a pause (SIGSTOP for a drawn 5-30 s, then SIGCONT:
//! the process and its links go silent, and past zenoh's 10 s lease its peers drop them, as a cut link looks from
//! the other side; a paused learner is the router of the run, so every link goes). It watches `metrics.csv` for the
//! epochs' ends, and when the run is over writes `<run>/chaos.json`: the faults by kind and target, the restarts,
//! the time each fault cost (the interval between the epochs around it less the median interval of the epochs
//! without one), the stalls (an epoch that took longer than `bus.epoch_timeout_s`), the steps published, stored and
//! short, the duplicates, the run's audit (every published segment's fate, `cabc audit`; a problem in it fails the
//! command), and whether and where the run stopped early. A run that has not ended by the time limit
//! is stopped and counted as a stall. A process it paused is always continued: when its pause is over, before the
//! supervisor stops the processes (the run's end, Ctrl-C, the time limit), and when the chaos itself unwinds.
//!
//! A pause is not a cut from the paused process's side (it runs nothing meanwhile): a real cut, where both sides
//! go on, and a restarted standalone router need network namespaces and a router of their own, which the end-to-end
//! tests make (tests/tests/survive.rs); the report says which kinds ran.

use crate::roster::Role;
use crate::{Ended, Live, SuperviseError, Supervisor, Watcher};
use cabc_runfolder::audit::{Audit, Figures};
use cabc_runfolder::{Status, Table};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// A reproducible stream of draws (SplitMix64): the same seed, the same schedule.
#[derive(Clone, Debug)]
pub struct Draws(u64);

impl Draws {
    pub fn new(seed: u64) -> Self {
        Draws(seed)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }

    /// Uniform among `n` (n > 0).
    pub fn index(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// What a fault does to its process.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// SIGKILL: the supervisor restarts the process.
    Kill,
    /// SIGSTOP for a drawn while, then SIGCONT: its links go silent (past the lease its peers drop them).
    Pause,
}

impl FaultKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::Kill => "kill",
            FaultKind::Pause => "pause",
        }
    }
}

impl std::str::FromStr for FaultKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "kill" => Ok(FaultKind::Kill),
            "pause" => Ok(FaultKind::Pause),
            _ => Err(format!("a fault is kill or pause, not `{s}`")),
        }
    }
}

/// One fault injected.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Fault {
    /// Seconds since the run started.
    pub at_s: f64,
    pub kind: String,
    /// The process (`actor-1`, `learner`, ...), and its role.
    pub target: String,
    pub role: String,
    /// The epoch in progress (the rows of `metrics.csv` when it struck).
    pub epoch: usize,
    /// How long a pause held the process stopped.
    pub paused_s: Option<f64>,
    /// The interval between the epochs around it less the median interval without faults, once the run went on.
    pub lost_s: Option<f64>,
}

/// The report of a chaos run (`<run>/chaos.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    pub seed: u64,
    /// The range of seconds between two faults.
    pub gap_s: (f64, f64),
    /// The fault kinds that ran.
    pub kinds: Vec<String>,
    pub faults: Vec<Fault>,
    pub faults_by_target_role: BTreeMap<String, u64>,
    /// The supervisor's restarts by role.
    pub restarts: BTreeMap<String, u64>,
    pub wall_s: f64,
    pub epochs: usize,
    /// The median interval between two epochs' ends without a fault in between.
    pub median_epoch_s: Option<f64>,
    /// Epochs that took longer than `bus.epoch_timeout_s` (a stall), or the run that never ended one, or that had
    /// not ended at the time limit.
    pub stalls: usize,
    /// The run was stopped at the chaos's time limit.
    pub timed_out: bool,
    pub max_lost_s: Option<f64>,
    /// The steps the actors said they published (their markers), and the steps the ledger stored.
    pub steps_published: u64,
    pub steps_stored: u64,
    /// Epochs that stored fewer steps than their markers said were published (a published step lost): 0 expected.
    pub epochs_short: usize,
    pub duplicate_segments: u64,
    /// The run's audit, segment by segment (`cabc audit`, issue 74): what became of each published segment, the
    /// steps taken and never published, and what does not add up (`audit_problems`: none expected; the exit status
    /// is 1 on one).
    pub audit: Option<Figures>,
    pub audit_problems: Vec<String>,
    pub early_stop_version: Option<u64>,
    pub ended: String,
    /// How the supervised run ended (the supervisor's words), and the exit status the command gives.
    pub supervisor: String,
    pub exit: i32,
}

/// A chaos run's settings.
#[derive(Clone, Debug)]
pub struct Chaos {
    pub seed: u64,
    pub gap_s: (f64, f64),
    /// The roles whose processes may be struck.
    pub roles: Vec<Role>,
    /// The kinds of fault drawn from.
    pub kinds: Vec<FaultKind>,
    /// The range of a pause's seconds.
    pub pause_s: (f64, f64),
    pub run_dir: PathBuf,
    pub epoch_timeout_s: f64,
    /// Past this, a run that has not ended is stopped and counted as a stall.
    pub limit: Duration,
}

/// A chaos run in progress: the [`Watcher`] in the supervisor's loop.
struct Striking<'a> {
    chaos: &'a Chaos,
    draws: Draws,
    started: Instant,
    next_fault: Instant,
    /// The process paused, and when it goes on.
    paused: Option<(libc::pid_t, Instant)>,
    faults: Vec<Fault>,
    epoch_ends: Vec<f64>,
    timed_out: bool,
}

impl Striking<'_> {
    fn go_on(&mut self) {
        if let Some((pid, _)) = self.paused.take() {
            signal(pid, libc::SIGCONT);
        }
    }
}

impl Watcher for Striking<'_> {
    fn poll(&mut self, live: &[Live]) -> Option<String> {
        let now = Instant::now();
        if self.paused.is_some_and(|(_, until)| now >= until) {
            self.go_on();
            self.next_fault = now + self.chaos.gap(&mut self.draws);
        }
        let rows = Table::rows_in(&self.chaos.run_dir.join(cabc_runfolder::METRICS));
        while self.epoch_ends.len() < rows {
            self.epoch_ends.push(self.started.elapsed().as_secs_f64());
        }
        if self.started.elapsed() >= self.chaos.limit {
            self.timed_out = true;
            return Some(format!(
                "the chaos's time limit ({} s) passed before the run ended",
                self.chaos.limit.as_secs()
            ));
        }
        if self.paused.is_none() && now >= self.next_fault {
            if let Some((fault, pid)) = self.chaos.strike(live, &mut self.draws, self.started, rows)
            {
                eprintln!(
                    "[chaos] {:.0} s: {} of {} ({}) in epoch {}{}",
                    fault.at_s,
                    fault.kind,
                    fault.target,
                    fault.role,
                    fault.epoch,
                    fault
                        .paused_s
                        .map_or(String::new(), |s| format!(" for {s:.0} s"))
                );
                if let Some(s) = fault.paused_s {
                    self.paused = Some((pid, Instant::now() + Duration::from_secs_f64(s)));
                }
                self.faults.push(fault);
            }
            self.next_fault = Instant::now() + self.chaos.gap(&mut self.draws);
        }
        None
    }

    fn before_stop(&mut self) {
        self.go_on();
    }
}

impl Drop for Striking<'_> {
    /// Even when the chaos unwinds, no process it paused stays stopped.
    fn drop(&mut self) {
        self.go_on();
    }
}

impl Chaos {
    /// Runs `supervisor`'s run under the schedule until it ends (or the time limit); writes and returns the report.
    pub fn run(&self, supervisor: &mut Supervisor) -> std::io::Result<Report> {
        let started = Instant::now();
        let mut draws = Draws::new(self.seed);
        let next_fault = started + self.gap(&mut draws);
        let mut striking = Striking {
            chaos: self,
            draws,
            started,
            next_fault,
            paused: None,
            faults: Vec::new(),
            epoch_ends: Vec::new(),
            timed_out: false,
        };
        let ended = supervisor.run_watched(&mut striking);
        striking.go_on();
        let supervisor = match &ended {
            Ok(Ended::Learner { code, .. }) => format!("the learner ended (exit {code})"),
            Ok(Ended::Interrupted) => "interrupted".into(),
            Ok(Ended::Finished) => "finished".into(),
            Ok(Ended::Stopped(why)) => format!("stopped: {why}"),
            Err(e) => format!("error: {e}"),
        };
        let exit = crate::exit_code(&ended);
        let faults = std::mem::take(&mut striking.faults);
        let epoch_ends = std::mem::take(&mut striking.epoch_ends);
        let timed_out = striking.timed_out;
        drop(striking);
        let mut report = self.report(faults, &epoch_ends, started.elapsed().as_secs_f64());
        report.supervisor = supervisor;
        match Audit::of(&self.run_dir) {
            Ok(audit) => {
                report.audit = Some(audit.figures());
                report.audit_problems = audit.problems.clone();
            }
            Err(e) => report.audit_problems = vec![format!("no audit: {e}")],
        }
        // A run that ended well with a segment unaccounted for fails the chaos all the same.
        report.exit = if exit == 0 && !report.audit_problems.is_empty() {
            1
        } else {
            exit
        };
        report.timed_out = timed_out;
        if timed_out {
            report.stalls += 1;
        }
        let text = serde_json::to_string_pretty(&report).map_err(std::io::Error::other)?;
        std::fs::write(self.run_dir.join("chaos.json"), text + "\n")?;
        if let Err(SuperviseError::Spawn { .. } | SuperviseError::Io { .. }) = &ended {
            return Err(std::io::Error::other(report.supervisor.clone()));
        }
        Ok(report)
    }

    fn gap(&self, draws: &mut Draws) -> Duration {
        Duration::from_secs_f64(draws.uniform(self.gap_s.0, self.gap_s.1).max(0.0))
    }

    /// Strikes one of the `live` processes of the roles asked for with a fault of a kind drawn, if any runs: the
    /// fault and the process's pid.
    fn strike(
        &self,
        live: &[Live],
        draws: &mut Draws,
        started: Instant,
        epoch: usize,
    ) -> Option<(Fault, libc::pid_t)> {
        let live: Vec<&Live> = live
            .iter()
            .filter(|p| self.roles.contains(&p.role))
            .collect();
        if live.is_empty() {
            return None;
        }
        let process = live[draws.index(live.len())];
        let kind = *self.kinds.get(draws.index(self.kinds.len()))?;
        let paused_s =
            (kind == FaultKind::Pause).then(|| draws.uniform(self.pause_s.0, self.pause_s.1));
        let pid = process.pid as libc::pid_t;
        let sig = match kind {
            FaultKind::Kill => libc::SIGKILL,
            FaultKind::Pause => libc::SIGSTOP,
        };
        if !signal(pid, sig) {
            return None;
        }
        let fault = Fault {
            at_s: started.elapsed().as_secs_f64(),
            kind: kind.as_str().into(),
            target: process.name.clone(),
            role: process.role.as_str().into(),
            epoch,
            paused_s,
            lost_s: None,
        };
        Some((fault, pid))
    }

    /// The report from the faults, the epochs' end times and the run folder's files.
    fn report(&self, mut faults: Vec<Fault>, epoch_ends: &[f64], wall_s: f64) -> Report {
        // Interval i: from the end of epoch i - 1 (or the start) to the end of epoch i.
        let intervals: Vec<f64> = epoch_ends
            .iter()
            .enumerate()
            .map(|(i, &end)| end - if i == 0 { 0.0 } else { epoch_ends[i - 1] })
            .collect();
        let struck: Vec<usize> = faults.iter().map(|f| f.epoch).collect();
        let mut calm: Vec<f64> = intervals
            .iter()
            .enumerate()
            .filter(|(i, _)| *i > 0 && !struck.contains(i))
            .map(|(_, &d)| d)
            .collect();
        calm.sort_by(f64::total_cmp);
        let median = (!calm.is_empty()).then(|| calm[calm.len() / 2]);
        for fault in &mut faults {
            fault.lost_s = intervals
                .get(fault.epoch)
                .zip(median)
                .map(|(d, m)| (d - m).max(0.0));
        }
        let mut stalls = intervals
            .iter()
            .filter(|&&d| d > self.epoch_timeout_s)
            .count();
        let summary: serde_json::Value = std::fs::read(self.run_dir.join(cabc_runfolder::SUMMARY))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default();
        if summary.is_null() {
            stalls += 1;
        }
        let metrics = self.run_dir.join(cabc_runfolder::METRICS);
        let table = Table::read(&metrics).unwrap_or_default();
        let column = |name| -> Vec<u64> {
            let cells = table.parsed::<u64>(name).unwrap_or_default();
            cells.into_iter().map(|c| c.unwrap_or(0)).collect()
        };
        let published = column("steps_published");
        let stored = column("steps_collected");
        let mut by_role = BTreeMap::new();
        for f in &faults {
            *by_role.entry(f.role.clone()).or_insert(0) += 1;
        }
        Report {
            seed: self.seed,
            gap_s: self.gap_s,
            kinds: self.kinds.iter().map(|k| k.as_str().to_string()).collect(),
            faults_by_target_role: by_role,
            restarts: Status::read(&self.run_dir)
                .map(|s| s.restarts)
                .unwrap_or_default(),
            wall_s,
            epochs: epoch_ends.len(),
            median_epoch_s: median,
            stalls,
            max_lost_s: faults
                .iter()
                .filter_map(|f| f.lost_s)
                .max_by(f64::total_cmp),
            steps_published: published.iter().sum(),
            steps_stored: summary["steps_stored"].as_u64().unwrap_or(0),
            epochs_short: stored.iter().zip(&published).filter(|(s, p)| s < p).count(),
            duplicate_segments: summary["duplicate_segments"].as_u64().unwrap_or(0),
            early_stop_version: summary["early_stop_version"].as_u64(),
            ended: summary["ended"]
                .as_str()
                .unwrap_or("no summary")
                .to_string(),
            faults,
            ..Report::default()
        }
    }
}

/// Sends `sig` to `pid`; whether it went.
fn signal(pid: libc::pid_t, sig: libc::c_int) -> bool {
    // SAFETY: kill(2) on a pid the supervisor reported as running (or that this chaos paused).
    unsafe { libc::kill(pid, sig) == 0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_draws_the_same_schedule() {
        let draw = |seed| {
            let mut d = Draws::new(seed);
            (0..8)
                .map(|_| (d.uniform(10.0, 30.0), d.index(5)))
                .collect::<Vec<_>>()
        };
        assert_eq!(draw(3), draw(3));
        assert_ne!(draw(3), draw(4));
        assert!(draw(3)
            .iter()
            .all(|&(g, i)| (10.0..30.0).contains(&g) && i < 5));
    }

    /// A `sleep 60` process, and it as the live actor-0.
    fn sleeping_actor() -> (std::process::Child, [Live; 1]) {
        let sleeper = std::process::Command::new("sleep")
            .arg("60")
            .spawn()
            .unwrap();
        let live = [Live {
            name: "actor-0".into(),
            role: Role::Actor,
            pid: sleeper.id(),
        }];
        (sleeper, live)
    }

    /// Chaos among the actors of `dir`'s run with faults of `kind`.
    fn actor_chaos(dir: &std::path::Path, seed: u64, kind: FaultKind) -> Chaos {
        Chaos {
            seed,
            gap_s: (1.0, 2.0),
            roles: vec![Role::Actor],
            kinds: vec![kind],
            pause_s: (5.0, 30.0),
            run_dir: dir.to_path_buf(),
            epoch_timeout_s: 6.0,
            limit: Duration::from_secs(60),
        }
    }

    /// The state letter of /proc/<pid>/stat ('T' stopped, 'S' sleeping, ...).
    fn state(pid: u32) -> char {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
        let after = &stat[stat.rfind(')').unwrap() + 2..];
        after.chars().next().unwrap()
    }

    #[test]
    fn a_pause_stops_the_drawn_process_for_a_drawn_while_and_a_kill_ends_it() {
        let dir = tempfile::tempdir().unwrap();
        let (mut sleeper, live) = sleeping_actor();
        let mut chaos = actor_chaos(dir.path(), 5, FaultKind::Pause);
        let (fault, pid) = chaos
            .strike(&live, &mut Draws::new(5), Instant::now(), 3)
            .unwrap();
        assert_eq!(
            (fault.kind.as_str(), fault.target.as_str(), fault.epoch),
            ("pause", "actor-0", 3)
        );
        assert!((5.0..30.0).contains(&fault.paused_s.unwrap()));
        assert_eq!(pid as u32, sleeper.id());
        // Stopped (the state may take a moment to show).
        let began = Instant::now();
        while state(sleeper.id()) != 'T' && began.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(state(sleeper.id()), 'T');
        assert!(signal(pid, libc::SIGCONT));
        // A role not asked for is never struck; a kill ends the process.
        chaos.roles = vec![Role::Learner];
        assert!(chaos
            .strike(&live, &mut Draws::new(5), Instant::now(), 3)
            .is_none());
        chaos.roles = vec![Role::Actor];
        chaos.kinds = vec![FaultKind::Kill];
        let (fault, _) = chaos
            .strike(&live, &mut Draws::new(5), Instant::now(), 3)
            .unwrap();
        assert_eq!((fault.kind.as_str(), fault.paused_s), ("kill", None));
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(sleeper.wait().unwrap().signal(), Some(libc::SIGKILL));
    }

    #[test]
    fn a_fault_costs_its_epochs_interval_less_the_calm_median() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("metrics.csv"),
            "epoch,steps_published,steps_collected\n0,10,10\n1,10,12\n2,10,9\n3,10,10\n",
        )
        .unwrap();
        std::fs::write(
            dir.path().join("summary.json"),
            r#"{"steps_stored": 41, "duplicate_segments": 0, "early_stop_version": 3, "ended": "early stop"}"#,
        )
        .unwrap();
        let chaos = actor_chaos(dir.path(), 1, FaultKind::Kill);
        let fault = Fault {
            at_s: 3.0,
            kind: "kill".into(),
            target: "actor-0".into(),
            role: "actor".into(),
            epoch: 2,
            paused_s: None,
            lost_s: None,
        };
        // Epoch ends at 2, 4, 11, 13 s: intervals 2, 2, 7, 2; the fault struck epoch 2.
        let report = chaos.report(vec![fault], &[2.0, 4.0, 11.0, 13.0], 14.0);
        assert_eq!(report.median_epoch_s, Some(2.0));
        assert_eq!(report.faults[0].lost_s, Some(5.0));
        assert_eq!(report.stalls, 1, "7 s > the 6 s timeout");
        assert_eq!(report.epochs_short, 1, "epoch 2 stored 9 of 10");
        assert_eq!(report.steps_published, 40);
        assert_eq!(report.steps_stored, 41);
        assert_eq!(report.early_stop_version, Some(3));
    }

    #[test]
    fn a_paused_process_goes_on_when_the_chaos_stops_and_the_time_limit_stops_the_run() {
        let dir = tempfile::tempdir().unwrap();
        let (mut sleeper, live) = sleeping_actor();
        let chaos = Chaos {
            gap_s: (0.001, 0.002),
            pause_s: (600.0, 600.0),
            limit: Duration::from_millis(300),
            ..actor_chaos(dir.path(), 2, FaultKind::Pause)
        };
        let started = Instant::now();
        let mut striking = Striking {
            chaos: &chaos,
            draws: Draws::new(2),
            started,
            next_fault: started,
            paused: None,
            faults: Vec::new(),
            epoch_ends: Vec::new(),
            timed_out: false,
        };
        assert_eq!(striking.poll(&live), None);
        assert_eq!(striking.faults.len(), 1, "the pause struck at once");
        let began = Instant::now();
        while state(sleeper.id()) != 'T' && began.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(state(sleeper.id()), 'T');
        // Past the limit the watcher stops the run, and a stall is counted by the run.
        std::thread::sleep(Duration::from_millis(350));
        assert!(striking.poll(&live).unwrap().contains("time limit"));
        assert!(striking.timed_out);
        // Dropped (the chaos ends, or unwinds) with its pause of 600 s not over: the process goes on.
        drop(striking);
        let began = Instant::now();
        while state(sleeper.id()) == 'T' && began.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_ne!(state(sleeper.id()), 'T');
        sleeper.kill().unwrap();
        sleeper.wait().unwrap();
    }
}
