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
    let text = std::fs::read_to_string(dir.join(cabc_runfolder::SUMMARY)).ok()?;
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
    if cabc_runfolder::has_checkpoint(&dir) {
        let rows = cabc_runfolder::Table::rows_in(&dir.join(cabc_runfolder::METRICS));
        return RunState::InProgress(rows);
    }
    RunState::NotStarted
}

/// The wall clock of a run folder's epochs in minutes (the sum of its metrics.csv's `epoch_s`); None without it.
fn wall_minutes(dir: &Path) -> Option<f64> {
    let table = cabc_runfolder::Table::read(&dir.join(cabc_runfolder::METRICS)).ok()?;
    let seconds: f64 = table
        .parsed::<f64>("epoch_s")
        .ok()?
        .into_iter()
        .flatten()
        .sum();
    Some(seconds / 60.0)
}

/// An ended run's wall clock, with what the estimate of a run left matches it on.
struct Took {
    group: String,
    method: &'static str,
    preset: String,
    epochs: Option<u32>,
    minutes: f64,
}

/// The report of `cabc campaign status`: per slice its runs and their states, then the counts and about how long
/// what is left takes one lane: each run left is estimated by the median wall clock of the ended runs of its group
/// and method, else of those of its preset, epoch cap and method, else of all; a run in progress less what it ran.
pub fn status(root: &Path, plan: &Plan) -> String {
    let mut out = String::new();
    let (mut ended_n, mut progress_n, mut not_n) = (0, 0, 0);
    let mut took: Vec<Took> = Vec::new();
    // Each run left: its slice, its name and the minutes it has run.
    let mut left: Vec<(&crate::plan::Slice, RunName, f64)> = Vec::new();
    for (i, slice) in plan.slices.iter().enumerate() {
        writeln!(out, "slice {i}: {slice}").unwrap();
        for run in slice.runs() {
            let name = run.to_string();
            let here = root.join("runs").join(&name);
            let what = match run_state(root, &run) {
                RunState::Ended(how) => {
                    ended_n += 1;
                    let minutes = wall_minutes(&here)
                        .or_else(|| wall_minutes(&root.join(RESULTS_DIR).join(&name)));
                    took.extend(minutes.map(|minutes| Took {
                        group: run.group().to_string(),
                        method: run.method(),
                        preset: slice.preset.clone(),
                        epochs: slice.epochs,
                        minutes,
                    }));
                    format!("ended, {how}")
                }
                RunState::InProgress(epochs) => {
                    progress_n += 1;
                    left.push((slice, run.clone(), wall_minutes(&here).unwrap_or(0.0)));
                    format!("in progress, {epochs} epochs")
                }
                RunState::NotStarted => {
                    not_n += 1;
                    left.push((slice, run.clone(), 0.0));
                    "not started".into()
                }
            };
            writeln!(out, "  {run}: {what}").unwrap();
        }
    }
    write!(
        out,
        "runs: {ended_n} ended, {progress_n} in progress, {not_n} not started"
    )
    .unwrap();
    let estimate = |slice: &crate::plan::Slice, run: &RunName| {
        let like = |same: &dyn Fn(&Took) -> bool| {
            let minutes: Vec<f64> = took.iter().filter(|t| same(t)).map(|t| t.minutes).collect();
            cabc_proto::stats::median_of_middles(&minutes)
        };
        like(&|t| t.group == run.group() && t.method == run.method())
            .or_else(|| {
                like(&|t| {
                    t.preset == slice.preset && t.epochs == slice.epochs && t.method == run.method()
                })
            })
            .or_else(|| like(&|_| true))
    };
    let minutes: Option<f64> = left
        .iter()
        .map(|(slice, run, ran)| estimate(slice, run).map(|m| (m - ran).max(0.0)))
        .sum();
    match minutes {
        Some(minutes) if !left.is_empty() => writeln!(
            out,
            "; what is left takes about {:.1} h of one lane (each run as the ended runs of its group, else of its \
             preset and epochs: the median of their wall clock)",
            minutes / 60.0
        ),
        _ => writeln!(out),
    }
    .unwrap();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes `text` to `path` under `root`, with its folders.
    fn write_under(root: &Path, path: &str, text: &str) {
        let path = root.join(path);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }

    #[test]
    fn states_from_the_folders() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        let write = |path: &str, text: &str| write_under(root, path, text);
        // s1: ended here; s2: its summary says interrupted, with a checkpoint and 3 epochs; s3: ended on another
        // machine (docs/reproduction); s4: interrupted in both, no checkpoint; s5: nothing.
        write(
            "runs/g-s1/summary.json",
            "{\n  \"ended\": \"early-stop\"\n}",
        );
        write("runs/g-s2/summary.json", "{\"ended\": \"interrupted\"}");
        write(
            "runs/g-s2/metrics.csv",
            "epoch,epoch_s\n1,120\n2,120\n3,120\n",
        );
        std::fs::create_dir_all(root.join("runs/g-s2/checkpoint.old")).unwrap();
        write(
            "docs/reproduction/g-s3/summary.json",
            "{\"ended\": \"max-epochs\"}",
        );
        // The ended runs' epochs: s1's 30 minutes here, s3's 90 in docs/reproduction (its runs/ copy is empty).
        write("runs/g-s1/metrics.csv", "epoch_s,epoch\n900,0\n900,1\n");
        write(
            "docs/reproduction/g-s3/metrics.csv",
            "epoch,epoch_s\n0,5400\n",
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
             runs: 2 ended, 1 in progress, 2 not started; what is left takes about 2.9 h of one lane (each run as \
             the ended runs of its group, else of its preset and epochs: the median of their wall clock)\n"
        );
    }

    /// A run whose group has not ended a run yet is estimated by the ended runs of its preset and epoch cap.
    #[test]
    fn a_new_group_is_estimated_by_its_preset_and_epochs() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        let write = |path: &str, text: &str| write_under(root, path, text);
        // g-a-s1 (epochs 10) took 6 minutes, g-s1 (epochs 20) 30: g-b-s1 (epochs 20) is estimated at 30.
        for (run, seconds) in [("g-a-s1", 360), ("g-s1", 1800)] {
            write(
                &format!("runs/{run}/summary.json"),
                "{\"ended\": \"max-epochs\"}",
            );
            write(
                &format!("runs/{run}/metrics.csv"),
                &format!("epoch,epoch_s\n0,{seconds}\n"),
            );
        }
        let plan = Plan::parse(
            "[[block]]\nseeds = [1]\nslices = [\
             { preset = \"g\", methods = [\"proposed\"], tag = \"a\", epochs = 10 },\
             { preset = \"g\", methods = [\"proposed\"], epochs = 20 },\
             { preset = \"g\", methods = [\"proposed\"], tag = \"b\", epochs = 20 }]",
        )
        .unwrap();
        let report = status(root, &plan);
        assert!(
            report.ends_with("runs: 2 ended, 0 in progress, 1 not started; what is left takes about 0.5 h of one lane (each run as the ended runs of its group, else of its preset and epochs: the median of their wall clock)\n"),
            "{report}"
        );
    }
}
