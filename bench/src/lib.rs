//! cabc-bench: demonstrations and benchmarks of the learning core and of a run's policy (`cabc demo`, `cabc bench`,
//! `cabc bench-epoch`, `cabc bench-vision`, `cabc robust`):
//!
//! * [`epoch`]: one epoch of a run's configuration, timed per phase against its floor;
//! * [`demo`]: the paper's Fig. 3, auto-labelling and the critic it trains on a constructed 2-d example;
//! * [`throughput`]: auto-labelling's and training's throughput (CPU, and CUDA where there is one);
//! * [`vision`]: the camera policy's training and inference images per second;
//! * [`robust`]: a policy's robustness (`cabc robust`): crashes, laps and lap times from random spawns under action
//!   and state noise.
//!
//! Why one crate: each is a measurement made from outside a run, over the libraries a run uses (the learning core,
//! the models, the evaluator's loop, the expert), that ends in a table or a figure of the paper; none is linked into
//! a run's processes. They share their tools (the figures of `cabc-outputs`, the analysis' intervals, the synthetic
//! replay of [`throughput`] that [`epoch`] times too), so apart they would be small crates with one dependency list.
//! The robustness study is not beside the evaluator in `cabc-actor`: it would bring the figures (plotters) and the
//! analysis into the actor, which every machine of a run starts.

pub mod demo;
pub mod epoch;
pub mod robust;
pub mod throughput;
pub mod vision;
