//! The actor's ports of Algorithm 1 over zenoh (blocking; no async runtime in the caller):
//!
//! * [`ZenohPolicySource`]: the learner's latest version on start (its queryable), then `policy` updates, and
//!   `control` stops; a collector skips to the newest version, an evaluator ([`ZenohPolicySource::every_version`])
//!   takes every version of its shard in order;
//! * `ZenohExpert` (in `crate::expert`, which uses the statistics here): batch queries on `expert/<kind>`, two in flight (the actor's halves),
//!   waiting and retrying while no server answers;
//! * `ZenohSegments` (in the `outbox` module: each segment held until the learner acknowledges it), [`ZenohEvals`]:
//!   reliable puts on `traj/<id>` and `eval/<id>`.
//!
//! [`WireStats`] adds up the time spent waiting on the expert and the time on the wire, for the actor's metrics.

use crate::interrupt::Interrupt;
pub use crate::vouch::{vouch, Vouch};
use crate::{decode_sample, Bus};
use bytes::Bytes;
use cabc_proto::messages::{EpochDone, EvalReport, PolicyUpdate, Stop, TrajMessage};
use cabc_proto::ports::FAR_AHEAD;
use cabc_proto::ports::{EvalSink, Next, PolicySource, PortError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::Wait;

/// How long a blocking wait lasts before the loops look at the interrupt flag again.
const POLL: Duration = Duration::from_millis(200);

fn transport(e: impl std::fmt::Display) -> PortError {
    PortError::Transport(e.to_string())
}

/// Time figures of an actor's traffic since start.
#[derive(Clone, Debug, Default)]
pub struct WireStats {
    /// Blocked on the expert: the part of each round trip the actor had nothing else to do.
    pub expert_wait: Duration,
    /// On the wire while the actor waited: of each expert round trip, the time less the server's residence, at most
    /// the time the actor was blocked on it (the rest overlapped its other half's work); plus publishing segments.
    pub transport: Duration,
    /// Broadcast latencies of the policy updates received by subscription (ms).
    pub policy_latency_ms: Vec<f64>,
    /// Segments and markers not sent because the actor was interrupted while no router was up, and segments its
    /// outbox dropped unacknowledged when full (`crate::outbox`).
    pub segments_lost: u64,
    /// Segments published again because the learner had not acknowledged them (`crate::outbox`).
    pub segments_resent: u64,
    /// Versions an evaluator dropped unevaluated because it fell too far behind ([`MAX_PENDING_BYTES`]).
    pub versions_skipped: u64,
    /// Policy updates refused because the learner did not vouch for them ([`Vouch::No`]: a version it never
    /// published, or other weights than it published under that version).
    pub versions_not_vouched: u64,
}

impl WireStats {
    /// The figures of an actor's metrics, as shares of `busy` (its collection time): expert wait, transport,
    /// broadcast latency, segments lost, versions skipped.
    pub fn figures(&self, busy: Duration) -> serde_json::Map<String, serde_json::Value> {
        let busy = busy.as_secs_f64();
        let share = |d: Duration| {
            if busy > 0.0 {
                d.as_secs_f64() / busy
            } else {
                0.0
            }
        };
        let latency = &self.policy_latency_ms;
        let figures = serde_json::json!({
            "expert_wait_share": share(self.expert_wait),
            "transport_share": share(self.transport),
            "policy_latency_ms_last": latency.last(),
            "policy_latency_ms_mean": cabc_proto::stats::mean(latency),
            "segments_lost": self.segments_lost,
            "segments_resent": self.segments_resent,
            "versions_skipped": self.versions_skipped,
            "versions_not_vouched": self.versions_not_vouched,
        });
        match figures {
            serde_json::Value::Object(map) => map,
            _ => serde_json::Map::new(),
        }
    }
}

/// Shared between the ports and the metrics.
pub type SharedStats = Arc<Mutex<WireStats>>;

pub(crate) fn with_stats(stats: &SharedStats, f: impl FnOnce(&mut WireStats)) {
    f(&mut stats.lock().unwrap_or_else(|e| e.into_inner()));
}

/// A stop on `control`, or Ctrl-C.
pub(crate) struct Stops {
    control: Subscriber<FifoChannelHandler<Sample>>,
    interrupt: Interrupt,
}

impl Stops {
    pub(crate) fn new(bus: &Bus, interrupt: &Interrupt) -> Result<Stops, PortError> {
        let control = bus
            .session
            .declare_subscriber(bus.keys.control())
            .wait()
            .map_err(transport)?;
        Ok(Stops {
            control,
            interrupt: interrupt.clone(),
        })
    }

    pub(crate) fn requested(&self, bus: &Bus) -> Option<String> {
        if self.interrupt.is_set() {
            return Some("interrupted".into());
        }
        while let Ok(Some(sample)) = self.control.try_recv() {
            let bytes = sample.payload().to_bytes();
            if let Some(stop) =
                decode_sample::<Stop>(sample.key_expr().as_str(), &bytes, &bus.rejects)
            {
                return Some(stop.reason);
            }
        }
        None
    }
}

/// How often a waiting actor asks the learner's queryable for its latest version: a restarted learner's first
/// publication may have gone out before this actor had reconnected.
const REQUERY: Duration = Duration::from_secs(5);

/// What makes a publication news: its version and when the learner published it (a resumed learner publishes a
/// version again, with a new time; a publication repeated for late joiners keeps its time).
fn identity(update: &PolicyUpdate) -> (u64, u64) {
    (update.version, update.published_unix_ms)
}

/// The evaluators' share of the versions: evaluator `index` of `count` evaluates the versions v with
/// v mod count = index (explicit, so that several evaluators keep up with a slow evaluation between them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

impl Shard {
    /// Evaluator `id`'s shard: `index` (default: the number at the end of `id`) of `count` (`actors.evaluators`).
    pub fn of_evaluator(id: &str, index: Option<u64>, count: u64) -> Result<Shard, String> {
        let index = index.unwrap_or_else(|| cabc_proto::keys::trailing_number(id));
        if index >= count {
            return Err(format!(
                "evaluator {id} has index {index} but the run has actors.evaluators = {count}: use ids eval-0 .. \
                 eval-{} (or --index)",
                count.saturating_sub(1)
            ));
        }
        Ok(Shard { index, count })
    }

    pub fn owns(&self, version: u64) -> bool {
        version % self.count.max(1) == self.index
    }
}

/// How far back an evaluator asks for versions it missed.
pub const MAX_GAP: u64 = 64;

/// The weights an evaluator holds at most for versions it has not evaluated yet; past it, the oldest are dropped
/// (logged and counted in `versions_skipped`).
pub const MAX_PENDING_BYTES: usize = 256 << 20;

/// The learner's policy versions, over zenoh.
pub struct ZenohPolicySource<'a> {
    bus: &'a Bus,
    updates: Subscriber<FifoChannelHandler<Sample>>,
    stops: Stops,
    /// The publication handed out last.
    current: Option<(u64, u64)>,
    last_query: Option<Instant>,
    stats: SharedStats,
    /// An evaluator's shard: every version of it, in order, none skipped but by [`MAX_PENDING_BYTES`].
    every: Option<Shard>,
    /// An evaluator's versions not handed out yet.
    pending: std::collections::BTreeMap<u64, PolicyUpdate>,
    /// The last version an evaluator handed out.
    last_version: Option<u64>,
    /// The newest version up to which an evaluator has asked the learner for the versions it missed (each missed
    /// version is asked for once).
    asked: Option<u64>,
    /// A collector's last marker, sent again when the learner publishes the version it answers once more.
    echo: Option<MarkerEcho>,
}

/// A collector's last "done with j" marker ([`crate::outbox::ZenohSegments::echo`]): when the learner publishes a
/// version again that the actor has already answered, its marker may have been lost (a link cut longer than zenoh's
/// lease drops what was in flight), so the source sends it again (issue 64), after every segment the learner has not
/// acknowledged yet (`unacknowledged`, the outbox's: the marker must not overtake them). Not only those a lost router
/// stranded: a segment put after the router came back but before the learner's subscription reached it is dropped
/// as well, and its marker, echoed alone, closed the epoch without it (seen under load in
/// `a_restarted_router_costs_its_time_and_no_step`: 115 of an epoch's 239 steps). The learner's gate takes a marker
/// twice as once, its ledger a segment twice as once.
#[derive(Clone)]
pub struct MarkerEcho {
    key: String,
    last: Arc<Mutex<Option<EpochDone>>>,
    unacknowledged: Arc<dyn Fn() -> Vec<Bytes> + Send + Sync>,
}

impl MarkerEcho {
    /// The marker last put on `key`, as the segment sink keeps it in `last`, sent after what `unacknowledged` gives.
    pub(crate) fn new(
        key: String,
        last: Arc<Mutex<Option<EpochDone>>>,
        unacknowledged: Arc<dyn Fn() -> Vec<Bytes> + Send + Sync>,
    ) -> MarkerEcho {
        MarkerEcho {
            key,
            last,
            unacknowledged,
        }
    }

    /// Sends the last marker again if it answers the publication `(version, published_unix_ms)`, after every segment
    /// not acknowledged yet; whether it did.
    pub fn again(&self, bus: &Bus, publication: (u64, u64), stats: &SharedStats) -> bool {
        let marker = self
            .last
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .filter(|m| (m.version, m.published_unix_ms) == publication);
        let Some(marker) = marker else {
            return false;
        };
        tracing::info!(
            version = marker.version,
            "the learner published the version again: sending its marker again"
        );
        for encoded in (self.unacknowledged)() {
            match bus.put_encoded_blocking::<TrajMessage>(&self.key, encoded) {
                Ok(()) => with_stats(stats, |s| s.segments_resent += 1),
                Err(e) => tracing::warn!("publishing an unacknowledged segment again: {e}"),
            }
        }
        if let Err(e) = bus.put_blocking(&self.key, &TrajMessage::EpochDone(marker)) {
            tracing::warn!("sending the marker again: {e}");
        }
        true
    }
}

impl<'a> ZenohPolicySource<'a> {
    pub fn new(bus: &'a Bus, interrupt: &Interrupt, stats: SharedStats) -> Result<Self, PortError> {
        let updates = bus
            .session
            .declare_subscriber(bus.keys.policy())
            .wait()
            .map_err(transport)?;
        Ok(ZenohPolicySource {
            bus,
            updates,
            stops: Stops::new(bus, interrupt)?,
            current: None,
            last_query: None,
            stats,
            every: None,
            pending: Default::default(),
            last_version: None,
            asked: None,
            echo: None,
        })
    }

    /// Sends the collector's last marker again when the learner publishes the version it answered once more.
    pub fn echoing(mut self, echo: MarkerEcho) -> Self {
        self.echo = Some(echo);
        self
    }

    /// `update` is a publication this actor already took: if it has answered it, the marker goes out again.
    fn echo_marker(&self, update: &PolicyUpdate) {
        if let Some(echo) = &self.echo {
            echo.again(self.bus, identity(update), &self.stats);
        }
    }

    /// An evaluator's source: every version of `shard`, oldest first, each once (a version published again by a
    /// resumed learner is not evaluated twice), instead of skipping to the newest.
    pub fn every_version(mut self, shard: Shard) -> Self {
        tracing::info!(
            ?shard,
            "evaluating every version v with v mod count = index"
        );
        self.every = Some(shard);
        self
    }

    /// Keeps an update for an evaluator, if it is of its shard and newer than what it handed out.
    fn keep(&mut self, update: PolicyUpdate, shard: Shard) {
        let version = update.version;
        if !shard.owns(version) || self.last_version.is_some_and(|last| version <= last) {
            return;
        }
        self.pending.insert(version, update);
        let mut bytes: usize = self.pending.values().map(|u| u.weights.len()).sum();
        while bytes > MAX_PENDING_BYTES && self.pending.len() > 1 {
            let Some((skipped, update)) = self.pending.pop_first() else {
                break;
            };
            bytes -= update.weights.len();
            with_stats(&self.stats, |s| s.versions_skipped += 1);
            tracing::warn!(
                version = skipped,
                pending = self.pending.len(),
                "evaluator too far behind: version skipped unevaluated (start more evaluators: actors.evaluators)"
            );
        }
    }

    /// Asks the learner for the versions of `shard` this evaluator missed (it joined late, or was restarted): those
    /// before the newest it holds and after the last it handed out, at most [`MAX_GAP`] back. A version the learner
    /// does not hold (it has its evaluation already, or dropped it for memory) is skipped, logged and counted.
    fn fill_gaps(&mut self, shard: Shard) {
        let Some(&newest) = self.pending.keys().next_back() else {
            return;
        };
        let after = self.last_version.max(self.asked);
        let first = after
            .map_or(0, |v| v + 1)
            .max(newest.saturating_sub(MAX_GAP));
        for version in (first..newest).filter(|&v| shard.owns(v)) {
            if self.pending.contains_key(&version) {
                continue;
            }
            match self.ask(Some(version)) {
                Some(update) if update.version == version => self.keep(update, shard),
                _ => {
                    with_stats(&self.stats, |s| s.versions_skipped += 1);
                    tracing::info!(
                        version,
                        "the learner does not hold this version (evaluated already, or dropped): skipped"
                    );
                }
            }
        }
        self.asked = Some(newest);
    }

    /// An evaluator's newest pending version far past the last one it handed out ([`FAR_AHEAD`]) is vouched for
    /// before the gaps up to it are asked for (a forged version of 1,000,000 would have it ask for 64 versions the
    /// learner never published); dropped when the learner does not vouch for it.
    fn drop_unvouched_jump(&mut self) {
        let Some(last) = self.last_version else {
            return;
        };
        let Some((&newest, _)) = self.pending.last_key_value() else {
            return;
        };
        if newest <= last + FAR_AHEAD {
            return;
        }
        if let Some((version, update)) = self.pending.pop_last() {
            if self.vouched(&update) != Vouch::No {
                self.pending.insert(version, update);
            }
        }
    }

    /// The next version of an evaluator's shard, in order.
    fn next_of_shard(&mut self, shard: Shard) -> Result<Next, PortError> {
        loop {
            if let Some(reason) = self.stops.requested(self.bus) {
                return Ok(Next::Stop(reason));
            }
            if self.last_query.is_none_or(|t| t.elapsed() >= REQUERY) {
                self.last_query = Some(Instant::now());
                if let Some(update) = self.latest() {
                    self.keep(update, shard);
                }
            }
            while let Ok(Some(sample)) = self.updates.try_recv() {
                if let Some(update) = self.decode(&sample) {
                    self.keep(update, shard);
                }
            }
            self.drop_unvouched_jump();
            self.fill_gaps(shard);
            if let Some((version, update)) = self.pending.pop_first() {
                match self.vouched(&update) {
                    Vouch::Yes => {
                        self.last_version = Some(version);
                        return Ok(self.hand_out(update));
                    }
                    Vouch::No => continue,
                    Vouch::Unknown => {
                        // The learner is away: the version waits (and the loop asks again after REQUERY).
                        self.pending.insert(version, update);
                        std::thread::sleep(POLL);
                        continue;
                    }
                }
            }
            if let Some(update) = self
                .updates
                .recv_timeout(POLL)
                .map_err(transport)?
                .and_then(|s| self.decode(&s))
            {
                self.keep(update, shard);
            }
        }
    }

    /// What the learner says of `update` ([`vouch`]); a refusal is logged and counted.
    fn vouched(&self, update: &PolicyUpdate) -> Vouch {
        let latest = self.latest();
        let verdict = vouch(update, latest.as_ref(), || self.ask(Some(update.version)));
        if verdict == Vouch::No {
            with_stats(&self.stats, |s| s.versions_not_vouched += 1);
            tracing::error!(
                version = update.version,
                latest = latest.as_ref().map(|l| l.version),
                "a policy update the learner did not publish (a version past its latest, or other weights): refused"
            );
        }
        verdict
    }

    /// The learner's latest version, if it is up (late joiners start at once).
    fn latest(&self) -> Option<PolicyUpdate> {
        self.ask(None)
    }

    /// The learner's latest version, or `version` if the learner still holds it.
    fn ask(&self, version: Option<u64>) -> Option<PolicyUpdate> {
        let key = self.bus.keys.policy();
        let selector = match version {
            Some(v) => format!("{key}?version={v}"),
            None => key.clone(),
        };
        let replies = self
            .bus
            .session
            .get(&selector)
            .timeout(Duration::from_secs(3))
            .wait()
            .ok()?;
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                let bytes = sample.payload().to_bytes();
                if let Some(update) = decode_sample::<PolicyUpdate>(&key, &bytes, &self.bus.rejects)
                {
                    return Some(update);
                }
            }
        }
        None
    }

    fn decode(&self, sample: &Sample) -> Option<PolicyUpdate> {
        let bytes = sample.payload().to_bytes();
        let update =
            decode_sample::<PolicyUpdate>(sample.key_expr().as_str(), &bytes, &self.bus.rejects)?;
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        let latency = now.saturating_sub(update.published_unix_ms) as f64;
        with_stats(&self.stats, |s| s.policy_latency_ms.push(latency));
        Some(update)
    }

    /// A collector's update far ahead of the version it followed ([`FAR_AHEAD`]) that the learner does not vouch for.
    fn far_ahead_unvouched(&self, update: &PolicyUpdate) -> bool {
        let last = self.current.map(|(version, _)| version);
        last.is_some_and(|last| update.version > last + FAR_AHEAD)
            && self.vouched(update) == Vouch::No
    }

    fn is_news(&self, update: &PolicyUpdate) -> bool {
        self.current != Some(identity(update))
    }

    /// The newest publication received that is news, if any.
    fn newest(&self) -> Option<PolicyUpdate> {
        let mut newest = None;
        while let Ok(Some(sample)) = self.updates.try_recv() {
            if let Some(update) = self.decode(&sample).filter(|u| self.is_news(u)) {
                newest = Some(update);
            }
        }
        newest
    }

    fn hand_out(&mut self, update: PolicyUpdate) -> Next {
        self.current = Some(identity(&update));
        Next::Policy(Box::new(update))
    }
}

impl PolicySource for ZenohPolicySource<'_> {
    fn next(&mut self) -> Result<Next, PortError> {
        if let Some(shard) = self.every {
            return self.next_of_shard(shard);
        }
        loop {
            if let Some(reason) = self.stops.requested(self.bus) {
                return Ok(Next::Stop(reason));
            }
            if self.last_query.is_none_or(|t| t.elapsed() >= REQUERY) {
                self.last_query = Some(Instant::now());
                if let Some(update) = self.latest().filter(|u| self.is_news(u)) {
                    let update = self.newest().unwrap_or(update);
                    return Ok(self.hand_out(update));
                }
            }
            let sample = self.updates.recv_timeout(POLL).map_err(transport)?;
            let update = sample.and_then(|s| self.decode(&s));
            if let Some(again) = update.as_ref().filter(|u| !self.is_news(u)) {
                self.echo_marker(again);
            }
            if let Some(update) = update.filter(|u| self.is_news(u)) {
                let update = self.newest().unwrap_or(update);
                if self.far_ahead_unvouched(&update) {
                    continue;
                }
                return Ok(self.hand_out(update));
            }
        }
    }

    fn interrupted(&mut self) -> Option<Next> {
        if let Some(reason) = self.stops.requested(self.bus) {
            return Some(Next::Stop(reason));
        }
        if self.every.is_some() {
            // An evaluation is not interrupted by a newer version: it waits its turn.
            return None;
        }
        let newest = self.newest()?;
        if self.far_ahead_unvouched(&newest) {
            return None;
        }
        Some(self.hand_out(newest))
    }
}

/// An evaluator's reports on `eval/<id>`.
pub struct ZenohEvals<'a> {
    bus: &'a Bus,
    key: String,
}

impl<'a> ZenohEvals<'a> {
    pub fn new(bus: &'a Bus, evaluator: &str) -> Self {
        ZenohEvals {
            bus,
            key: bus.keys.eval(evaluator),
        }
    }
}

impl EvalSink for ZenohEvals<'_> {
    fn report(&mut self, report: EvalReport) -> Result<(), PortError> {
        self.bus.put_blocking(&self.key, &report).map_err(transport)
    }
}
