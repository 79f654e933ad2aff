//! The port the learner writes everything but its checkpoint through ([`Sink`], Acme's injected logger): each
//! epoch's [`Record`], the evaluations taken in, the phase of an epoch and the run's end; [`Sinks`], several as one;
//! and [`Bus`], the sink of the actors' port's metrics (the other sinks, the run folder's files, TensorBoard and the
//! progress bar, are the cabc-outputs crate's).

use crate::evaluations::Taken;
use crate::record::Record;
use crate::state::LearnerState;
use cabc_proto::ports::Rollouts;
use serde_json::json;

/// A sink's failure (a file not written).
#[derive(Debug, thiserror::Error)]
#[error("{what}: {source}")]
pub struct SinkError {
    pub what: String,
    pub source: Box<dyn std::error::Error + Send + Sync>,
}

/// The port the learner writes its outputs through (Acme's logger): each epoch's record, the evaluations, the
/// phase of an epoch and the run's end. The sinks (the cabc-outputs crate, and [`Bus`] here): `metrics.csv` and the run folder's other
/// files, TensorBoard's events, the bus's JSON metrics, the progress bar.
pub trait Sink {
    /// The run starts, fresh or resumed with `run` (the records so far).
    fn open(&mut self, _run: &LearnerState) {}
    /// A phase of epoch `epoch` begins (collecting, auto-labelling, training).
    fn phase(&mut self, _epoch: u64, _phase: &str) {}
    /// An epoch's record, complete and checkpointed; `run` holds it as its last row.
    fn write(&mut self, record: &Record, run: &LearnerState) -> Result<(), SinkError>;
    /// [`Sink::write`] of `run`'s last record (none: nothing to write).
    fn write_last(&mut self, run: &LearnerState) -> Result<(), SinkError> {
        match run.rows.last() {
            Some(record) => self.write(record, run),
            None => Ok(()),
        }
    }
    /// An evaluation taken in.
    fn evaluation(&mut self, _taken: &Taken<'_>) {}
    /// The run ends with `summary`; `final_policy`: the policy's weights, unless the run was interrupted.
    fn close(
        &mut self,
        _run: &LearnerState,
        _summary: &serde_json::Value,
        _final_policy: Option<&[u8]>,
    ) -> Result<(), SinkError> {
        Ok(())
    }
}

/// Several sinks as one, each given everything in turn (a failing one does not keep the others from writing: the
/// first error is returned).
#[derive(Default)]
pub struct Sinks(pub Vec<Box<dyn Sink>>);

impl Sink for Sinks {
    fn open(&mut self, run: &LearnerState) {
        self.0.iter_mut().for_each(|s| s.open(run));
    }

    fn phase(&mut self, epoch: u64, phase: &str) {
        self.0.iter_mut().for_each(|s| s.phase(epoch, phase));
    }

    fn write(&mut self, record: &Record, run: &LearnerState) -> Result<(), SinkError> {
        self.0
            .iter_mut()
            .map(|s| s.write(record, run))
            .fold(Ok(()), Result::and)
    }

    fn evaluation(&mut self, taken: &Taken<'_>) {
        self.0.iter_mut().for_each(|s| s.evaluation(taken));
    }

    fn close(
        &mut self,
        run: &LearnerState,
        summary: &serde_json::Value,
        final_policy: Option<&[u8]>,
    ) -> Result<(), SinkError> {
        self.0
            .iter_mut()
            .map(|s| s.close(run, summary, final_policy))
            .fold(Ok(()), Result::and)
    }
}

/// The bus's metrics (`metrics/learner`): each record as JSON, with the actors alive at the epoch's end and the
/// messages the bus refused so far, for people watching the run.
pub struct Bus<'a> {
    pub actors: &'a mut dyn Rollouts,
    pub live: &'a [String],
}

impl Sink for Bus<'_> {
    fn write(&mut self, record: &Record, _run: &LearnerState) -> Result<(), SinkError> {
        let json = json!({
            "epoch": record.epoch(),
            "row": record.to_json(),
            "live_actors": self.live,
            "rejected_messages": self.actors.rejected(),
        });
        self.actors.metrics(&json.to_string());
        Ok(())
    }
}
