//! Who sent a message, read from the key it came on: a segment or marker counts only from its actor's
//! `traj/<actor>`, an evaluation report only from `eval/<id>` with `report.actor == id`, and a liveliness token names
//! an actor (`alive/actor/<id>`) or an evaluator (`alive/eval/<id>`). No message is believed for what it says about
//! itself.

use cabc_proto::messages::{EvalReport, TrajMessage};

/// The component name of an actor's liveliness token `.../alive/actor/<id>`.
pub fn actor_of_token(key: &str) -> Option<String> {
    let (_, rest) = key.split_once("/alive/actor/")?;
    Some(rest.to_string())
}

/// The id of an evaluator's liveliness token `.../alive/eval/<id>`.
pub fn evaluator_of_token(key: &str) -> Option<String> {
    let (_, rest) = key.split_once("/alive/eval/")?;
    Some(rest.to_string())
}

/// The `<actor>` of a key `.../traj/<actor>` (one chunk, nothing after it).
pub fn traj_sender(key: &str) -> Option<&str> {
    let (_, actor) = key.rsplit_once("/traj/")?;
    (!actor.is_empty() && !actor.contains('/')).then_some(actor)
}

/// The `<id>` of a key `.../eval/<id>` (one chunk, nothing after it).
pub fn eval_sender(key: &str) -> Option<&str> {
    let (_, id) = key.rsplit_once("/eval/")?;
    (!id.is_empty() && !id.contains('/')).then_some(id)
}

/// A segment's or a marker's `actor` must be the actor of the key it came on.
pub fn check_traj(key: &str, message: &TrajMessage) -> Result<(), String> {
    // A batch names one actor (the codec refuses one that names several).
    let named = match message {
        TrajMessage::EpochDone(d) => &d.actor,
        TrajMessage::Segment(_) | TrajMessage::Segments(_) => match message.segments().first() {
            Some(s) => &s.actor,
            None => return Err("a batch of no segments".into()),
        },
    };
    match traj_sender(key) {
        Some(sender) if sender == named => Ok(()),
        Some(sender) => Err(format!("names actor `{named}` but came from `{sender}`")),
        None => Err(format!("not an actor's key (names actor `{named}`)")),
    }
}

/// An evaluation report counts only from an evaluator's key `eval/<id>` with `report.actor == id`.
pub fn check_eval(key: &str, report: &EvalReport) -> Result<(), String> {
    match eval_sender(key) {
        Some(id) if id == report.actor => Ok(()),
        Some(id) => Err(format!(
            "an evaluation report of `{}` from `{id}`",
            report.actor
        )),
        None => Err(format!(
            "not an evaluator's key (report of `{}`)",
            report.actor
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Segment;

    #[test]
    fn evaluator_tokens_are_recognised() {
        assert_eq!(
            evaluator_of_token("cabc/r/alive/eval/eval-0").as_deref(),
            Some("eval-0")
        );
        assert_eq!(evaluator_of_token("cabc/r/alive/actor/actor-1"), None);
    }

    #[test]
    fn actor_tokens_are_recognised() {
        assert_eq!(
            actor_of_token("cabc/r/alive/actor/actor-1").as_deref(),
            Some("actor-1")
        );
        assert_eq!(actor_of_token("cabc/r/alive/eval/e"), None);
        assert_eq!(actor_of_token("cabc/r/alive/learner"), None);
    }

    fn marker(actor: &str) -> TrajMessage {
        TrajMessage::EpochDone(cabc_proto::messages::EpochDone {
            actor: actor.into(),
            version: 1,
            published_unix_ms: 0,
            segments: 0,
            steps: 0,
            taken: 0,
            staged: 0,
            shielded: 0,
        })
    }

    fn segment(actor: &str) -> TrajMessage {
        TrajMessage::Segment(Segment {
            actor: actor.into(),
            incarnation: 0,
            env: 0,
            episode: 0,
            seq: 0,
            policy_version: 0,
            outcome: cabc_proto::messages::Outcome::Lap,
            steps: Vec::new(),
        })
    }

    fn report(actor: &str) -> EvalReport {
        EvalReport {
            actor: actor.into(),
            version: 0,
            laps: 0,
            lap_times: Vec::new(),
            end_reason: cabc_proto::messages::EndReason::Stall,
            steps: 0,
            line: Vec::new(),
            spawn_episodes: 0,
            spawn_crashes: 0,
        }
    }

    #[test]
    fn senders_are_read_from_their_keys() {
        assert_eq!(traj_sender("cabc/r/traj/actor-1"), Some("actor-1"));
        assert_eq!(traj_sender("cabc/r/traj/"), None);
        assert_eq!(traj_sender("cabc/r/traj/a/b"), None);
        assert_eq!(traj_sender("cabc/r/eval/a"), None);
        assert_eq!(eval_sender("cabc/r/eval/eval-0"), Some("eval-0"));
        assert_eq!(eval_sender("cabc/r/traj/eval-0"), None);
        assert_eq!(eval_sender("cabc/r/eval/x/y"), None);
    }

    #[test]
    fn segments_and_markers_must_come_on_their_actor_key() {
        let key = "cabc/r/traj/actor-1";
        assert!(check_traj(key, &segment("actor-1")).is_ok());
        assert!(check_traj(key, &marker("actor-1")).is_ok());
        assert!(check_traj(key, &segment("actor-2")).is_err());
        assert!(check_traj(key, &marker("actor-2")).is_err());
        assert!(check_traj("cabc/r/eval/actor-1", &segment("actor-1")).is_err());
        let batch = |actor: &str| TrajMessage::Segments(segment(actor).into_segments());
        assert!(check_traj(key, &batch("actor-1")).is_ok());
        assert!(check_traj(key, &batch("actor-2")).is_err());
        assert!(check_traj(key, &TrajMessage::Segments(Vec::new())).is_err());
    }

    #[test]
    fn evaluation_reports_count_only_from_their_evaluator() {
        assert!(check_eval("cabc/r/eval/eval-0", &report("eval-0")).is_ok());
        assert!(check_eval("cabc/r/eval/eval-0", &report("eval-1")).is_err());
        assert!(check_eval("cabc/r/traj/eval-0", &report("eval-0")).is_err());
    }
}
