//! cabc-actor: the actor of Algorithm 1: K simulators stepped in lockstep under the expert/policy mixture
//! ([`collect`]), their streams cut into segments ([`segment`]), the evaluation of each new policy ([`evaluate`]),
//! and the actor's loop over its ports ([`run`]). Zenoh-free: the `actor` binary wires [`run`] to the bus, and
//! [`local`] runs the same code in-process as the learner's `Rollouts` port.

pub mod collect;
mod dart;
pub mod evaluate;
pub mod expert;
pub mod eyes;
pub mod journal;
pub mod local;
pub mod run;
pub mod segment;
pub mod sensor;
pub mod shield;
pub mod spawns;
