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

/// The run's expert client by `expert.placement`: the expert servers over `bus` (waiting up to `expert.timeout_s`
/// for an answer), or this actor's own [`Relabeller`].
pub fn of_run<'a>(
    config: &RunConfig,
    bus: &'a cabc_bus::Bus,
    interrupt: &cabc_bus::interrupt::Interrupt,
    stats: cabc_bus::ports::SharedStats,
) -> Result<Box<dyn cabc_proto::ports::ExpertClient + 'a>, ClientError> {
    Ok(match config.expert.placement {
        cabc_proto::config::ExpertPlacement::Server => {
            Box::new(cabc_bus::expert::ZenohExpert::new(
                bus,
                config.expert.kind.as_str(),
                std::time::Duration::from_secs_f64(config.expert.timeout_s),
                interrupt,
                stats,
            )?)
        }
        cabc_proto::config::ExpertPlacement::InActor => Box::new(in_actor(config)?),
    })
}

/// Why the run's expert client could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("the expert servers' client: {0}")]
    Bus(#[from] cabc_proto::ports::PortError),
    #[error("the actor's own expert: {0}")]
    InActor(#[from] MpccError),
}
