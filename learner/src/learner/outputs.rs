//! What the learner writes besides its checkpoint, as it goes: the tables and plots, TensorBoard's events, the
//! evaluations' videos, and the access-control drops it warns about.

use super::{Learner, LearnerError};
use crate::plots;
use cabc_proto::messages::EvalReport;

impl Learner {
    /// Writes `(tag, value)` scalars of `step` under `group/` to the TensorBoard events; a failure is logged once and
    /// ends the events (the CSV tables stay).
    pub(super) fn record_scalars(&mut self, step: u64, group: &str, scalars: &[(&str, f32)]) {
        let Some(tb) = &mut self.tb else { return };
        let tagged: Vec<(String, f32)> = scalars
            .iter()
            .map(|(name, v)| (format!("{group}/{name}"), *v))
            .collect();
        let refs: Vec<(&str, f32)> = tagged.iter().map(|(t, v)| (t.as_str(), *v)).collect();
        if let Err(e) = tb.scalars(step, &refs) {
            tracing::warn!("writing TensorBoard events: {e}; no more are written");
            self.tb = None;
        }
    }

    /// Warns when the router's access control dropped messages since the last epoch (zenoh logs its decisions only
    /// at TRACE): an operator under attack sees who tried what.
    pub(super) fn report_denials(&mut self, epoch: u64) {
        let by = cabc_proto::telemetry::acl_denials();
        let total: u64 = by.values().sum();
        if total > self.acl_denied {
            tracing::warn!(
                epoch,
                new = total - self.acl_denied,
                total,
                "the access control dropped messages: {by:?}"
            );
            self.acl_denied = total;
        }
    }

    /// A video of an evaluation that completed the laps (`plots/eval-v<version>.gif`), also `best-policy.gif` when
    /// it is the best so far; a failure is logged.
    pub(super) fn eval_video(&self, report: &EvalReport, best: bool) {
        let plots = self.run_dir.plots();
        let path = plots.join(format!("eval-v{}.gif", report.version));
        let written = std::fs::create_dir_all(&plots)
            .map_err(|e| e.to_string())
            .and_then(|_| crate::video::eval_gif(&path, report).map_err(|e| e.to_string()))
            .and_then(|_| match best {
                true => std::fs::copy(&path, self.run_dir.path().join("best-policy.gif"))
                    .map(|_| ())
                    .map_err(|e| e.to_string()),
                false => Ok(()),
            });
        if let Err(e) = written {
            tracing::warn!(version = report.version, "the evaluation's video: {e}");
        }
    }

    pub(super) fn write_outputs(&self, final_: bool) -> Result<(), LearnerError> {
        self.run_dir.write_tables(&self.state)?;
        if let Err(e) = plots::draw_all(
            &self.run_dir.plots(),
            &self.state,
            self.last_eval.as_ref(),
            self.config.collection.eval_laps,
        ) {
            tracing::warn!("drawing plots: {e}");
        }
        if final_ {
            self.run_dir
                .write_file("final-policy.safetensors", &self.trainer.policy_bytes())?;
        }
        Ok(())
    }
}
