//! The messages of the bus (architecture.md). Plain data with serde; the codec adds the header.
//!
//! Frames and units: `state` = [v_long, v_tran, omega, s, x_tran, e_psi] (m/s, m/s, rad/s, m, m, rad) in the track's
//! Frenet frame; `pose` = [X, Y, psi] (m, m, rad; psi unwrapped) in the track's global frame; actions = [a, delta]
//! (m/s², rad).

use serde::{Deserialize, Serialize};

/// Observation dimension of the full state.
pub const STATE_DIM: usize = 6;
/// Action dimension.
pub const ACTION_DIM: usize = 2;
/// Velocities the camera policy sees beside the image.
pub const VELOCITY_DIM: usize = 3;

/// [v_long, v_tran, omega] = state[0..3]: the velocities the vision policy sees beside the image (the one definition).
pub fn velocity_of(state: &[f32; STATE_DIM]) -> [f32; VELOCITY_DIM] {
    [state[0], state[1], state[2]]
}

/// An RGB camera image, row-major HWC.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub width: u16,
    pub height: u16,
    #[serde(with = "bytes")]
    pub rgb: Vec<u8>,
}

/// Bytes (an image's, a network's weights) as one byte string for serde: the same encoding as a `Vec<u8>`'s in bincode
/// (its length, then the bytes) and in JSON (an array of numbers), decoded with one copy instead of one call a byte (a
/// 64x64 image took 30 µs to decode that way, most of the learner's CPU per camera step, and the camera policy's 1.2 MB
/// of weights 3 ms in each actor; issue 73, `cabc bench-bus`).
mod bytes {
    use serde::de::{Deserializer, SeqAccess, Visitor};
    use serde::Serializer;

    pub fn serialize<S: Serializer>(bytes: &[u8], serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_bytes(bytes)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<Vec<u8>, D::Error> {
        deserializer.deserialize_byte_buf(Bytes)
    }

    struct Bytes;

    impl<'de> Visitor<'de> for Bytes {
        type Value = Vec<u8>;

        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("an image's bytes")
        }

        fn visit_bytes<E>(self, v: &[u8]) -> Result<Vec<u8>, E> {
            Ok(v.to_vec())
        }

        fn visit_byte_buf<E>(self, v: Vec<u8>) -> Result<Vec<u8>, E> {
            Ok(v)
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<u8>, A::Error> {
            // A length is the sender's word: the vector grows as the bytes come, never ahead of them.
            let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(1 << 16));
            while let Some(b) = seq.next_element()? {
                out.push(b);
            }
            Ok(out)
        }
    }
}

/// Bytes of one RGB image of `width` x `height` pixels in the [`Image`] layout (row-major HWC, a byte a channel): the
/// one place an image's size is written.
pub const fn image_bytes(width: usize, height: usize) -> usize {
    width * height * 3
}

/// One environment step, as the learner stores it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// [v_long, v_tran, omega, s, x_tran, e_psi] before the step.
    pub state: [f32; STATE_DIM],
    /// [X, Y, psi] before the step.
    pub pose: [f32; 3],
    /// The camera image before the step, when the run observes images.
    pub image: Option<Image>,
    /// The expert's action at `state` (the label). Meaningless when `expert_ok` is false.
    pub expert_action: [f32; ACTION_DIM],
    /// The beta mixture the environment received, which the dynamics model trains on: clipped to the action box
    /// (ours), or as blended before the environment clips it (`collection.stored_action = "unclipped"`, the reference).
    pub applied_action: [f32; ACTION_DIM],
    /// The state after the step.
    pub next_state: [f32; STATE_DIM],
    /// Whether the expert solved its problem at this state.
    pub expert_ok: bool,
}

impl Step {
    /// [v_long, v_tran, omega] before the step ([`velocity_of`]).
    pub fn velocity(&self) -> [f32; VELOCITY_DIM] {
        velocity_of(&self.state)
    }
}

/// Why an episode was cut (simulator.md 3.6), or that the expert failed twice in a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum EndReason {
    /// |x_tran| > half-width: the constraint violation.
    OutOfTrack,
    /// The car left the Frenet band (|x_tran| > 0.85).
    LeftBand,
    /// v_long < 0.25.
    Stall,
    /// |e_psi| > pi/2.
    Spin,
    /// The maximum number of laps was driven.
    MaxLaps,
    /// The expert failed on consecutive steps (patience exhausted).
    ExpertFailure,
    /// The step budget ran out.
    Budget,
}

impl std::fmt::Display for EndReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            EndReason::OutOfTrack => "out-of-track",
            EndReason::LeftBand => "left-band",
            EndReason::Stall => "stall",
            EndReason::Spin => "spin",
            EndReason::MaxLaps => "max-laps",
            EndReason::ExpertFailure => "expert-failure",
            EndReason::Budget => "budget",
        };
        f.write_str(s)
    }
}

/// How a segment ended, which decides its replay buffer (algorithm.md 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Outcome {
    /// A lap was completed: every step goes to D+.
    Lap,
    /// The episode was truncated: the steps go to D? (uncertain).
    Failure(EndReason),
    /// One step at which the expert failed: straight to D?.
    ExpertFailure,
    /// The epoch's step budget ran out: kept for the dynamics model, never labelled.
    Incomplete,
}

/// A piece of one episode, cut at a lap, a failure or the end of the budget.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    pub actor: String,
    /// Environment index inside the actor.
    pub env: u32,
    /// Episode counter of that environment.
    pub episode: u64,
    /// The actor process's incarnation (chosen at its start): a restarted actor's segments are new segments even
    /// though its `seq` starts again at 0.
    pub incarnation: u64,
    /// Sequence number of this segment among the segments of this incarnation (0, 1, 2, ...).
    pub seq: u64,
    /// Policy version that collected it.
    pub policy_version: u64,
    pub outcome: Outcome,
    pub steps: Vec<Step>,
}

impl Segment {
    /// The segment `steps` of `actor`'s environment 0, episode 0, first of its incarnation, collected by version 0:
    /// for tests and benchmarks that build replays by hand.
    pub fn of(actor: &str, outcome: Outcome, steps: Vec<Step>) -> Segment {
        Segment {
            actor: actor.to_string(),
            env: 0,
            episode: 0,
            incarnation: 0,
            seq: 0,
            policy_version: 0,
            outcome,
            steps,
        }
    }
}

/// "Actor `actor` is done with policy version `version`": the epoch protocol's marker.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct EpochDone {
    pub actor: String,
    pub version: u64,
    /// The `published_unix_ms` of the publication it answers: a learner resumed mid-epoch publishes the same version
    /// again, and a marker of the first publication (the actor was interrupted) must not close the second.
    pub published_unix_ms: u64,
    /// Segments and steps the actor published for this version, so the learner can check that none was lost.
    pub segments: u64,
    pub steps: u64,
    /// Steps the actor took with this version (its share of the budget, unless a newer version interrupted it).
    pub taken: u64,
    /// Steps taken but still staged when the actor was done with this version (an unfinished lap, carried into the
    /// next epoch's segments when episodes go on across epochs).
    pub staged: u64,
    /// Steps the shield handed to the expert (`collection.shield`).
    pub shielded: u64,
}

/// What an actor publishes on `traj/<actor>`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum TrajMessage {
    Segment(Segment),
    EpochDone(EpochDone),
    /// Several segments of one actor's incarnation in one message (issue 73: the learner's cost is per message, so
    /// an actor batches what it cut within `bus.segment_batch_ms`; `cabc_bus::outbox`). Each is still its own
    /// segment: stored, acknowledged and accounted for by its own seq.
    Segments(Vec<Segment>),
}

impl TrajMessage {
    /// The segments this message carries (none for a marker).
    pub fn segments(&self) -> &[Segment] {
        match self {
            TrajMessage::Segment(segment) => std::slice::from_ref(segment),
            TrajMessage::Segments(segments) => segments,
            TrajMessage::EpochDone(_) => &[],
        }
    }

    /// The segments this message carries, taken (none for a marker).
    pub fn into_segments(self) -> Vec<Segment> {
        match self {
            TrajMessage::Segment(segment) => vec![segment],
            TrajMessage::Segments(segments) => segments,
            TrajMessage::EpochDone(_) => Vec::new(),
        }
    }
}

/// The learner's policy broadcast.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolicyUpdate {
    pub version: u64,
    /// Mixture weight of the expert for this version: u = beta * expert + (1 - beta) * policy.
    pub beta: f64,
    /// The architecture's name; an actor refuses weights of another architecture.
    pub architecture: String,
    /// safetensors bytes of the policy network.
    #[serde(with = "bytes")]
    pub weights: Vec<u8>,
    /// Environment steps each actor collects with this version (the epoch budget).
    pub steps_per_actor: u64,
    /// When the learner published it (ms since the Unix epoch), for the broadcast latency.
    pub published_unix_ms: u64,
    /// f_hat and p_hat for the shield in collection (`collection.shield` > 0, once the critic has trained).
    pub shield: Option<ShieldNets>,
}

/// The networks of the shield in collection: safetensors bytes of f_hat and p_hat (their sizes are the run's
/// `networks.dynamics` and `networks.critic`; an actor refuses others).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShieldNets {
    #[serde(with = "bytes")]
    pub dynamics: Vec<u8>,
    #[serde(with = "bytes")]
    pub critic: Vec<u8>,
}

/// Identifies a stream of expert queries (one environment's episode), for the MPCC warm start.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct StreamId {
    pub actor: String,
    pub env: u32,
    pub episode: u64,
}

/// One state to relabel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExpertQuery {
    pub stream: StreamId,
    /// True on the first query of a stream (the MPCC cold-starts).
    pub start: bool,
    /// [v_x, v_y, omega, X, Y, psi]: the vehicle state in the global frame.
    pub vehicle: [f64; 6],
    /// [v_long, v_tran, omega, s, x_tran, e_psi]: the same state in the Frenet frame (the PID reads it).
    pub frenet: [f64; 6],
}

/// A batch of states to relabel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExpertRequest {
    pub request_id: u64,
    pub queries: Vec<ExpertQuery>,
}

/// The expert's answer for one query.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExpertAnswer {
    pub action: [f64; 2],
    pub success: bool,
    /// Solver status, human-readable ("Solved", "MaxIterations", "out of band: ...").
    pub status: String,
    pub iterations: u32,
    pub solve_time_us: u32,
}

/// The answer to an [`ExpertRequest`], item by item.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExpertReply {
    pub request_id: u64,
    pub answers: Vec<ExpertAnswer>,
    /// Wall time the request spent in the server, from receipt to reply (µs), so that a client can tell the time on
    /// the wire from the time spent solving (and queueing for the server's cores).
    pub batch_time_us: u64,
}

/// The result of one evaluation of a policy version (fixed spawn, beta = 0): its laps, lap times, end and line; and,
/// under `collection.early_stop_spawns`, how the episodes from random spawns that the early stop also judges went.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub actor: String,
    pub version: u64,
    pub laps: u32,
    /// Seconds per completed lap.
    pub lap_times: Vec<f64>,
    pub end_reason: EndReason,
    pub steps: u64,
    /// The driven line, [X, Y] per step (subsampled by the actor when long).
    pub line: Vec<[f32; 2]>,
    /// Episodes driven from random spawns under noise (`collection.early_stop_spawns`) after the fixed spawn
    /// completed its laps; 0 when it did not, or without the key.
    pub spawn_episodes: u32,
    /// Of those, the episodes that did not complete their laps (a crash, or the evaluator's step limit).
    pub spawn_crashes: u32,
}

/// The learner's receipt of an actor's segments, on `ack/<actor>` (issue 64): the learner process `learner` (its
/// incarnation, chosen at its start) has the segments `seqs` of the actor's incarnation `incarnation`. Two kinds
/// (issue 74): on arrival (`committed` false), so the actor stops publishing them again; and after the checkpoint
/// that holds them (`committed` true: stored, or refused or dropped as copies for good), so the actor forgets them.
/// Until then the actor's outbox keeps each segment (at least once on the wire; the learner's ledger makes it
/// exactly once in the replay), and when a receipt comes from another learner process (a learner killed and resumed
/// from its checkpoint) it publishes again what the old one received and never committed (`cabc_bus::outbox`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ack {
    pub incarnation: u64,
    pub seqs: Vec<u64>,
    pub learner: u64,
    pub committed: bool,
}

/// A segment's identity: (actor, incarnation, seq), as the learner's ledger keys it.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SegmentId {
    pub actor: String,
    pub incarnation: u64,
    pub seq: u64,
}

impl SegmentId {
    pub fn of(segment: &Segment) -> Self {
        SegmentId {
            actor: segment.actor.clone(),
            incarnation: segment.incarnation,
            seq: segment.seq,
        }
    }
}

/// The learner ends the run.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stop {
    pub reason: String,
}
