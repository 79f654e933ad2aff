//! cabc-bench: demonstrations and benchmarks of the learning core (`cabc demo`, `cabc bench`, `cabc bench-epoch`,
//! `cabc bench-vision`, `cabc bench-bus`):
//!
//! * [`capacity`]: one learner's intake over the bus under N synthetic actors (steps/s, CPU per step by stage, the
//!   receipts' round trip, the policy's broadcast, nothing lost);
//! * [`epoch`]: one epoch of a run's configuration, timed per phase against its floor;
//! * [`demo`]: the paper's Fig. 3, auto-labelling and the critic it trains on a constructed 2-d example;
//! * [`throughput`]: auto-labelling's and training's throughput (CPU, and CUDA where there is one);
//! * [`vision`]: the camera policy's training and inference images per second.
//!
//! Why one crate: each is a measurement of the learning core's speed or behaviour made from outside a run, and they
//! share their tools (the synthetic replay of [`throughput`] that [`epoch`] times too). A policy's robustness
//! (`cabc robust`) is a study of a run's result, not of the core: its own crate, cabc-robust (issue 67).

pub mod capacity;
pub mod demo;
pub mod epoch;
pub mod throughput;
pub mod vision;
