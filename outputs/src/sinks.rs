//! The sinks of the learner's records (`cabc_learning::sink::Sink`): the run folder's files ([`RunFolder`]: `metrics.csv`,
//! `evals.csv`, plots, evaluation videos, the best and final policies, `summary.json`), TensorBoard's events
//! ([`Tensorboard`]) and the progress bar ([`Progress`]) (the bus's JSON metrics are the `learner` binary's sink);
//! and [`learner`], the learner of a run folder with the three ([`learner_on_bus`]: and the bus's).

use crate::plots;
use crate::rundir::{KeptPolicy, RunDir};
use crate::tensorboard::EventWriter;
use crate::video::{eval_gif, CameraView};
use cabc_learning::evaluations::{EvalSummary, Taken};
use cabc_learning::learner::{AclDenials, Learner, LearnerError};
use cabc_learning::record::Record;
use cabc_learning::sink::{History, Sink, SinkError, Sinks};
use cabc_learning::summary::Summary;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::EvalReport;
use cabc_sim::track::Track;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::BTreeMap;

/// The learner of `run_dir` (its checkpoint there) in one process (a test, `learner run --local`), writing the run
/// folder's files, TensorBoard's events in `tb/` and the progress bar. No bus: no access control refuses anything.
pub fn learner(config: RunConfig, run_dir: RunDir, resume: bool) -> Result<Learner, LearnerError> {
    open(config, run_dir, resume, None, Box::new(BTreeMap::new))
}

/// [`learner`] of a distributed run: `metrics`, the bus's sink, writes each record after the run folder's sinks,
/// and the access control's refusals are read from `acl_denials` (both the bus side's, the `learner` binary's).
pub fn learner_on_bus(
    config: RunConfig,
    run_dir: RunDir,
    resume: bool,
    metrics: Box<dyn Sink>,
    acl_denials: AclDenials,
) -> Result<Learner, LearnerError> {
    open(config, run_dir, resume, Some(metrics), acl_denials)
}

fn open(
    config: RunConfig,
    run_dir: RunDir,
    resume: bool,
    bus: Option<Box<dyn Sink>>,
    acl_denials: AclDenials,
) -> Result<Learner, LearnerError> {
    let folder = run_dir.path().to_path_buf();
    let mut sinks: Vec<Box<dyn Sink>> = vec![
        Box::new(RunFolder::new(run_dir.clone(), &config)?),
        Box::new(Tensorboard::new(&run_dir)),
        Box::new(Progress::new(config.run.max_epochs)),
    ];
    sinks.extend(bus);
    Learner::open(config, folder, Box::new(Sinks(sinks)), acl_denials, resume)
}

fn failed(what: &str, e: impl std::error::Error + Send + Sync + 'static) -> SinkError {
    SinkError {
        what: what.to_string(),
        source: Box::new(e),
    }
}

/// The run folder's files: the tables (rewritten from the state after each epoch, so a resumed run's files stay
/// consistent with its checkpoint) and plots, an evaluation's video, the best and final policies, the summary.
pub struct RunFolder {
    run_dir: RunDir,
    /// `collection.eval_laps`, drawn on the laps plot.
    eval_laps: u32,
    /// The run's track (`sim.track`), under the line plot and the videos.
    track: Track,
    /// A camera run's camera, drawn beside the track in the videos.
    camera: Option<CameraView>,
    /// What the tables and plots are drawn from, kept from the sink's events.
    history: History,
}

impl RunFolder {
    /// The run folder's outputs on the run's track; an error when the track (`sim.track`) cannot be built.
    pub fn new(run_dir: RunDir, config: &RunConfig) -> Result<Self, cabc_sim::TrackError> {
        let track = Track::of(&config.sim)?.as_ref().clone();
        Ok(RunFolder {
            run_dir,
            eval_laps: config.collection.eval_laps,
            camera: CameraView::of(&config.observation, &track),
            track,
            history: History::default(),
        })
    }

    fn tables_and_plots(&self) -> Result<(), SinkError> {
        let run = &self.history;
        self.run_dir
            .write_tables(&run.rows, &run.evals)
            .map_err(|e| failed("the tables", e))?;
        if let Err(e) = plots::draw_all(&self.run_dir.plots(), run, self.eval_laps, &self.track) {
            tracing::warn!("drawing plots: {e}");
        }
        Ok(())
    }

    /// A video of an evaluation that completed the laps (`plots/eval-v<version>.gif`), also `best-policy.gif` when
    /// it is the best so far; a failure is logged.
    fn video(&mut self, report: &EvalReport, best: bool) {
        let plots = self.run_dir.plots();
        let path = self.run_dir.path().join(RunDir::eval_video(report.version));
        let best_video = self
            .run_dir
            .path()
            .join(RunDir::policy_video(KeptPolicy::Best));
        let written = std::fs::create_dir_all(&plots)
            .map_err(|e| e.to_string())
            .and_then(|_| {
                eval_gif(&path, &self.track, report, self.camera.as_mut())
                    .map_err(|e| e.to_string())
            })
            .and_then(|_| match best {
                true => std::fs::copy(&path, &best_video)
                    .map(|_| ())
                    .map_err(|e| e.to_string()),
                false => Ok(()),
            });
        if let Err(e) = written {
            tracing::warn!(version = report.version, "the evaluation's video: {e}");
        }
    }
}

impl Sink for RunFolder {
    fn open(&mut self, history: &History) {
        self.history = history.clone();
    }

    fn expert_lap(&mut self, seconds: f64) {
        self.history.expert_lap(seconds);
    }

    fn write(&mut self, record: &Record) -> Result<(), SinkError> {
        self.history.record(record);
        self.tables_and_plots()
    }

    fn evaluation(&mut self, taken: &Taken<'_>) {
        self.history.evaluation(taken);
        if taken.completed {
            self.video(taken.report, taken.best);
        }
        if let Some(weights) = taken.weights {
            if let Err(e) = self.run_dir.write_policy(KeptPolicy::Best, weights) {
                tracing::warn!("saving the best policy: {e}");
            }
        }
    }

    fn close(&mut self, summary: &Summary, final_policy: Option<&[u8]>) -> Result<(), SinkError> {
        if let Some(weights) = final_policy {
            self.tables_and_plots()?;
            self.run_dir
                .write_policy(KeptPolicy::Final, weights)
                .map_err(|e| failed("the final policy", e))?;
        }
        self.run_dir
            .write_summary(summary)
            .map_err(|e| failed("the summary", e))
    }
}

/// TensorBoard's events in the run folder's `tb/`: every metric of a record under `metrics/` at its epoch, and each
/// evaluation's laps and lap time under `eval/` at its version. The file is created when the run starts; a failure
/// is logged once and ends the events (the CSV tables stay).
pub struct Tensorboard {
    dir: std::path::PathBuf,
    events: Option<EventWriter>,
}

impl Tensorboard {
    pub fn new(run_dir: &RunDir) -> Self {
        Tensorboard {
            dir: run_dir.path().join("tb"),
            events: None,
        }
    }

    fn scalars(&mut self, step: u64, group: &str, scalars: impl Iterator<Item = (String, f64)>) {
        let Some(events) = &mut self.events else {
            return;
        };
        let tagged: Vec<(String, f32)> = scalars
            .map(|(name, v)| (format!("{group}/{name}"), v as f32))
            .collect();
        let refs: Vec<(&str, f32)> = tagged.iter().map(|(t, v)| (t.as_str(), *v)).collect();
        if let Err(e) = events.scalars(step, &refs) {
            tracing::warn!("writing TensorBoard events: {e}; no more are written");
            self.events = None;
        }
    }
}

impl Sink for Tensorboard {
    fn open(&mut self, _history: &History) {
        self.events = EventWriter::create(&self.dir)
            .map_err(|e| tracing::warn!("no TensorBoard events: {e}"))
            .ok();
    }

    fn write(&mut self, record: &Record) -> Result<(), SinkError> {
        let scalars = record
            .iter()
            .map(|(name, v)| (name.to_string(), v.as_f64()));
        self.scalars(record.epoch(), "metrics", scalars);
        Ok(())
    }

    fn evaluation(&mut self, taken: &Taken<'_>) {
        let s = taken.summary;
        let scalars = [
            ("laps", Some(s.laps as f64)),
            ("lap_mean", s.lap_mean),
            ("lap_std", s.lap_std),
        ];
        let scalars = scalars
            .into_iter()
            .filter_map(|(name, v)| Some((name.to_string(), v?)));
        self.scalars(s.version, "eval", scalars);
    }
}

/// The progress bar: the epoch of the budget and the time elapsed, the phase, and the last record's beta, D+, D?,
/// D-, time per epoch and evaluation; with `short_lines` (a terminal that shows the learner's warnings alone,
/// [`cabc_proto::telemetry::brief`]), one line above the bar per evaluation that completes laps. indicatif draws
/// nothing where stderr is not a terminal.
pub struct Progress {
    bar: ProgressBar,
    /// The last record, as the bar shows it.
    last: String,
    short_lines: bool,
}

impl Progress {
    /// The bar on stderr, with short lines when the process's terminal is brief.
    pub fn new(epochs: u64) -> Self {
        Progress::on(
            epochs,
            ProgressDrawTarget::stderr(),
            cabc_proto::telemetry::brief(),
        )
    }

    /// The bar on `target`.
    pub fn on(epochs: u64, target: ProgressDrawTarget, short_lines: bool) -> Self {
        let bar = ProgressBar::with_draw_target(Some(epochs), target);
        bar.set_style(
            ProgressStyle::with_template("{elapsed_precise} epoch {pos}/{len} {bar:30} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        Progress {
            bar,
            last: String::new(),
            short_lines,
        }
    }

    /// The short line of an evaluation: its version, laps and mean lap time, and the crashes of the early stop's
    /// episodes from random spawns when it drove some (`collection.early_stop_spawns`).
    fn short_line(s: &EvalSummary) -> String {
        let lap = s
            .lap_mean
            .map(|m| format!(", {m:.2} s a lap"))
            .unwrap_or_default();
        let spawns = match s.spawn_episodes {
            0 => String::new(),
            n => format!("; {} of {n} random spawns crashed", s.spawn_crashes),
        };
        format!("version {}: {} laps{lap}{spawns}", s.version, s.laps)
    }
}

impl Sink for Progress {
    fn open(&mut self, history: &History) {
        self.bar.set_position(history.next_epoch());
    }

    fn phase(&mut self, _epoch: u64, phase: &str) {
        self.bar.set_message(format!("{phase}{}", self.last));
    }

    fn write(&mut self, r: &Record) -> Result<(), SinkError> {
        let n = |name| r.u64(name).unwrap_or(0);
        let eval = match (r.u64("eval_version"), r.u64("eval_laps")) {
            (Some(v), Some(laps)) => format!("v{v}: {laps} laps"),
            _ => "none".into(),
        };
        self.last = format!(
            " | {:.1} s/epoch | beta {:.3} | D+ {} D? {} D- {} | last eval {eval}",
            r.f64("epoch_s").unwrap_or(f64::NAN),
            r.f64("beta").unwrap_or(f64::NAN),
            n("d_plus"),
            n("d_uncertain"),
            n("d_minus")
        );
        self.bar.set_position(r.epoch() + 1);
        self.bar
            .set_message(self.last.trim_start_matches(" | ").to_string());
        Ok(())
    }

    fn evaluation(&mut self, taken: &Taken<'_>) {
        if self.short_lines && taken.summary.laps > 0 {
            self.bar.println(Progress::short_line(taken.summary));
        }
    }

    fn close(&mut self, _: &Summary, _: Option<&[u8]>) -> Result<(), SinkError> {
        self.bar.finish_and_clear();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_learning::evaluations::EvalSummary;
    use cabc_proto::messages::EndReason;
    use indicatif::InMemoryTerm;

    fn report(version: u64, laps: u32) -> EvalReport {
        EvalReport {
            actor: "eval".into(),
            version,
            laps,
            lap_times: vec![5.0; laps as usize],
            end_reason: EndReason::OutOfTrack,
            steps: 40,
            line: (0..40).map(|i| [i as f32 * 0.05, 0.0]).collect(),
            spawn_episodes: 0,
            spawn_crashes: 0,
        }
    }

    fn record(epoch: u64) -> Record {
        let mut r = Record::new(epoch);
        r.real("imitation_loss", 0.5, 6);
        r
    }

    /// The run folder keeps what its tables and plots need from the events alone: a resumed run's history, then
    /// the evaluations and records that follow, in metrics.csv, evals.csv and the plots.
    #[test]
    fn the_run_folder_draws_from_its_events() {
        let dir = tempfile::tempdir().unwrap();
        let run_dir = RunDir::create(dir.path()).unwrap();
        let config = RunConfig::load("smoke").unwrap();
        let mut folder = RunFolder::new(run_dir.clone(), &config).unwrap();
        let before = report(1, 0);
        folder.open(&History {
            rows: vec![record(0), record(1)],
            evals: vec![EvalSummary::of(&before)],
            last_eval: Some(before),
            expert_lap_times: vec![4.8],
        });
        folder.expert_lap(4.9);
        let after = report(2, 1);
        folder.evaluation(&Taken {
            report: &after,
            summary: &EvalSummary::of(&after),
            best: true,
            completed: false,
            weights: None,
        });
        folder.write(&record(2)).unwrap();
        let metrics = std::fs::read_to_string(dir.path().join("metrics.csv")).unwrap();
        let epochs: Vec<&str> = metrics
            .lines()
            .skip(1)
            .map(|l| l.split(',').next().unwrap())
            .collect();
        assert_eq!(epochs, ["0", "1", "2"], "{metrics}");
        let evals = std::fs::read_to_string(dir.path().join("evals.csv")).unwrap();
        let versions: Vec<&str> = evals
            .lines()
            .skip(1)
            .map(|l| l.split(',').next().unwrap())
            .collect();
        assert_eq!(versions, ["1", "2"], "{evals}");
        assert_eq!(folder.history.expert_lap_times, [4.8, 4.9]);
        assert_eq!(
            folder.history.last_eval.as_ref().map(|r| r.version),
            Some(2)
        );
        for plot in ["laps.png", "losses.png", "lap_times.png", "line.png"] {
            assert!(run_dir.plots().join(plot).is_file(), "{plot}");
        }
    }

    /// Issue 59 item 4: on a brief terminal the bar shows the epoch of the budget, the time per epoch, beta, D+, D?,
    /// D- and the last evaluation, and one short line per evaluation that completes laps (none for one that does
    /// not); without short lines (a terminal that shows the log lines) an evaluation adds no line.
    #[test]
    fn the_progress_bar_shows_the_run_and_one_line_per_evaluation_with_laps() {
        for short_lines in [true, false] {
            let term = InMemoryTerm::new(10, 160);
            let mut progress = Progress::on(
                200,
                ProgressDrawTarget::term_like(Box::new(term.clone())),
                short_lines,
            );
            let mut r = record(2);
            r.real("epoch_s", 4.31, 3);
            r.real("beta", 0.857375, 4);
            r.count("d_plus", 1200);
            r.count("d_uncertain", 7);
            r.count("d_minus", 3);
            r.count("eval_version", 2);
            r.count("eval_laps", 0);
            progress.write(&r).unwrap();
            let judged = EvalReport {
                spawn_episodes: 5,
                spawn_crashes: 1,
                ..report(4, 50)
            };
            for report in [report(2, 0), report(3, 50), judged] {
                progress.evaluation(&Taken {
                    report: &report,
                    summary: &EvalSummary::of(&report),
                    best: true,
                    completed: false,
                    weights: None,
                });
            }
            progress.bar.tick();
            let screen = term.contents();
            assert!(screen.contains("epoch 3/200"), "{screen}");
            assert!(
                screen.contains(
                    "4.3 s/epoch | beta 0.857 | D+ 1200 D? 7 D- 3 | last eval v2: 0 laps"
                ),
                "{screen}"
            );
            assert_eq!(
                screen.contains("version 3: 50 laps, 5.00 s a lap"),
                short_lines,
                "{screen}"
            );
            assert_eq!(
                screen.contains("version 4: 50 laps, 5.00 s a lap; 1 of 5 random spawns crashed"),
                short_lines,
                "{screen}"
            );
            assert!(!screen.contains("version 2:"), "{screen}");
        }
    }
}
