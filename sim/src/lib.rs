//! cabc-sim: the racing simulator of the seed paper, ported from its reference implementation
//! (simulator.md): the `L_track_barc` track with Frenet conversions ([`track`]), the dynamic bicycle
//! ([`vehicle`]), the PID lane-follower expert ([`pid`]), the gym-like environment and the one definition of the
//! plant's numbers ([`env`]: dt, truncation limits, the fixed spawn) and a CPU first-person camera ([`camera`]);
//! around them, the `cabc-sim` tool's rollouts ([`rollout`], [`trace`]), track maps ([`map`]) and throughput
//! benchmark ([`bench`]). It knows nothing of the bus or of the learner (only the protocol's plain types).

pub mod bench;
pub mod camera;
pub mod env;
pub mod map;
pub mod pid;
pub mod rollout;
pub mod trace;
pub mod track;
pub mod vehicle;

pub use camera::{Camera, Frame, Sun, TrackLookup};
pub use env::{
    Env, EnvBatch, EnvConfig, EnvObservation, Spawn, StepResult, Truncation, DT, FIXED_SPAWN,
    FIXED_SPAWN_SPEED,
};
pub use pid::PidLaneFollower;
pub use track::{Frenet, Pose, Track, TrackError, TrackPiece};
pub use vehicle::{clip_action, Input, State, VehicleParams, ACTION_HIGH, ACTION_LOW};
