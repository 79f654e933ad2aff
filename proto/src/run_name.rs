//! The campaign's run names, in one place: `<experiment>-s<k>[-baseline]`, where the experiment is a preset, or a
//! preset and a tag (`<preset>-<tag>`, the name of an ablation or a candidate), `k` counts seeds from 1 and the run's
//! seed is `41 + k` (seed 1 is the presets' 42), and `-baseline` marks the baseline method (lambda = 0) of the same
//! experiment and seed. The experiment is the run's *group*: the runs of one group over seeds and methods are what
//! `cabc compare` and `--by-group` put side by side.
//!
//! `deploy/reproduce.sh` names its runs so (`--tag T` makes the experiment `<preset>-T`), `cabc campaign` expands a
//! plan's slices into these names, and the analysis over run folders groups them by [`group_of`].

use std::fmt;
use std::str::FromStr;

/// What [`RunName::seed`] adds to `k`: seed 1 is the presets' `run.seed = 42`.
pub const SEED_OFFSET: u64 = 41;

/// A run's name under the campaign's convention: `<experiment>-s<k>[-baseline]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RunName {
    /// The preset, or `<preset>-<tag>`: the group of the run (letters, digits, '-', '_', '.').
    pub experiment: String,
    /// The seed's number, from 1: the run's seed is `41 + k`.
    pub k: u32,
    /// The baseline method (`-baseline`, `--baseline`: lambda = 0) rather than the proposed one.
    pub baseline: bool,
}

/// Why a name is not a run name of the convention, or an experiment or tag not usable in one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RunNameError {
    #[error("run name {0:?}: expected <experiment>-s<k>[-baseline] with k a number from 1 (no leading zero)")]
    NoSeed(String),
    #[error("experiment {0:?}: expected letters, digits, '-', '_' or '.', not starting or ending with '-'")]
    Experiment(String),
    #[error("seed number {0}: k counts from 1 (the seed is 41 + k)")]
    Zero(u32),
}

impl RunName {
    /// A run name; fails on an experiment a run folder cannot be named after, or k = 0.
    pub fn new(
        experiment: impl Into<String>,
        k: u32,
        baseline: bool,
    ) -> Result<Self, RunNameError> {
        let experiment = experiment.into();
        check_experiment(&experiment)?;
        if k == 0 {
            return Err(RunNameError::Zero(k));
        }
        Ok(Self {
            experiment,
            k,
            baseline,
        })
    }

    /// The experiment of a preset run with `--tag`: `<preset>-<tag>`, or the preset alone.
    pub fn experiment_of(preset: &str, tag: Option<&str>) -> String {
        match tag {
            Some(tag) if !tag.is_empty() => format!("{preset}-{tag}"),
            _ => preset.to_string(),
        }
    }

    /// The run's `run.seed`: 41 + k.
    pub fn seed(&self) -> u64 {
        SEED_OFFSET + u64::from(self.k)
    }

    /// The run's group: its name without `-s<k>` and `-baseline` (the method, [`RunName::method`]).
    pub fn group(&self) -> &str {
        &self.experiment
    }

    /// Its group's label in a comparison ([`group_label`]).
    pub fn label(&self) -> String {
        group_label(self.group(), self.baseline)
    }

    /// "baseline" or "proposed".
    pub fn method(&self) -> &'static str {
        if self.baseline {
            "baseline"
        } else {
            "proposed"
        }
    }
}

impl fmt::Display for RunName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-s{}", self.experiment, self.k)?;
        if self.baseline {
            f.write_str("-baseline")?;
        }
        Ok(())
    }
}

impl FromStr for RunName {
    type Err = RunNameError;

    /// Parses `<experiment>-s<k>[-baseline]`; `k` is written without leading zeros, so that a name parses back to
    /// itself (`to_string` of the result is the name).
    fn from_str(name: &str) -> Result<Self, Self::Err> {
        let no_seed = || RunNameError::NoSeed(name.to_string());
        let (stem, baseline) = match name.strip_suffix("-baseline") {
            Some(stem) => (stem, true),
            None => (name, false),
        };
        let (experiment, k) = stem.rsplit_once("-s").ok_or_else(no_seed)?;
        if k.is_empty() || !k.bytes().all(|b| b.is_ascii_digit()) || k.starts_with('0') {
            return Err(no_seed());
        }
        let k: u32 = k.parse().map_err(|_| no_seed())?;
        if experiment.is_empty() {
            return Err(no_seed());
        }
        Self::new(experiment, k, baseline)
    }
}

fn check_experiment(experiment: &str) -> Result<(), RunNameError> {
    let ok = !experiment.is_empty()
        && !experiment.starts_with('-')
        && !experiment.ends_with('-')
        && experiment
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'));
    if ok {
        Ok(())
    } else {
        Err(RunNameError::Experiment(experiment.to_string()))
    }
}

/// How a comparison names a group's runs of one method (`cabc compare --by-group`'s rows, `--versus A=B`'s labels):
/// the group for its proposed runs, `<group> (baseline)` for its baselines.
pub fn group_label(group: &str, baseline: bool) -> String {
    if baseline {
        format!("{group} (baseline)")
    } else {
        group.to_string()
    }
}

/// The group a label names ([`group_label`]'s inverse), and whether it names the baselines.
pub fn label_group(label: &str) -> (&str, bool) {
    match label.strip_suffix(" (baseline)") {
        Some(group) => (group, true),
        None => (label, false),
    }
}

/// The group of any run folder's name: the experiment of a name of the convention ([`RunName::group`]), else the
/// name less a `-baseline` suffix (a run named by hand, `v-b-s1-to-300`, is a group of its own).
pub fn group_of(name: &str) -> &str {
    match name.parse::<RunName>() {
        Ok(_) => {
            let stem = name.strip_suffix("-baseline").unwrap_or(name);
            stem.rsplit_once("-s").map_or(stem, |(group, _)| group)
        }
        Err(_) => name.strip_suffix("-baseline").unwrap_or(name),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn a_label_names_a_group_and_its_method() {
        let run: RunName = "v-c-ref-bc-ten-s2-baseline".parse().unwrap();
        assert_eq!(run.label(), "v-c-ref-bc-ten (baseline)");
        assert_eq!(label_group(&run.label()), ("v-c-ref-bc-ten", true));
        assert_eq!(label_group("v-c-ref-ten"), ("v-c-ref-ten", false));
    }

    #[test]
    fn formats_and_parses_back() {
        for (name, experiment, k, baseline) in [
            ("v-b-s1", "v-b", 1, false),
            ("v-b-s1-baseline", "v-b", 1, true),
            (
                "v-b-ref-warmup-dminus-s10",
                "v-b-ref-warmup-dminus",
                10,
                false,
            ),
            ("v-c-ref-bc-s3-baseline", "v-c-ref-bc", 3, true),
            // A tag may itself look like a name's parts: the last -s<k> is the seed.
            ("v-b-ref-s2-s4", "v-b-ref-s2", 4, false),
            ("x-baseline-s1", "x-baseline", 1, false),
        ] {
            let run: RunName = name.parse().unwrap();
            assert_eq!(run, RunName::new(experiment, k, baseline).unwrap());
            assert_eq!(run.to_string(), name);
            assert_eq!(run.group(), experiment);
            assert_eq!(group_of(name), experiment);
            assert_eq!(run.seed(), 41 + u64::from(k));
        }
        assert_eq!(
            RunName::experiment_of("v-b-ref", Some("abl-clip")),
            "v-b-ref-abl-clip"
        );
        assert_eq!(RunName::experiment_of("v-b-ref", None), "v-b-ref");
        assert_eq!(RunName::experiment_of("v-b-ref", Some("")), "v-b-ref");
        let run = RunName::new(RunName::experiment_of("v-a-ref", Some("abl-lr")), 2, true).unwrap();
        assert_eq!(run.to_string(), "v-a-ref-abl-lr-s2-baseline");
        assert_eq!((run.seed(), run.method()), (43, "baseline"));
    }

    #[test]
    fn refuses_names_off_the_convention() {
        for name in [
            "v-b",
            "v-b-s",
            "v-b-s0",
            "v-b-s01",
            "v-b-sx",
            "v-b-s1-to-300",
            "v-b-s1-baseline-baseline",
            "-s1",
            "v-b-s1 ",
            "v b-s1",
            "v-b--s1",
            "v-b-s99999999999",
            "",
        ] {
            let err = name.parse::<RunName>().unwrap_err();
            assert!(err.to_string().contains("expected"), "{name}: {err}");
        }
        assert_eq!(
            RunName::new("v-b", 0, false).unwrap_err(),
            RunNameError::Zero(0)
        );
        assert!(RunName::new("v/b", 1, false).is_err());
        // Not of the convention: a group of its own, less -baseline.
        assert_eq!(group_of("v-b-s1-to-300"), "v-b-s1-to-300");
        assert_eq!(group_of("v-a-cpu-mem-baseline"), "v-a-cpu-mem");
    }

    /// The run folders of docs/reproduction/ (and its before-flush/ and in-progress/): each of the convention parses,
    /// prints back to itself, and its config.toml's run.seed
    /// is 41 + k; the few named by hand are refused, by name.
    #[test]
    fn the_reproduction_folders_parse() {
        let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/reproduction");
        let by_hand = [
            "v-b-s1-to-300",
            "v-a-cpu-mem",
            "v-c-cpu-mem",
            "v-b-7d46ebc-rerun",
        ];
        let mut dirs = vec![];
        for parent in [
            out.clone(),
            out.join("before-flush"),
            out.join("in-progress"),
        ] {
            let Ok(entries) = std::fs::read_dir(&parent) else {
                continue;
            };
            for e in entries.map(Result::unwrap) {
                if e.path().join("config.toml").is_file() {
                    dirs.push(e.path());
                }
            }
        }
        assert!(
            dirs.len() > 100,
            "{} run folders in {}",
            dirs.len(),
            out.display()
        );
        let mut parsed = 0;
        for dir in dirs {
            let name = dir.file_name().unwrap().to_str().unwrap();
            match name.parse::<RunName>() {
                Ok(run) => {
                    parsed += 1;
                    assert_eq!(run.to_string(), name);
                    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
                    let seed = config
                        .lines()
                        .find_map(|l| l.strip_prefix("seed = "))
                        .unwrap();
                    assert_eq!(seed, run.seed().to_string(), "{name}");
                }
                Err(e) => assert!(by_hand.contains(&name), "{name}: {e}"),
            }
        }
        assert!(parsed > 100);
    }
}
