//! cabc-learning: the learning core of constraint-aware behaviour cloning, the paper's Algorithm 1 and the state it
//! keeps between epochs. It knows nothing of the bus, the run folder's files, plots, videos, TensorBoard or datasets:
//! it keeps its checkpoint through one port, [`checkpointer::Checkpointer`], and writes everything else through
//! another, [`sink::Sink`].
//!
//! Algorithm 1, line by line, and where each part lives:
//!
//! | Algorithm 1 | file |
//! |---|---|
//! | the loop: collect with beta-mixing, partition, auto-label, train, publish, evaluate | [`algorithm`] |
//! | what is held between epochs (replay, networks, ledger, evaluations, checkpoint) | [`learner`], [`state`] |
//! | "store trajectories in D+ / D?" (completed laps; failed episodes' steps), D- | [`replay`], [`ledger`] (exactly once), [`provenance`] |
//! | "auto-label D?": eq. (19), local convex hulls of D+ | [`autolabel`], over [`kdtree`] and [`hull`] |
//! | "train f̂ on D+ ∪ D?": eq. (15) | [`train`] (`train/dynamics.rs`) |
//! | "train p̂ on D+ (safe) and D- (unsafe)": eq. (16) | [`train`] (`train/critic.rs`) |
//! | "train π on L_CA = L_clone + λ L_safety": eq. (14) | [`train`] (`train/policy.rs`) |
//! | when each part runs (k_f, k_p, labelling, λ warm-up) | [`schedule`] |
//! | the evaluations from the fixed spawn, early stopping, the best version | [`evaluations`] |
//! | an epoch's metrics, one line where each is computed | [`record`], written through [`sink`] |
//! | the run's summary (`summary.json`) | [`summary`] |
//! | what a run's data lets a policy copy (`cabc probe`, issue 58) | [`probe`] |
//! | the checkpoint: the learner's port | [`checkpointer`] (and one in memory), the learner's part in [`state`] |
//! | the checkpoint in a run folder (atomic, one writer) | [`checkpoint`]; old formats read in `replay::migrate` and `record::rows` |
//!
//! The actors are a port (`cabc_proto::ports::Rollouts`): over zenoh in a run (the `learner` binary), in-process
//! in a test. The sinks of a run folder (CSV tables, plots, GIFs, TensorBoard, the progress bar) are the
//! cabc-outputs crate's; the analysis over run folders is cabc-analysis's; the LeRobot export is cabc-export's.

pub mod algorithm;
pub mod autolabel;
pub mod checkpoint;
pub mod checkpointer;
pub mod evaluations;
pub mod fault;
pub mod hull;
pub mod kdtree;
pub mod learner;
pub mod ledger;
pub mod probe;
pub mod provenance;
pub mod record;
pub mod replay;
pub mod schedule;
pub mod sink;
pub mod state;
pub mod summary;
pub mod train;

pub use autolabel::{autolabel, autolabel_replay, AutolabelOptions, AutolabelReport};
pub use checkpoint::{Checkpoint, CheckpointError, CheckpointWriter};
pub use replay::{Replay, ReplayError};
pub use schedule::{Due, Schedule};
pub use train::{CriticFit, Fit, PolicyFit, TrainError, Trainer};
