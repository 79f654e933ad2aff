//! cabc-learner: the learning core of constraint-aware behaviour cloning (the paper's Algorithm 1):
//!
//! * [`replay`]: D+, D? and the dynamics-only store, filled from segments, saved to disk;
//! * [`autolabel`]: safety auto-labelling, eq. (20)-(21), over a k-d tree ([`kdtree`]) and an exact hull test
//!   ([`hull`]);
//! * [`train`]: the dynamics model, the critic and the policy with L_CA = L_clone + L_safety (eq. (15)-(17));
//! * [`demo`]: the paper's Fig. 3 reproduced; [`bench`]: throughput figures.
//!
//! The library knows nothing of the bus; the `learner` binary's `run` subcommand connects it to zenoh.

pub mod autolabel;
pub mod bench;
pub mod demo;
pub mod hull;
pub mod kdtree;
pub mod replay;
pub mod train;

pub use autolabel::{autolabel, autolabel_replay, AutolabelOptions, AutolabelReport};
pub use replay::{Replay, ReplayError};
pub use train::{EpochLosses, TrainError, Trainer};
