//! Whether the learner published a policy update that arrived on its key (issue 64): the evaluators, and the
//! collectors for a version far ahead, adopt only what the learner's queryable vouches for.

use cabc_proto::messages::PolicyUpdate;

/// What the learner says of a policy update that arrived on its key (issue 64: a forged update with a huge version
/// left the evaluator at that version, so that it evaluated no later real one and the run could never stop early).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Vouch {
    /// The learner published these weights under this version (or published later versions and no longer holds
    /// this one: an old version, no harm).
    Yes,
    /// A version past the learner's latest, or other weights than the learner's under this version.
    No,
    /// The learner did not answer (it is restarting): ask again later.
    Unknown,
}

/// Judges `update` by the learner's answers: `latest`, its newest publication (None: no answer), and `held`, what it
/// holds under `update.version` (asked only for an older version; None: not held).
pub fn vouch(
    update: &PolicyUpdate,
    latest: Option<&PolicyUpdate>,
    held: impl FnOnce() -> Option<PolicyUpdate>,
) -> Vouch {
    let Some(latest) = latest else {
        return Vouch::Unknown;
    };
    let same = |other: &PolicyUpdate| {
        other.architecture == update.architecture && other.weights == update.weights
    };
    if update.version > latest.version {
        Vouch::No
    } else if update.version == latest.version {
        if same(latest) {
            Vouch::Yes
        } else {
            Vouch::No
        }
    } else {
        match held() {
            Some(held) if !same(&held) => Vouch::No,
            _ => Vouch::Yes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{vouch, Vouch};
    use cabc_proto::messages::PolicyUpdate;

    fn update(version: u64, weights: &[u8]) -> PolicyUpdate {
        PolicyUpdate {
            version,
            beta: 0.0,
            architecture: "mlp".into(),
            weights: weights.to_vec(),
            steps_per_actor: 1,
            published_unix_ms: version,
            shield: None,
        }
    }

    #[test]
    fn the_learner_vouches_only_for_what_it_published() {
        let latest = update(7, b"seven");
        let never = || -> Option<PolicyUpdate> { panic!("not asked") };
        assert_eq!(
            vouch(&update(7, b"seven"), Some(&latest), never),
            Vouch::Yes
        );
        // Issue 64's forged update: a huge version, or the learner's own weights replayed far ahead.
        assert_eq!(
            vouch(&update(1_007, b"seven"), Some(&latest), never),
            Vouch::No
        );
        assert_eq!(vouch(&update(8, b"eight"), Some(&latest), never), Vouch::No);
        assert_eq!(
            vouch(&update(7, b"forged"), Some(&latest), never),
            Vouch::No
        );
        // An older version: as the learner holds it, or no longer held (evicted: an old version does no harm).
        assert_eq!(
            vouch(&update(5, b"five"), Some(&latest), || Some(update(
                5, b"five"
            ))),
            Vouch::Yes
        );
        assert_eq!(
            vouch(&update(5, b"five"), Some(&latest), || None),
            Vouch::Yes
        );
        assert_eq!(
            vouch(&update(5, b"evil"), Some(&latest), || Some(update(
                5, b"five"
            ))),
            Vouch::No
        );
        // The learner away: ask again later.
        assert_eq!(vouch(&update(7, b"seven"), None, never), Vouch::Unknown);
    }
}
