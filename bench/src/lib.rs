//! cabc-bench: demonstrations and benchmarks of the learning core (`cabc demo`, `cabc bench`, `cabc bench-vision`):
//!
//! * [`demo`]: the paper's Fig. 3, auto-labelling and the critic it trains on a constructed 2-d example;
//! * [`throughput`]: auto-labelling's and training's throughput (CPU, and CUDA where there is one);
//! * [`vision`]: the camera policy's training and inference images per second.

pub mod demo;
pub mod throughput;
pub mod vision;
