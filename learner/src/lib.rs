//! cabc-learner: the learning core of constraint-aware behaviour cloning (the paper's Algorithm 1):
//!
//! * [`replay`]: D+, D? and the dynamics-only store, filled from segments, saved to disk;
//! * [`autolabel`]: safety auto-labelling, eq. (20)-(21), over a k-d tree ([`kdtree`]) and an exact hull test
//!   ([`hull`]);
//! * [`train`]: the dynamics model, the critic and the policy with L_CA = L_clone + L_safety (eq. (15)-(17));
//! * [`demo`]: the paper's Fig. 3 reproduced; [`bench`]: throughput figures;
//! * [`epoch`]: the epoch protocol; [`rundir`]: the run folder and checkpoints; [`plots`]: the run's plots;
//!   `serve` (feature `server`): the learner process over zenoh.
//!
//! Apart from `serve` (behind the `server` feature), the library knows nothing of the bus.

pub mod algorithm;
pub mod autolabel;
pub mod bench;
pub mod demo;
pub mod hull;
pub mod kdtree;
pub mod learner;
pub mod ledger;
pub mod plots;
pub mod replay;
pub mod rundir;
pub mod schedule;
#[cfg(feature = "server")]
pub mod serve;
pub mod train;

pub use autolabel::{autolabel, autolabel_replay, AutolabelOptions, AutolabelReport};
pub use replay::{Replay, ReplayError};
pub use train::{EpochLosses, TrainError, Trainer};
