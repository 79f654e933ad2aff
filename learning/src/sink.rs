//! The port the learner writes everything but its checkpoint through ([`Sink`], Acme's injected logger): each
//! epoch's [`Record`], the evaluations taken in, the phase of an epoch, how its collection closed and the run's end;
//! and [`Sinks`], several as one. The sinks are given to the learner when it is made: the run folder's files,
//! TensorBoard and the progress bar (the cabc-outputs crate), the bus's metrics in a distributed run (the `learner`
//! binary).

use crate::evaluations::{EvalSummary, Taken};
use crate::record::Record;
use crate::summary::Summary;
use cabc_proto::messages::EvalReport;
use cabc_proto::ports::Collected;

/// A sink's failure (a file not written).
#[derive(Debug, thiserror::Error)]
#[error("{what}: {source}")]
pub struct SinkError {
    pub what: String,
    pub source: Box<dyn std::error::Error + Send + Sync>,
}

/// What a run has written so far: every epoch's record, every evaluation taken in (the last one's report whole) and
/// the expert's lap times. [`Sink::open`] gives it to the sinks (empty for a fresh run, the checkpoint's for a
/// resumed one); a sink that needs it later (the run folder's tables and plots) keeps its own from the events that
/// follow ([`History::record`], [`History::evaluation`], [`History::expert_lap`]).
#[derive(Debug, Clone, Default)]
pub struct History {
    pub rows: Vec<Record>,
    pub evals: Vec<EvalSummary>,
    pub last_eval: Option<EvalReport>,
    pub expert_lap_times: Vec<f64>,
}

impl History {
    /// The epoch the run goes on with.
    pub fn next_epoch(&self) -> u64 {
        self.rows.last().map_or(0, |r| r.epoch() + 1)
    }

    /// [`Sink::write`]'s record, appended.
    pub fn record(&mut self, record: &Record) {
        self.rows.push(record.clone());
    }

    /// [`Sink::evaluation`]'s, appended.
    pub fn evaluation(&mut self, taken: &Taken<'_>) {
        self.evals.push(taken.summary.clone());
        self.last_eval = Some(taken.report.clone());
    }

    /// [`Sink::expert_lap`]'s, appended.
    pub fn expert_lap(&mut self, seconds: f64) {
        self.expert_lap_times.push(seconds);
    }
}

/// The port the learner writes its outputs through (Acme's logger): events, each given once, in the order they
/// happen (the run opens; per epoch its phases, how its collection closed, the expert's laps and the evaluations
/// taken in, then its record; the run closes). A sink sees no learner state: what it needs of the past it keeps
/// itself ([`History`]). The sinks: `metrics.csv` and the run folder's other files, TensorBoard's events, the
/// progress bar (the cabc-outputs crate), the bus's JSON metrics (the `learner` binary's).
pub trait Sink {
    /// The run starts, fresh or resumed with `history` (what was written before).
    fn open(&mut self, _history: &History) {}
    /// A phase of epoch `epoch` begins (collecting, auto-labelling, training).
    fn phase(&mut self, _epoch: u64, _phase: &str) {}
    /// The collection of epoch `epoch` closed: the actors' counts and who was alive (its counts are in the record).
    fn collected(&mut self, _epoch: u64, _collected: &Collected) {}
    /// A lap driven by the expert alone (beta = 1), in seconds.
    fn expert_lap(&mut self, _seconds: f64) {}
    /// An evaluation taken in.
    fn evaluation(&mut self, _taken: &Taken<'_>) {}
    /// An epoch's record, complete and checkpointed.
    fn write(&mut self, record: &Record) -> Result<(), SinkError>;
    /// The run ends with `summary`; `final_policy`: the policy's weights, unless the run was interrupted.
    fn close(&mut self, _summary: &Summary, _final_policy: Option<&[u8]>) -> Result<(), SinkError> {
        Ok(())
    }
}

/// Several sinks as one, each given everything in turn (a failing one does not keep the others from writing: the
/// first error is returned).
#[derive(Default)]
pub struct Sinks(pub Vec<Box<dyn Sink>>);

impl Sink for Sinks {
    fn open(&mut self, history: &History) {
        self.0.iter_mut().for_each(|s| s.open(history));
    }

    fn phase(&mut self, epoch: u64, phase: &str) {
        self.0.iter_mut().for_each(|s| s.phase(epoch, phase));
    }

    fn collected(&mut self, epoch: u64, collected: &Collected) {
        self.0
            .iter_mut()
            .for_each(|s| s.collected(epoch, collected));
    }

    fn expert_lap(&mut self, seconds: f64) {
        self.0.iter_mut().for_each(|s| s.expert_lap(seconds));
    }

    fn evaluation(&mut self, taken: &Taken<'_>) {
        self.0.iter_mut().for_each(|s| s.evaluation(taken));
    }

    fn write(&mut self, record: &Record) -> Result<(), SinkError> {
        self.0
            .iter_mut()
            .map(|s| s.write(record))
            .fold(Ok(()), Result::and)
    }

    fn close(&mut self, summary: &Summary, final_policy: Option<&[u8]>) -> Result<(), SinkError> {
        self.0
            .iter_mut()
            .map(|s| s.close(summary, final_policy))
            .fold(Ok(()), Result::and)
    }
}
