//! The actor's expert when it solves its own relabellings (`expert.placement = "in-actor"`): the expert servers'
//! [`Relabeller`] in this process, so that a step waits for the solve alone, not for a round trip over the bus. The
//! answers are the servers' (the same code, each environment's warm start in its own stream); the bus's client of
//! the servers is `cabc_bus::expert::ZenohExpert`.

use cabc_expert::mpcc::MpccError;
use cabc_expert::relabel::{Expert, Relabeller};
use cabc_proto::config::RunConfig;

/// The run's expert (`expert.kind`, built from the configuration as a server builds it) as this actor's client.
pub fn in_actor(config: &RunConfig) -> Result<Relabeller, MpccError> {
    let expert = Expert::from_config(config)?;
    Ok(Relabeller::new(
        expert,
        config.expert.max_streams,
        config.expert.max_batch,
    ))
}
