//! The narrow interfaces between the parts of Algorithm 1, in the spirit of Acme's actor / adder / variable source.
//!
//! An actor sees three ports: a [`PolicySource`] (the learner's published (pi_j, beta_j)), an [`ExpertClient`]
//! (pi_beta(x) for a batch of states) and a [`SegmentSink`] (where its segments go); an evaluator reports through an
//! [`EvalSink`]. The learner sees the actors as one port, [`Rollouts`]: "publish (pi_j, beta_j) and collect D_new",
//! and the evaluation reports.
//!
//! The same algorithm code runs over the in-process implementations (a test, one process: `cabc_actor::local`,
//! `cabc_expert::relabel::Relabeller`) and over zenoh (`cabc_bus::ports`). This module knows nothing of either.

use crate::messages::{
    EvalReport, ExpertAnswer, ExpertQuery, PolicyUpdate, Segment, SegmentId, TrajMessage,
};

/// A port that could not do its job.
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    /// The run is over (a Stop, an interrupt) while the port was waiting.
    #[error("stopped: {0}")]
    Stopped(String),
    /// The transport failed.
    #[error("{0}")]
    Transport(String),
    /// No actor was alive for `waited_s` while epoch `epoch` collected: the run cannot go on (issue 64). Its last
    /// checkpoint stays, and `--resume` continues it once actors are back.
    #[error(
        "no live actor for {waited_s} s (bus.no_actor_timeout_s) in epoch {epoch}: the run cannot collect; its \
         checkpoint stays, and `learner run --resume` (deploy/run-local.sh --resume) continues it once actors run"
    )]
    NoActors { epoch: u64, waited_s: f64 },
}

/// How far a policy version may jump past the last one a process followed before it is taken for a forged or
/// replayed update rather than the learner's pace (the learner publishes one version per epoch; an actor skips only
/// those published while it finished a share or an evaluation, a handful; issue 57's replay was 1,000 ahead): an actor
/// logs such a jump, and a collector over the bus asks the learner to vouch for it (issue 64).
pub const FAR_AHEAD: u64 = 100;

/// What a policy source hands an actor next.
#[derive(Clone, Debug, PartialEq)]
pub enum Next {
    Policy(Box<PolicyUpdate>),
    Stop(String),
}

/// A relabelling started by [`ExpertClient::send`], to be finished by [`ExpertClient::receive`].
#[derive(Debug)]
pub enum Pending {
    /// A client that cannot overlap (in-process) answered at once.
    Answered(Vec<ExpertAnswer>),
    /// On its way: the client's request id.
    InFlight(u64),
}

/// pi_beta(x): the expert's actions for a batch of states (the relabelling of Algorithm 1).
pub trait ExpertClient {
    /// One answer per query, in order. Waits for an expert; fails only when the run stops or the transport dies.
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError>;

    /// Starts a relabelling without waiting for its answers, so that the caller simulates meanwhile; they come from
    /// [`Self::receive`]. A client that cannot overlap answers at once (the default).
    fn send(&mut self, queries: Vec<ExpertQuery>) -> Result<Pending, PortError> {
        self.relabel(queries).map(Pending::Answered)
    }

    /// Drops a relabelling started by [`Self::send`] whose answers are no longer wanted (the epoch ended early).
    fn cancel(&mut self, pending: Pending) {
        drop(pending);
    }

    /// The answers of a relabelling started by [`Self::send`], waiting for them as [`Self::relabel`] does.
    fn receive(&mut self, pending: Pending) -> Result<Vec<ExpertAnswer>, PortError> {
        match pending {
            Pending::Answered(answers) => Ok(answers),
            Pending::InFlight(id) => Err(PortError::Transport(format!(
                "request {id} is not in flight with this client"
            ))),
        }
    }
}

/// An actor's variable source: the learner's policy versions.
pub trait PolicySource {
    /// Blocks until the next policy version (the newest of a burst) or a stop.
    fn next(&mut self) -> Result<Next, PortError>;
    /// A newer version or a stop that arrived meanwhile, without blocking: the learner moved on.
    fn interrupted(&mut self) -> Option<Next>;
}

/// Where an actor's segments and its epoch markers go (the adder's output).
pub trait SegmentSink {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError>;
}

/// Where an evaluator's reports go.
pub trait EvalSink {
    fn report(&mut self, report: EvalReport) -> Result<(), PortError>;
}

/// How an epoch's collection ended, as the learner sees it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Collected {
    /// Steps the actors said they published with this version (their markers).
    pub steps_published: u64,
    /// Steps the actors took with this version (their markers).
    pub steps_taken: u64,
    /// Steps the actors had taken but still staged when they were done (their markers): unfinished laps that later
    /// epochs' segments carry.
    pub steps_staged: u64,
    /// Steps the shield handed to the expert (their markers; `collection.shield`).
    pub steps_shielded: u64,
    /// Whether the timeout closed the epoch (an actor missing or not yet seen).
    pub timed_out: bool,
    /// Actors alive when the epoch closed that had not said they were done.
    pub missing: Vec<String>,
    /// The actors alive when the epoch closed.
    pub live: Vec<String>,
    /// Where the collection's wall clock went, when the actors ran in the learner's process (None over the bus).
    pub times: Option<CollectionTimes>,
}

/// Where an in-process collection's wall clock went, in seconds, summed over the actors' steps (what
/// `learner run --local` puts in `metrics.csv` as `collect_<phase>_s`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CollectionTimes {
    /// Observing: the camera's frames and the sensor's noise.
    pub observe_s: f64,
    /// The policy's inference.
    pub policy_s: f64,
    /// Waiting for the expert's answers: with an expert answering as it is asked, solving them.
    pub expert_s: f64,
    /// The mixture, the plant's step and the segmenter.
    pub step_s: f64,
    /// Handing the cut segments to the learner's store.
    pub store_s: f64,
    /// The version's evaluation, which runs beside the collection: its own wall clock.
    pub evaluate_s: f64,
}

impl CollectionTimes {
    /// Adds `other`'s phases to these.
    pub fn add(&mut self, other: &CollectionTimes) {
        self.observe_s += other.observe_s;
        self.policy_s += other.policy_s;
        self.expert_s += other.expert_s;
        self.step_s += other.step_s;
        self.store_s += other.store_s;
        self.evaluate_s += other.evaluate_s;
    }
}

/// The actors, as the learner sees them.
pub trait Rollouts {
    /// Publishes (pi_j, beta_j): the actors start collecting D_new with it.
    fn publish(&mut self, update: &PolicyUpdate) -> Result<(), PortError>;
    /// Gathers D_new of the version last published (`update`): every segment that arrives goes to `store`, until
    /// every live actor is done with this version (or the epoch's timeout, counted from the publication). What
    /// arrived between the two calls (the learner trained meanwhile under `collection.overlap`) is taken first.
    /// `Ok(None)`: interrupted, the run must end.
    fn gather(
        &mut self,
        update: &PolicyUpdate,
        store: &mut dyn FnMut(Segment),
    ) -> Result<Option<Collected>, PortError>;
    /// Evaluation reports received since the last call.
    fn evaluations(&mut self) -> Vec<EvalReport>;
    /// The checkpoint holds these segments (stored, or settled as refused or copies): their actors may forget them.
    fn commit(&mut self, _segments: &[SegmentId]) {}
    /// Whether the run was interrupted (Ctrl-C) since the last collection.
    fn interrupted(&self) -> bool {
        false
    }
    /// Ends the run for every actor.
    fn stop(&mut self, reason: &str) -> Result<(), PortError>;
    /// Messages refused so far (foreign, malformed).
    fn rejected(&self) -> u64 {
        0
    }
}
