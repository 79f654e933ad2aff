//! The run configuration's deployment sections: the bus (`[bus]`) and the supervision of its processes
//! (`[supervision]`).

use super::SecuritySection;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BusSection {
    /// Endpoints the learner listens on (the embedded default: no router needed on one machine).
    pub listen: Vec<String>,
    /// Endpoints the other processes connect to (the learner, or a zenohd router).
    pub connect: Vec<String>,
    /// Seconds the learner waits for the last actor of an epoch before it closes the epoch without it.
    pub epoch_timeout_s: f64,
    /// Seconds an epoch waits while no actor is alive (none started yet, or all dead and not restarted) before the
    /// learner ends the run with an error; its checkpoint stays for `--resume` (issue 64).
    pub no_actor_timeout_s: f64,
    /// zenoh multicast scouting; off by default, so that a loopback run never meets strangers.
    pub multicast_scouting: bool,
    /// How long an actor gathers the segments it cuts into one message (milliseconds; issue 73): the learner's
    /// intake costs per message, and short segments (V-B's are 9 steps on average) would cost it most. A batch goes
    /// when it is this old at the actor's next segment, when it reaches `segment_batch_kib`, and before every "done"
    /// marker, so the epoch never waits for it. 0: every segment a message of its own.
    pub segment_batch_ms: f64,
    /// The most a batch of segments holds before it goes (KiB, as encoded, roughly).
    pub segment_batch_kib: u64,
    /// TLS, passwords and access control (`[bus.security]`); off by default.
    pub security: SecuritySection,
}

impl Default for BusSection {
    fn default() -> Self {
        BusSection {
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec!["tcp/127.0.0.1:7447".into()],
            epoch_timeout_s: 120.0,
            no_actor_timeout_s: 300.0,
            multicast_scouting: false,
            segment_batch_ms: 50.0,
            segment_batch_kib: 256,
            security: SecuritySection::default(),
        }
    }
}

/// How `cabc supervise` (the local job's and each scale-out machine's supervisor) restarts the run's processes
/// (issue 64): a dead actor, evaluator or expert server is started again after a backoff that doubles with each
/// death in the window, the learner with `--resume`, at most `max_restarts` times within `window_s`; the death after
/// those restarts (death `max_restarts + 1` in the window, OTP's restart intensity) stops the run with an error naming
/// the process and its log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SupervisionSection {
    /// Restarts of one process within `window_s`; its next death in the window ends the run (a crash loop). 0:
    /// never restarted (its first death ends the run).
    pub max_restarts: u32,
    /// The crash loop's window, in seconds.
    pub window_s: f64,
    /// The wait before the first restart, in seconds; doubled for each further death in the window.
    pub backoff_s: f64,
    /// The longest wait before a restart, in seconds.
    pub backoff_max_s: f64,
}

impl Default for SupervisionSection {
    fn default() -> Self {
        SupervisionSection {
            max_restarts: 5,
            window_s: 300.0,
            backoff_s: 1.0,
            backoff_max_s: 30.0,
        }
    }
}
