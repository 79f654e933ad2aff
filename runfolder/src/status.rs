//! `<run>/supervision.json`: what the supervisor restarted, by role and by process, written whole and swapped in by
//! rename after every change. The learner reads it at each epoch's end (`restarts_<role>` in `metrics.csv`, `restarts`
//! in `summary.json`), so it says what this machine's supervisor did; another machine's supervisor keeps its own file
//! in its own run folder (or, on a cluster's shared folder, its own `supervision-<node>.json`).

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The file's name in the run folder.
pub const FILE: &str = "supervision.json";

/// The largest file read back (a few hundred processes' entries).
const MAX_BYTES: u64 = 4 << 20;

/// The supervisor's record.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Restarts by role (`learner`, `expert`, `actor`, `evaluator`), every role of [`Status::new`] present.
    pub restarts: BTreeMap<String, u64>,
    /// Each process's restarts and how it last ended.
    pub processes: BTreeMap<String, ProcessStatus>,
    /// Why the supervisor stopped the run, once it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended: Option<String>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProcessStatus {
    pub role: String,
    pub restarts: u64,
    /// Its process id while it runs (what a fault injector kills).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pid: Option<u32>,
    /// How it last ended ("exit 1", "signal 9"), if it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_exit: Option<String>,
    pub log: String,
}

impl Status {
    /// Every one of `roles` at 0 restarts.
    pub fn new<'a>(roles: impl IntoIterator<Item = &'a str>) -> Self {
        Status {
            restarts: roles.into_iter().map(|r| (r.to_string(), 0)).collect(),
            ..Status::default()
        }
    }

    /// The path of the file in `run_dir`.
    pub fn path(run_dir: &Path) -> PathBuf {
        run_dir.join(FILE)
    }

    /// Writes the file `path` whole: a temporary beside it, renamed over it.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let tmp = path.with_extension("json.tmp");
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(&tmp, text + "\n")?;
        std::fs::rename(&tmp, path)
    }

    /// The file of `run_dir`, if there is one that reads (a file too large or malformed is None).
    pub fn read(run_dir: &Path) -> Option<Status> {
        let path = Status::path(run_dir);
        if std::fs::metadata(&path).ok()?.len() > MAX_BYTES {
            return None;
        }
        serde_json::from_slice(&std::fs::read(path).ok()?).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_reads_back_what_was_written() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(Status::read(dir.path()), None);
        let mut status = Status::new(["actor", "learner"]);
        *status.restarts.entry("actor".into()).or_default() += 2;
        status.processes.insert(
            "actor-0".into(),
            ProcessStatus {
                role: "actor".into(),
                restarts: 2,
                pid: Some(42),
                last_exit: Some("signal 9".into()),
                log: "logs/actor-0.log".into(),
            },
        );
        status.write(&Status::path(dir.path())).unwrap();
        assert_eq!(Status::read(dir.path()), Some(status));
        std::fs::write(Status::path(dir.path()), "{not json").unwrap();
        assert_eq!(Status::read(dir.path()), None);
    }

    #[test]
    fn a_new_status_has_every_role_it_is_given() {
        let s = Status::new(["learner", "expert", "actor", "evaluator"]);
        assert_eq!(
            s.restarts.keys().map(String::as_str).collect::<Vec<_>>(),
            ["actor", "evaluator", "expert", "learner"]
        );
    }
}
