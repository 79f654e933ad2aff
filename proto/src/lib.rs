//! cabc-proto: the wire protocol of cabc and the run configuration.
//!
//! * [`messages`]: what travels on the bus (policy updates, trajectory segments, expert queries, evaluation
//!   reports, stop);
//! * [`keys`]: every zenoh key expression, built in one place;
//! * [`codec`]: `encode` / `decode` with a header (magic + schema version + message kind), so a stale or foreign
//!   payload is refused with a typed error, never half-read;
//! * [`config`]: the run configuration (TOML), the one place for every number that defines an experiment;
//! * [`ports`]: the narrow interfaces between the parts of Algorithm 1 (expert client, policy source, segment
//!   sink, evaluation sink; the actors as the learner sees them);
//! * [`run_name`]: the campaign's run names, `<experiment>-s<k>[-baseline]` with seed 41 + k, parsed and printed in
//!   one place;
//! * [`stats`]: mean / standard deviation and nearest-rank percentiles, the one definition for every report;
//! * [`telemetry`]: `tracing` set up the same way in every binary.
//!
//! This crate knows nothing of zenoh or tch.

pub mod codec;
pub mod config;
pub mod keys;
pub mod messages;
pub mod ports;
pub mod run_name;
pub mod stats;
pub mod telemetry;

pub use codec::{decode, encode, DecodeError, Message};
pub use config::RunConfig;
