//! Where the points that enter D? come from, counted per epoch for `metrics.csv`: the protocol differences between
//! ours and the reference (issue 18) change exactly these numbers, so a run shows which of them fed its critic.

use cabc_proto::config::Flush;
use cabc_proto::messages::{EndReason, Outcome, Segment, STATE_DIM};
use serde::{Deserialize, Serialize};

/// Steps that entered D? in one epoch, by origin. Every D? step is counted once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// The step whose transition truncated the episode (`collection.flush = "with-step"` only; the reference drops
    /// it), when it started on the track.
    pub truncating: u64,
    /// A truncating step that started off the track: a random spawn outside the track (x_tran beyond the
    /// half-width), whose single step is the whole episode.
    pub spawn: u64,
    /// The staged steps of an episode the expert ended (`expert.patience` failures in a row).
    pub patience: u64,
    /// The other steps of a failed episode: the lap that ended in a truncation.
    pub failed_lap: u64,
    /// Steps at which the expert failed (each goes to D? on its own): the expert's failures.
    pub expert_failures: u64,
}

impl Provenance {
    /// Counts the D? steps of `segment` (a segment of D_new; laps and incomplete segments add nothing, nor do steps
    /// that a store does not take). `half_width` is the track's.
    pub fn add(&mut self, segment: &Segment, flush: Flush, half_width: f64) {
        let n = segment.steps.len() as u64;
        match segment.outcome {
            Outcome::Lap | Outcome::Incomplete => {}
            Outcome::ExpertFailure => self.expert_failures += n,
            Outcome::Failure(EndReason::ExpertFailure) => self.patience += n,
            Outcome::Failure(_) => {
                let last = match (flush, segment.steps.last()) {
                    (Flush::WithStep, Some(last)) => last,
                    _ => {
                        self.failed_lap += n;
                        return;
                    }
                };
                if off_track(&last.state, half_width) {
                    self.spawn += 1;
                } else {
                    self.truncating += 1;
                }
                self.failed_lap += n - 1;
            }
        }
    }
}

/// Whether a state lies off the track: |x_tran| beyond the half-width.
fn off_track(state: &[f32; STATE_DIM], half_width: f64) -> bool {
    (state[4] as f64).abs() > half_width
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Step;

    fn segment(outcome: Outcome, x_trans: &[f32]) -> Segment {
        let step = |x: f32| Step {
            state: [1.0, 0.0, 0.0, 0.0, x, 0.0],
            pose: [0.0; 3],
            image: None,
            expert_action: [0.0; 2],
            applied_action: [0.0; 2],
            next_state: [1.0, 0.0, 0.0, 0.1, x, 0.0],
            expert_ok: true,
        };
        Segment::of("a", outcome, x_trans.iter().map(|&x| step(x)).collect())
    }

    #[test]
    fn each_d_uncertain_step_is_counted_once_by_origin() {
        let out = Outcome::Failure(EndReason::OutOfTrack);
        let mut p = Provenance::default();
        p.add(&segment(out, &[0.7]), Flush::WithStep, 0.55);
        assert_eq!(
            (p.spawn, p.truncating, p.failed_lap),
            (1, 0, 0),
            "an off-track spawn"
        );
        p.add(&segment(out, &[0.0, 0.2, 0.5]), Flush::WithStep, 0.55);
        assert_eq!((p.spawn, p.truncating, p.failed_lap), (1, 1, 2));
        p.add(&segment(out, &[0.0, 0.2]), Flush::BeforeStep, 0.55);
        assert_eq!(
            (p.truncating, p.failed_lap),
            (1, 4),
            "no truncating step is stored before-step"
        );
        p.add(
            &segment(Outcome::Failure(EndReason::ExpertFailure), &[0.0; 3]),
            Flush::WithStep,
            0.55,
        );
        p.add(
            &segment(Outcome::ExpertFailure, &[0.0]),
            Flush::WithStep,
            0.55,
        );
        p.add(&segment(Outcome::Lap, &[0.0; 9]), Flush::WithStep, 0.55);
        p.add(
            &segment(Outcome::Incomplete, &[0.0; 9]),
            Flush::WithStep,
            0.55,
        );
        assert_eq!((p.patience, p.expert_failures), (3, 1));
        let total = p.truncating + p.spawn + p.patience + p.failed_lap + p.expert_failures;
        assert_eq!(total, 1 + 3 + 2 + 3 + 1);
    }
}
