//! The segmenter (an "adder" in Acme's words): turns one environment's stream of steps into the segments the
//! learner stores, exactly as algorithm.md 2:
//!
//! * a completed lap flushes the staged steps as a [`Outcome::Lap`] segment (D+);
//! * a truncation flushes them as [`Outcome::Failure`] (D?), except the max-laps truncation, which ends an episode
//!   that did not fail: its staged steps (the one after the last lap) are flushed as [`Outcome::Incomplete`];
//! * a step at which the expert failed goes straight to D? as its own [`Outcome::ExpertFailure`] segment, and after
//!   `patience` consecutive failures the episode is truncated ([`EndReason::ExpertFailure`]);
//! * steps still staged when the epoch's budget runs out are flushed as [`Outcome::Incomplete`] (the reference drops
//!   them; kept here for the dynamics model, never labelled).
//!
//! One deliberate difference from the reference: the reference checks its flush *before* appending the current
//! frame, so the frame whose transition completes a lap lands in the next lap's staging, and the frame that
//! causes a truncation is dropped with the reset. Here the step belongs to the segment its transition ends: the
//! lap-completing step is part of the lap (its next state is safe by Definition 1) and the truncating step is part
//! of the failure.

use cabc_proto::config::{ExpertFailureStaged, Flush};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};

/// Where a step's episode stands after it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepEnd {
    /// The episode goes on.
    Continue,
    /// A lap was completed on this step; the episode goes on.
    Lap,
    /// The episode was truncated on this step.
    Truncated(EndReason),
}

/// One environment's staging buffer.
#[derive(Debug)]
pub struct Segmenter {
    actor: String,
    env: u32,
    episode: u64,
    patience: u32,
    failures_in_a_row: u32,
    staged: Vec<Step>,
    flush: Flush,
    expert_failure_staged: ExpertFailureStaged,
    /// Steps dropped so far (the reference's rules: a truncating step, the staged steps of an episode the expert
    /// ended).
    pub dropped: u64,
}

/// Numbers the segments of one actor incarnation (its `seq`).
#[derive(Debug, Default)]
pub struct SeqCounter {
    /// The actor process's incarnation, carried by every segment.
    pub incarnation: u64,
    /// The next `seq`.
    pub next: u64,
}

impl SeqCounter {
    fn next(&mut self) -> u64 {
        self.next += 1;
        self.next - 1
    }
}

impl Segmenter {
    pub fn new(actor: &str, env: u32, patience: u32) -> Self {
        Segmenter {
            actor: actor.to_string(),
            env,
            episode: 0,
            patience: patience.max(1),
            failures_in_a_row: 0,
            staged: Vec::new(),
            flush: Flush::WithStep,
            expert_failure_staged: ExpertFailureStaged::Uncertain,
            dropped: 0,
        }
    }

    /// The same segmenter under the given rules (`collection.flush`, `collection.expert_failure_staged`).
    pub fn with_rules(mut self, flush: Flush, expert_failure_staged: ExpertFailureStaged) -> Self {
        self.flush = flush;
        self.expert_failure_staged = expert_failure_staged;
        self
    }

    pub fn episode(&self) -> u64 {
        self.episode
    }

    pub fn staged(&self) -> usize {
        self.staged.len()
    }

    fn cut(
        &mut self,
        outcome: Outcome,
        steps: Vec<Step>,
        version: u64,
        seq: &mut SeqCounter,
    ) -> Segment {
        Segment {
            actor: self.actor.clone(),
            env: self.env,
            episode: self.episode,
            incarnation: seq.incarnation,
            seq: seq.next(),
            policy_version: version,
            outcome,
            steps,
        }
    }

    /// Adds one step. Returns the segments it completes and whether the episode must end (reset) now: after a
    /// truncation by the environment, or when the expert failed `patience` times in a row.
    pub fn push(
        &mut self,
        step: Step,
        end: StepEnd,
        version: u64,
        seq: &mut SeqCounter,
        out: &mut Vec<Segment>,
    ) -> Option<EndReason> {
        let expert_ok = step.expert_ok;
        // With `before-step` a successful step is staged after the flush its end causes (the reference's add_frame).
        let mut held = None;
        if expert_ok {
            self.failures_in_a_row = 0;
            match self.flush {
                Flush::WithStep => self.staged.push(step),
                Flush::BeforeStep => held = Some(step),
            }
        } else {
            self.failures_in_a_row += 1;
            let seg = self.cut(Outcome::ExpertFailure, vec![step], version, seq);
            out.push(seg);
        }
        let end_reason = match end {
            StepEnd::Truncated(reason) => Some(reason),
            _ if self.failures_in_a_row >= self.patience => Some(EndReason::ExpertFailure),
            _ => None,
        };
        match (end, end_reason) {
            (_, Some(reason)) => {
                let steps = std::mem::take(&mut self.staged);
                // The reference discards what is staged when the expert failed on the ending step.
                let discard = !expert_ok
                    && self.expert_failure_staged == ExpertFailureStaged::Discard
                    && reason != EndReason::MaxLaps;
                if discard {
                    self.dropped += steps.len() as u64;
                } else if !steps.is_empty() {
                    let outcome = match reason {
                        EndReason::MaxLaps => Outcome::Incomplete,
                        reason => Outcome::Failure(reason),
                    };
                    let seg = self.cut(outcome, steps, version, seq);
                    out.push(seg);
                }
                // `before-step`: the truncating step was never staged; it goes with the reset.
                self.dropped += held.is_some() as u64;
                self.new_episode();
                Some(reason)
            }
            (StepEnd::Lap, None) => {
                let steps = std::mem::take(&mut self.staged);
                if !steps.is_empty() {
                    let seg = self.cut(Outcome::Lap, steps, version, seq);
                    out.push(seg);
                }
                // `before-step`: the lap-completing step opens the next lap.
                self.staged.extend(held);
                None
            }
            _ => {
                self.staged.extend(held);
                None
            }
        }
    }

    /// The budget ran out: flush what is staged as incomplete and start a new episode.
    pub fn finish(&mut self, version: u64, seq: &mut SeqCounter, out: &mut Vec<Segment>) {
        let steps = std::mem::take(&mut self.staged);
        if !steps.is_empty() {
            let seg = self.cut(Outcome::Incomplete, steps, version, seq);
            out.push(seg);
        }
        self.new_episode();
    }

    fn new_episode(&mut self) {
        self.episode += 1;
        self.failures_in_a_row = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(ok: bool, x: f32) -> Step {
        Step {
            state: [1.0, 0.0, 0.0, x, 0.0, 0.0],
            pose: [0.0; 3],
            image: None,
            expert_action: [0.0; 2],
            applied_action: [0.0; 2],
            next_state: [1.0, 0.0, 0.0, x + 0.1, 0.0, 0.0],
            expert_ok: ok,
        }
    }

    #[test]
    fn a_max_laps_truncation_is_not_a_failure() {
        let (mut s, mut seq, mut out) = (Segmenter::new("a", 0, 2), SeqCounter::default(), vec![]);
        s.push(step(true, 0.0), StepEnd::Lap, 1, &mut seq, &mut out);
        let end = StepEnd::Truncated(EndReason::MaxLaps);
        assert_eq!(
            s.push(step(true, 0.1), end, 1, &mut seq, &mut out),
            Some(EndReason::MaxLaps)
        );
        let outcomes: Vec<_> = out.iter().map(|s| s.outcome).collect();
        assert_eq!(outcomes, [Outcome::Lap, Outcome::Incomplete]);
        let end = StepEnd::Truncated(EndReason::OutOfTrack);
        s.push(step(true, 0.2), end, 1, &mut seq, &mut out);
        assert_eq!(out[2].outcome, Outcome::Failure(EndReason::OutOfTrack));
    }

    #[test]
    fn a_lap_flushes_to_d_plus_with_the_lap_step() {
        let (mut s, mut seq, mut out) = (Segmenter::new("a", 0, 2), SeqCounter::default(), vec![]);
        for i in 0..5 {
            assert_eq!(
                s.push(
                    step(true, i as f32),
                    StepEnd::Continue,
                    1,
                    &mut seq,
                    &mut out
                ),
                None
            );
        }
        assert_eq!(
            s.push(step(true, 5.0), StepEnd::Lap, 1, &mut seq, &mut out),
            None
        );
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].outcome, Outcome::Lap);
        assert_eq!(out[0].steps.len(), 6);
        assert_eq!(out[0].episode, 0);
        assert_eq!(s.staged(), 0);
    }

    #[test]
    fn a_truncation_flushes_to_d_uncertain_and_ends_the_episode() {
        let (mut s, mut seq, mut out) = (Segmenter::new("a", 0, 2), SeqCounter::default(), vec![]);
        s.push(step(true, 0.0), StepEnd::Continue, 1, &mut seq, &mut out);
        let end = s.push(
            step(true, 1.0),
            StepEnd::Truncated(EndReason::OutOfTrack),
            1,
            &mut seq,
            &mut out,
        );
        assert_eq!(end, Some(EndReason::OutOfTrack));
        assert_eq!(out[0].outcome, Outcome::Failure(EndReason::OutOfTrack));
        assert_eq!(out[0].steps.len(), 2);
        assert_eq!(s.episode(), 1);
    }

    #[test]
    fn expert_failures_go_straight_to_d_uncertain_and_patience_truncates() {
        let (mut s, mut seq, mut out) = (Segmenter::new("a", 0, 2), SeqCounter::default(), vec![]);
        s.push(step(true, 0.0), StepEnd::Continue, 1, &mut seq, &mut out);
        assert_eq!(
            s.push(step(false, 1.0), StepEnd::Continue, 1, &mut seq, &mut out),
            None
        );
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].outcome, Outcome::ExpertFailure);
        // A success in between resets the count.
        s.push(step(true, 2.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(step(false, 3.0), StepEnd::Continue, 1, &mut seq, &mut out);
        let end = s.push(step(false, 4.0), StepEnd::Continue, 1, &mut seq, &mut out);
        assert_eq!(end, Some(EndReason::ExpertFailure));
        let outcomes: Vec<_> = out.iter().map(|s| s.outcome).collect();
        assert_eq!(
            outcomes,
            [
                Outcome::ExpertFailure,
                Outcome::ExpertFailure,
                Outcome::ExpertFailure,
                Outcome::Failure(EndReason::ExpertFailure)
            ]
        );
        // Every step is in exactly one segment, and sequence numbers are consecutive.
        assert_eq!(out.iter().map(|s| s.steps.len()).sum::<usize>(), 5);
        assert_eq!(out.iter().map(|s| s.seq).collect::<Vec<_>>(), [0, 1, 2, 3]);
    }

    #[test]
    fn the_budget_end_flushes_incomplete() {
        let (mut s, mut seq, mut out) = (Segmenter::new("a", 3, 2), SeqCounter::default(), vec![]);
        s.push(step(true, 0.0), StepEnd::Continue, 4, &mut seq, &mut out);
        s.finish(4, &mut seq, &mut out);
        assert_eq!(out[0].outcome, Outcome::Incomplete);
        assert_eq!((out[0].env, out[0].policy_version), (3, 4));
        s.finish(4, &mut seq, &mut out);
        assert_eq!(out.len(), 1, "nothing staged, nothing cut");
    }

    #[test]
    fn before_step_drops_the_truncating_step_and_opens_the_next_lap_with_the_lap_step() {
        let rules = |p| {
            Segmenter::new("a", 0, p).with_rules(Flush::BeforeStep, ExpertFailureStaged::Uncertain)
        };
        let (mut s, mut seq, mut out) = (rules(2), SeqCounter::default(), vec![]);
        // An off-track spawn: its first step truncates, and nothing is stored.
        let off = StepEnd::Truncated(EndReason::OutOfTrack);
        assert_eq!(
            s.push(step(true, 0.0), off, 1, &mut seq, &mut out),
            Some(EndReason::OutOfTrack)
        );
        assert!(out.is_empty());
        assert_eq!(s.dropped, 1);
        // Two steps, then the lap step: the lap holds the two, the lap step is the next lap's first.
        s.push(step(true, 1.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(step(true, 2.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(step(true, 3.0), StepEnd::Lap, 1, &mut seq, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!((out[0].outcome, out[0].steps.len()), (Outcome::Lap, 2));
        assert_eq!(s.staged(), 1);
        s.push(step(true, 4.0), off, 1, &mut seq, &mut out);
        assert_eq!(out[1].outcome, Outcome::Failure(EndReason::OutOfTrack));
        let xs: Vec<f32> = out[1].steps.iter().map(|s| s.state[3]).collect();
        assert_eq!(
            xs,
            [3.0],
            "the lap step is stored, the truncating step (4.0) is not"
        );
        assert_eq!(s.dropped, 2);
        // Ours keeps the truncating step: the off-track spawn's state goes to D?.
        let (mut ours, mut out) = (Segmenter::new("a", 0, 2), vec![]);
        ours.push(step(true, 0.0), off, 1, &mut seq, &mut out);
        assert_eq!((out.len(), ours.dropped), (1, 0));
    }

    #[test]
    fn discard_drops_what_is_staged_when_the_expert_ends_the_episode() {
        let (mut s, mut seq, mut out) = (
            Segmenter::new("a", 0, 2).with_rules(Flush::WithStep, ExpertFailureStaged::Discard),
            SeqCounter::default(),
            vec![],
        );
        s.push(step(true, 0.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(step(true, 1.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(step(false, 2.0), StepEnd::Continue, 1, &mut seq, &mut out);
        let end = s.push(step(false, 3.0), StepEnd::Continue, 1, &mut seq, &mut out);
        assert_eq!(end, Some(EndReason::ExpertFailure));
        let outcomes: Vec<_> = out.iter().map(|s| s.outcome).collect();
        assert_eq!(
            outcomes,
            [Outcome::ExpertFailure, Outcome::ExpertFailure],
            "the failing steps go to D?"
        );
        assert_eq!(s.dropped, 2, "the two staged steps are discarded");
        // An ordinary truncation still sends its steps to D?.
        s.push(step(true, 4.0), StepEnd::Continue, 1, &mut seq, &mut out);
        s.push(
            step(true, 5.0),
            StepEnd::Truncated(EndReason::Spin),
            1,
            &mut seq,
            &mut out,
        );
        assert_eq!(out[2].outcome, Outcome::Failure(EndReason::Spin));
    }
}
