//! Why the supervisor could not run, or stopped, the run.

use crate::exit;
use std::path::PathBuf;

/// Why the supervisor could not run, or stopped, the run.
#[derive(Debug, thiserror::Error)]
pub enum SuperviseError {
    #[error(
        "{endpoint} (bus.listen) is in use: another run on this machine? Give this run its own port: --set \
         'bus.listen=[\"tcp/127.0.0.1:PORT\"]' --set 'bus.connect=[\"tcp/127.0.0.1:PORT\"]'"
    )]
    PortInUse { endpoint: String },
    #[error("{name} ended ({how}) before its bus opened; see {log}", log = .log.display())]
    DidNotStart {
        /// The learner, or the supervised router.
        name: String,
        how: String,
        code: Option<i32>,
        log: PathBuf,
    },
    #[error(
        "{name} died {deaths} times within {window_s} s (last: {how}): a crash loop, so the run is stopped; its log: \
         {log}", log = .log.display()
    )]
    CrashLoop {
        name: String,
        deaths: usize,
        window_s: f64,
        how: String,
        log: PathBuf,
    },
    #[error(
        "the learner gave up: no live actor for bus.no_actor_timeout_s; its checkpoint stays (--resume continues \
         the run); its log: {log}", log = .log.display()
    )]
    NoActors { log: PathBuf },
    #[error("starting {name} ({program}): {source}", program = .program.display())]
    Spawn {
        name: String,
        program: PathBuf,
        source: std::io::Error,
    },
    #[error("the run's router: {0}")]
    Router(String),
    #[error("{what}: {source}")]
    Io {
        what: String,
        source: std::io::Error,
    },
}

impl SuperviseError {
    /// The exit status a command should end with: the learner's own where it ended the run, else 1.
    pub fn exit_code(&self) -> i32 {
        match self {
            SuperviseError::DidNotStart { code: Some(c), .. } if *c != 0 => *c,
            SuperviseError::NoActors { .. } => exit::NO_ACTORS,
            _ => 1,
        }
    }
}
