//! cabc-learner: the learning core of constraint-aware behaviour cloning (the paper's Algorithm 1):
//!
//! * [`algorithm`]: Algorithm 1 on one screen, over the actors' port (`cabc_proto::ports::Rollouts`);
//! * [`learner`]: what the learner holds between epochs (replay, networks, ledger, evaluations, checkpoint);
//! * [`record`]: an epoch's metrics as one record, each put where it is computed, and the port ([`record::Sink`]) the
//!   learner writes through; [`outputs`]: its sinks (the run folder, TensorBoard, the progress bar, the bus);
//! * [`evaluations`]: the evaluations, early stopping, the best version;
//! * [`replay`]: D+, D?, D- and the dynamics-only store, filled from segments;
//! * [`autolabel`]: safety auto-labelling, eq. (19), over a k-d tree ([`kdtree`]) and an exact hull test ([`hull`]);
//! * [`schedule`]: when each part of Algorithm 1 runs (k_f, k_p, auto-labelling, warm-up);
//! * [`train`]: the dynamics model (eq. (15)), the critic (eq. (16)) and the policy with L_CA = L_clone + L_safety
//!   (eq. (14));
//! * [`checkpoint`]: the one checkpoint writer (atomic) and reader;
//! * [`demo`]: the paper's Fig. 3 reproduced; [`bench`]: throughput figures;
//! * [`ledger`]: exactly-once storage of segments; [`rundir`]: the run folder; [`plots`]: the run's plots;
//!   `serve` (feature `server`): `learner run`, Algorithm 1 with the actors over zenoh; `show` (feature `server`): a
//!   run's evaluation videos on request; [`video`]: the GIFs.
//!
//! Apart from `serve` (behind the `server` feature), the library knows nothing of the bus.
//! A run's data as a LeRobot dataset (parquet) is the cabc-export crate's (`cabc export`), so that the learning core
//! depends on no arrow or parquet.

pub mod algorithm;
pub mod autolabel;
pub mod bench;
pub mod bench_vision;
pub mod checkpoint;
pub mod compare;
pub mod demo;
pub mod evaluations;
pub mod fault;
pub mod groups;
pub mod hull;
pub mod intervals;
pub mod kdtree;
pub mod learner;
pub mod ledger;
pub mod outputs;
pub mod plots;
pub mod provenance;
pub mod record;
pub mod replay;
pub mod rundir;
pub mod schedule;
pub mod seeds;
#[cfg(feature = "server")]
pub mod serve;
#[cfg(feature = "server")]
pub mod show;
pub mod tensorboard;
pub mod train;
pub mod video;

pub use autolabel::{autolabel, autolabel_replay, AutolabelOptions, AutolabelReport};
pub use checkpoint::{Checkpoint, CheckpointError, CheckpointWriter};
pub use replay::{Replay, ReplayError};
pub use schedule::Schedule;
pub use train::{CriticFit, EpochLosses, Fit, PolicyFit, TrainError, Trainer};
