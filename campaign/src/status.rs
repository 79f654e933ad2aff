//! Where each run of a plan stands, read from its folders as deploy/reproduce.sh reads them: ended (a summary.json of
//! a run not interrupted, in `runs/<run>/` or, from an earlier session on another machine, in
//! `docs/reproduction/<run>/`), in progress (a checkpoint in `runs/<run>/`: reproduce.sh resumes it) or not started.

use crate::plan::Plan;
use cabc_proto::run_name::RunName;
use std::fmt::Write;
use std::path::Path;

/// Where the campaign's results go (reproduce.sh copies each run's there).
pub const RESULTS_DIR: &str = "docs/reproduction";

/// A run's state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RunState {
    /// How it ended (summary.json's `ended`: "early-stop", "max-epochs", ...).
    Ended(String),
    /// Resumable, at this many epochs (the rows of its metrics.csv).
    InProgress(usize),
    NotStarted,
}

/// How a run folder's run ended, if it did: its summary.json's `ended`, unless "interrupted".
fn ended(dir: &Path) -> Option<String> {
    let text = std::fs::read_to_string(dir.join("summary.json")).ok()?;
    let how = serde_json::from_str::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| v.get("ended").and_then(|e| e.as_str()).map(str::to_string));
    match how {
        Some(how) if how == "interrupted" => None,
        Some(how) => Some(how),
        // A summary without `ended` (or not JSON): reproduce.sh counts it as ended too.
        None if text.contains("\"interrupted\"") => None,
        None => Some("?".into()),
    }
}

/// The state of one run under the repository's root.
pub fn run_state(root: &Path, run: &RunName) -> RunState {
    let dir = root.join("runs").join(run.to_string());
    if let Some(how) = ended(&dir).or_else(|| ended(&root.join(RESULTS_DIR).join(run.to_string())))
    {
        return RunState::Ended(how);
    }
    if dir.join("checkpoint").is_dir() || dir.join("checkpoint.old").is_dir() {
        let rows = std::fs::read_to_string(dir.join("metrics.csv"))
            .map(|m| m.lines().count().saturating_sub(1))
            .unwrap_or(0);
        return RunState::InProgress(rows);
    }
    RunState::NotStarted
}

/// The report of `cabc campaign status`: per slice its runs and their states, then the counts.
pub fn status(root: &Path, plan: &Plan) -> String {
    let mut out = String::new();
    let (mut ended_n, mut progress_n, mut not_n) = (0, 0, 0);
    for (i, slice) in plan.slices.iter().enumerate() {
        writeln!(out, "slice {i}: {slice}").unwrap();
        for run in slice.runs() {
            let what = match run_state(root, &run) {
                RunState::Ended(how) => {
                    ended_n += 1;
                    format!("ended, {how}")
                }
                RunState::InProgress(epochs) => {
                    progress_n += 1;
                    format!("in progress, {epochs} epochs")
                }
                RunState::NotStarted => {
                    not_n += 1;
                    "not started".into()
                }
            };
            writeln!(out, "  {run}: {what}").unwrap();
        }
    }
    writeln!(
        out,
        "runs: {ended_n} ended, {progress_n} in progress, {not_n} not started"
    )
    .unwrap();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn states_from_the_folders() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        let write = |path: &str, text: &str| {
            let path = root.join(path);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        };
        // s1: ended here; s2: its summary says interrupted, with a checkpoint and 3 epochs; s3: ended on another
        // machine (docs/reproduction); s4: interrupted in both, no checkpoint; s5: nothing.
        write(
            "runs/g-s1/summary.json",
            "{\n  \"ended\": \"early-stop\"\n}",
        );
        write("runs/g-s2/summary.json", "{\"ended\": \"interrupted\"}");
        write("runs/g-s2/metrics.csv", "epoch\n1\n2\n3\n");
        std::fs::create_dir_all(root.join("runs/g-s2/checkpoint.old")).unwrap();
        write(
            "docs/reproduction/g-s3/summary.json",
            "{\"ended\": \"max-epochs\"}",
        );
        write("runs/g-s3/metrics.csv", "epoch\n");
        write("runs/g-s4/summary.json", "{\"ended\": \"interrupted\"}");
        write(
            "docs/reproduction/g-s4/summary.json",
            "{\"ended\": \"interrupted\"}",
        );
        let plan = Plan::parse("[[block]]\nseeds = [1, 2, 3, 4, 5]\nslices = [{ preset = \"g\", methods = [\"proposed\"] }]")
            .unwrap();
        assert_eq!(
            status(root, &plan),
            "slice 0: --seeds 1-1 --methods proposed g\n  g-s1: ended, early-stop\n\
             slice 1: --seeds 2-2 --methods proposed g\n  g-s2: in progress, 3 epochs\n\
             slice 2: --seeds 3-3 --methods proposed g\n  g-s3: ended, max-epochs\n\
             slice 3: --seeds 4-4 --methods proposed g\n  g-s4: not started\n\
             slice 4: --seeds 5-5 --methods proposed g\n  g-s5: not started\n\
             runs: 2 ended, 1 in progress, 2 not started\n"
        );
    }
}
