//! cabc-bench: demonstrations and benchmarks of the learning core and of a run's policy (`cabc demo`, `cabc bench`,
//! `cabc bench-epoch`, `cabc bench-vision`, `cabc robust`):
//!
//! * [`epoch`]: one epoch of a run's configuration, timed per phase against its floor;
//! * [`demo`]: the paper's Fig. 3, auto-labelling and the critic it trains on a constructed 2-d example;
//! * [`throughput`]: auto-labelling's and training's throughput (CPU, and CUDA where there is one);
//! * [`vision`]: the camera policy's training and inference images per second;
//! * [`robust`]: a policy's robustness (`cabc robust`): crashes, laps and lap times from random spawns under action
//!   and state noise.

pub mod demo;
pub mod epoch;
pub mod robust;
pub mod throughput;
pub mod vision;
