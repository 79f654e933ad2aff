//! cabc-actor: the actor of Algorithm 1: K simulators stepped in lockstep under the expert/policy mixture, their
//! streams cut into segments, and the evaluation of each new policy. Zenoh-free; the `actor` binary is the thin
//! shell that wires it to the bus, so tests drive the same code in-process.

pub mod collect;
pub mod evaluate;
pub mod eyes;
pub mod segment;
