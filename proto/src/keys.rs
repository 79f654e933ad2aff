//! Key expressions: every key of the bus, under `cabc/<run>/` (architecture.md).
//!
//! | key | payload |
//! |---|---|
//! | `policy` | [`PolicyUpdate`](crate::messages::PolicyUpdate) (+ a queryable for late joiners) |
//! | `traj/<actor>` | [`TrajMessage`](crate::messages::TrajMessage) |
//! | `expert/<kind>` | [`ExpertRequest`](crate::messages::ExpertRequest) → [`ExpertReply`](crate::messages::ExpertReply) |
//! | `eval/<actor>` | [`EvalReport`](crate::messages::EvalReport) |
//! | `metrics/<component>` | JSON |
//! | `alive/<component>` | liveliness token |
//! | `control` | [`Stop`](crate::messages::Stop) |
//! | `ack/<actor>` | [`Ack`](crate::messages::Ack) (the learner's receipts of an actor's segments) |

/// Root of every key.
pub const ROOT: &str = "cabc";

/// The keys of one run. Names are checked so that they cannot escape their chunk of the key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Keys {
    run: String,
}

/// A run or component name that cannot be one chunk of a key expression.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("`{0}` is not a valid key chunk: use letters, digits, '-', '_' or '.' (non-empty, no '/', '*', '$', '?', '#')")]
pub struct BadChunk(pub String);

/// The number at the end of an id ("actor-3" → 3, "eval-1" → 1), else 0: a process's default index.
pub fn trailing_number(id: &str) -> u64 {
    let start = id.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    id[start..].parse().unwrap_or(0)
}

/// Checks that `name` is usable as one chunk of a key expression.
pub fn check_chunk(name: &str) -> Result<&str, BadChunk> {
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(name)
    } else {
        Err(BadChunk(name.to_string()))
    }
}

impl Keys {
    pub fn new(run: &str) -> Result<Self, BadChunk> {
        Ok(Keys {
            run: check_chunk(run)?.to_string(),
        })
    }
    pub fn run(&self) -> &str {
        &self.run
    }
    fn key(&self, rest: &str) -> String {
        format!("{ROOT}/{}/{rest}", self.run)
    }
    pub fn policy(&self) -> String {
        self.key("policy")
    }
    pub fn traj(&self, actor: &str) -> String {
        self.key(&format!("traj/{actor}"))
    }
    /// All actors' trajectories (for the learner's subscriber).
    pub fn traj_all(&self) -> String {
        self.key("traj/*")
    }
    pub fn expert(&self, kind: &str) -> String {
        self.key(&format!("expert/{kind}"))
    }
    pub fn eval(&self, actor: &str) -> String {
        self.key(&format!("eval/{actor}"))
    }
    pub fn eval_all(&self) -> String {
        self.key("eval/*")
    }
    /// `component` may hold a '/' (for instance `expert-server/3`).
    pub fn metrics(&self, component: &str) -> String {
        self.key(&format!("metrics/{component}"))
    }
    pub fn alive(&self, component: &str) -> String {
        self.key(&format!("alive/{component}"))
    }
    pub fn alive_all(&self) -> String {
        self.key("alive/**")
    }
    pub fn control(&self) -> String {
        self.key("control")
    }
    /// The learner's receipts of `actor`'s segments.
    pub fn ack(&self, actor: &str) -> String {
        self.key(&format!("ack/{actor}"))
    }
    /// Every actor's receipts (what the learner puts).
    pub fn ack_all(&self) -> String {
        self.key("ack/*")
    }
    /// The last chunk of a key, i.e. the actor of `traj/<actor>`.
    pub fn last_chunk(key: &str) -> &str {
        key.rsplit('/').next().unwrap_or(key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_under_the_run() {
        let k = Keys::new("vb-1").unwrap();
        assert_eq!(k.policy(), "cabc/vb-1/policy");
        assert_eq!(k.traj("actor-0"), "cabc/vb-1/traj/actor-0");
        assert_eq!(k.expert("mpcc"), "cabc/vb-1/expert/mpcc");
        assert_eq!(
            k.metrics("expert-server/0"),
            "cabc/vb-1/metrics/expert-server/0"
        );
        assert_eq!(k.alive_all(), "cabc/vb-1/alive/**");
        assert_eq!(k.ack("actor-0"), "cabc/vb-1/ack/actor-0");
        assert_eq!(Keys::last_chunk("cabc/vb-1/traj/actor-0"), "actor-0");
    }

    #[test]
    fn bad_chunks_are_refused() {
        for bad in ["", "a/b", "*", "a b", "x$", "**"] {
            assert!(Keys::new(bad).is_err(), "{bad:?} accepted");
        }
    }
}
