//! `cabc reproduce`: the campaign's per-run step, and the tool for runs over seeds outside a campaign. For each
//! experiment (a preset), each seed k and each method it names the run ([`RunName`]: `<preset>[-<tag>]-s<k>
//! [-baseline]`, seed 41 + k), skips it when it ended (here or in `docs/reproduction/`, [`run_state`]), resumes it
//! when it has a checkpoint and starts it fresh otherwise, through `deploy/run-local.sh` with the binaries of
//! `CABC_BIN`; then copies its results, the four small files a figure is drawn from ([`RESULT_FILES`]: summary.json,
//! metrics.csv, evals.csv, config.toml; no plots or videos: `cabc plots RUN` redraws a run's plots from them), to
//! `docs/reproduction/<run>/`, and after each experiment redraws its group's figures and table with `cabc compare`
//! (`docs/reproduction/<group>-*.png`, `<group>-table.md`). `deploy/reproduce.sh` builds the binaries and calls it.
//!
//! A failed run stops the step with its error (the lane reports the slice as failed and goes on); a failed drawing
//! is reported and does not.

use crate::plan::Method;
use crate::status::{run_state, RunState, RESULTS_DIR};
use anyhow::{bail, Context, Result};
use cabc_proto::run_name::RunName;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The experiments run when none is named.
pub const DEFAULT_EXPERIMENTS: [&str; 3] = ["v-b", "v-a-cpu", "v-c-cpu"];

/// The files of a run folder copied to its results, and the only ones: what the figures and tables are drawn from
/// (the run's plots and videos stay in the run folder; `cabc plots RUN` redraws the plots from these).
pub const RESULT_FILES: [&str; 4] = [
    cabc_runfolder::SUMMARY,
    cabc_runfolder::METRICS,
    cabc_runfolder::EVALS,
    cabc_runfolder::CONFIG,
];

/// The seeds' numbers: `N` (1 to N) or `A-B`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Seeds {
    pub first: u32,
    pub last: u32,
}

impl std::str::FromStr for Seeds {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let number = |t: &str| match t.parse::<u32>() {
            Ok(n) if n > 0 && !t.starts_with('0') && !t.starts_with('+') => Some(n),
            _ => None,
        };
        let bad = || format!("--seeds needs N or A-B (numbers from 1), not {s:?}");
        let (first, last) = match s.split_once('-') {
            None => (1, number(s).ok_or_else(bad)?),
            Some((a, b)) => (number(a).ok_or_else(bad)?, number(b).ok_or_else(bad)?),
        };
        Ok(Self { first, last })
    }
}

/// What one call runs.
#[derive(Debug, Clone)]
pub struct Reproduce {
    /// Presets, in order ([`DEFAULT_EXPERIMENTS`] when empty).
    pub experiments: Vec<String>,
    pub seeds: Seeds,
    /// `run.max_epochs` of every run (default: the preset's).
    pub epochs: Option<u32>,
    /// Names the ablation: the group is `<preset>-<tag>`.
    pub tag: Option<String>,
    /// In order; both (proposed, then baseline) by default.
    pub methods: Vec<Method>,
    /// `KEY=VALUE` settings of every run, before the run's own (seed, name, epochs).
    pub sets: Vec<String>,
    /// Prints what it would run, runs and copies nothing.
    pub dry_run: bool,
}

/// One run of a call: its name and the arguments of `deploy/run-local.sh` after the mode, the preset last.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedRun {
    pub name: RunName,
    pub args: Vec<String>,
}

impl Reproduce {
    /// The runs, per experiment in order, seed-major, in the methods' order.
    pub fn runs(&self) -> Result<Vec<PlannedRun>> {
        if self.epochs == Some(0) {
            bail!("--epochs needs a positive number");
        }
        let experiments: Vec<String> = match self.experiments.is_empty() {
            true => DEFAULT_EXPERIMENTS.iter().map(|s| s.to_string()).collect(),
            false => self.experiments.clone(),
        };
        let methods = match self.methods.is_empty() {
            true => vec![Method::Proposed, Method::Baseline],
            false => self.methods.clone(),
        };
        let mut runs = vec![];
        for preset in &experiments {
            let experiment = RunName::experiment_of(preset, self.tag.as_deref());
            for k in self.seeds.first..=self.seeds.last {
                for &method in &methods {
                    let name = RunName::new(&experiment, k, method == Method::Baseline)
                        .with_context(|| format!("preset {preset:?}, tag {:?}", self.tag))?;
                    let mut args = vec![];
                    for set in &self.sets {
                        args.extend(["--set".to_string(), set.clone()]);
                    }
                    if name.baseline {
                        args.push("--baseline".into());
                    }
                    args.extend(["--set".into(), format!("run.seed={}", name.seed())]);
                    args.extend(["--set".into(), format!("run.name={name}")]);
                    if let Some(e) = self.epochs {
                        args.extend(["--set".into(), format!("run.max_epochs={e}")]);
                    }
                    args.push(preset.clone());
                    runs.push(PlannedRun { name, args });
                }
            }
        }
        Ok(runs)
    }

    /// Runs them under the repository's `root` with the binaries in `bin` (run-local.sh is given them as
    /// `CABC_BIN`) and draws each group with `compare`'s `compare` subcommand: a `cabc` that may be newer than the
    /// runs' (a campaign's pinned binaries predate a column or a figure; the numbers are the runs' whichever draws
    /// them). Progress goes to stderr, each group's table to stdout.
    pub fn run(&self, root: &Path, bin: &Path, compare: &Path) -> Result<()> {
        let runs = self.runs()?;
        for group in runs.chunk_by(|a, b| a.name.group() == b.name.group()) {
            for run in group {
                self.run_one(root, bin, run)?;
            }
            if !self.dry_run {
                draw(root, compare, group[0].name.group());
            }
        }
        eprintln!("[reproduce] done; results in {RESULTS_DIR}/");
        Ok(())
    }

    /// One run: skipped when it ended, else resumed or started; then its results copied.
    fn run_one(&self, root: &Path, bin: &Path, run: &PlannedRun) -> Result<()> {
        let mode = match run_state(root, &run.name) {
            RunState::Ended(how) => {
                eprintln!("[reproduce] {}: done (ended {how})", run.name);
                None
            }
            RunState::InProgress(_) => Some("--resume"),
            RunState::NotStarted => Some("--fresh"),
        };
        if let Some(mode) = mode {
            eprintln!(
                "[reproduce] {}: run-local.sh {mode} {}",
                run.name,
                run.args.join(" ")
            );
            if !self.dry_run {
                let script = root.join("deploy/run-local.sh");
                let status = Command::new(&script)
                    .arg(mode)
                    .args(&run.args)
                    .env("CABC_BIN", bin)
                    .current_dir(root)
                    .status()
                    .with_context(|| format!("starting {}", script.display()))?;
                if !status.success() {
                    bail!("{}: run-local.sh failed ({status})", run.name);
                }
            }
        }
        let dir = root.join("runs").join(run.name.to_string());
        if !self.dry_run && dir.is_dir() {
            let to = root.join(RESULTS_DIR).join(run.name.to_string());
            copy_results(&dir, &to).with_context(|| format!("copying {}'s results", run.name))?;
        }
        // A run stopped by Ctrl-C exits cleanly with its checkpoint: the slice is not done (a lane must not mark
        // it so), and the next call resumes it.
        if let (Some(_), RunState::InProgress(epochs)) = (mode, run_state(root, &run.name)) {
            if !self.dry_run {
                bail!(
                    "{}: interrupted after {epochs} epochs; the same command resumes it",
                    run.name
                );
            }
        }
        Ok(())
    }
}

/// Redraws a group's figures and table (`<cabc> compare` over its result folders with a metrics.csv); a failure
/// is reported, not returned.
fn draw(root: &Path, cabc: &Path, group: &str) {
    let results = root.join(RESULTS_DIR);
    let folders = match group_folders(&results, group) {
        Ok(folders) if !folders.is_empty() => folders,
        Ok(_) => return,
        Err(e) => {
            eprintln!("[reproduce] compare {group} failed: {e:#}");
            return;
        }
    };
    let out = Command::new(cabc)
        .arg("compare")
        .arg("--out")
        .arg(results.join(group))
        .args(&folders)
        .current_dir(root)
        .output();
    match out {
        Ok(out) if out.status.success() => {
            let table = results.join(format!("{group}-table.md"));
            if let Err(e) = std::fs::write(&table, &out.stdout) {
                eprintln!("[reproduce] writing {}: {e}", table.display());
            }
            print!("{}", String::from_utf8_lossy(&out.stdout));
        }
        Ok(out) => eprintln!(
            "[reproduce] compare {group} failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim_end()
        ),
        Err(e) => eprintln!("[reproduce] compare {group} failed: {e}"),
    }
}

/// The result folders of a group's runs (their names parse to the group; a metrics.csv in them), sorted by name.
pub fn group_folders(results: &Path, group: &str) -> Result<Vec<PathBuf>> {
    let mut folders = vec![];
    let entries = match std::fs::read_dir(results) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(folders),
        Err(e) => return Err(e).with_context(|| format!("reading {}", results.display())),
    };
    for entry in entries {
        let path = entry?.path();
        let ours = path
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.parse::<RunName>().ok())
            .is_some_and(|name| name.group() == group);
        if ours && path.join(cabc_runfolder::METRICS).is_file() {
            folders.push(path);
        }
    }
    folders.sort();
    Ok(folders)
}

/// Copies a run folder's results into `to` (created), overwriting what is there: the files of [`RESULT_FILES`] it
/// has, nothing else (no plots/, GIFs, policies or checkpoint).
fn copy_results(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
    for file in RESULT_FILES {
        let src = from.join(file);
        if src.is_file() {
            std::fs::copy(&src, to.join(file))
                .with_context(|| format!("copying {}", src.display()))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_parse() {
        assert_eq!("3".parse(), Ok(Seeds { first: 1, last: 3 }));
        assert_eq!("6-10".parse(), Ok(Seeds { first: 6, last: 10 }));
        for bad in ["0", "", "a", "1-", "-2", "01", "1-0", "+2", "1-2-3"] {
            assert!(bad.parse::<Seeds>().is_err(), "{bad}");
        }
    }

    #[test]
    fn the_runs_are_named_and_seeded_by_the_convention() {
        let call = Reproduce {
            experiments: vec!["v-b-ref".into()],
            seeds: "2-3".parse().unwrap(),
            epochs: Some(200),
            tag: Some("clone".into()),
            methods: vec![],
            sets: vec!["training.clone_uncertain=true".into()],
            dry_run: true,
        };
        let runs = call.runs().unwrap();
        let names: Vec<String> = runs.iter().map(|r| r.name.to_string()).collect();
        assert_eq!(
            names,
            [
                "v-b-ref-clone-s2",
                "v-b-ref-clone-s2-baseline",
                "v-b-ref-clone-s3",
                "v-b-ref-clone-s3-baseline"
            ]
        );
        assert_eq!(
            runs[1].args.join(" "),
            "--set training.clone_uncertain=true --baseline --set run.seed=43 \
             --set run.name=v-b-ref-clone-s2-baseline --set run.max_epochs=200 v-b-ref"
        );
        let none = Reproduce {
            experiments: vec![],
            methods: vec![Method::Baseline],
            tag: None,
            epochs: None,
            sets: vec![],
            ..call
        };
        let runs = none.runs().unwrap();
        assert_eq!(runs.len(), 6);
        assert_eq!(runs[0].name.to_string(), "v-b-s2-baseline");
        assert_eq!(runs[5].args.last().unwrap(), "v-c-cpu");
    }

    /// The results are the four small files and nothing else of the run folder: no plots/, GIFs, policies or
    /// checkpoint (issue 47: results small; `cabc plots RUN` redraws the plots).
    #[test]
    fn only_the_result_files_are_copied() {
        let dir = tempfile::tempdir().unwrap();
        let (from, to) = (dir.path().join("runs/r-s1"), dir.path().join("docs/r-s1"));
        for file in [
            "summary.json",
            "metrics.csv",
            "evals.csv",
            "config.toml",
            "plots/laps.png",
            "plots/eval-v3.gif",
            "best-policy.gif",
            "best-policy.safetensors",
            "checkpoint/state.json",
            "logs/learner.log",
        ] {
            let path = from.join(file);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, file).unwrap();
        }
        copy_results(&from, &to).unwrap();
        let mut copied: Vec<String> = std::fs::read_dir(&to)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        copied.sort();
        let mut expected = RESULT_FILES.map(String::from).to_vec();
        expected.sort();
        assert_eq!(copied, expected);
        assert_eq!(
            std::fs::read_to_string(to.join("evals.csv")).unwrap(),
            "evals.csv"
        );
        // A run without a summary yet (interrupted): what it has.
        std::fs::remove_file(from.join("summary.json")).unwrap();
        let partial = dir.path().join("docs/r-s2");
        copy_results(&from, &partial).unwrap();
        assert!(partial.join("metrics.csv").is_file() && !partial.join("summary.json").exists());
    }

    #[test]
    fn a_bad_tag_or_epochs_is_refused() {
        let call = Reproduce {
            experiments: vec!["v-b".into()],
            seeds: "1".parse().unwrap(),
            epochs: None,
            tag: Some("a b".into()),
            methods: vec![],
            sets: vec![],
            dry_run: true,
        };
        assert!(call.runs().is_err());
        let zero = Reproduce {
            tag: None,
            epochs: Some(0),
            ..call
        };
        assert!(zero.runs().is_err());
    }
}
