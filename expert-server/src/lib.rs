//! cabc-expert: the experts (MPCC-conv on Clarabel, the PID lane follower) and the expert server.
//!
//! The library is the controller: [`mpcc`] (expert.md §1–§9), the RK4 prediction model with exact Jacobians
//! ([`rk4`]), the not-a-knot track splines ([`spline`]), the relabelling service ([`relabel`]), closed-loop drives
//! in `sim::Env` ([`drive`]) and the step-time and throughput benchmarks ([`bench`]). The `expert-server` binary
//! (feature `server`) is a thin zenoh shell over it. The PID expert lives in `cabc-sim` (`PidLaneFollower`).

pub mod bench;
pub mod drive;
pub mod mpcc;
pub mod relabel;
pub mod rk4;
pub mod spline;
pub mod tracks;

pub use bench::{bench, BenchReport};
pub use drive::{drive, drive_from, DriveEnd, DriveOptions, DriveReport, DriveStep};
pub use mpcc::{Mpcc, MpccConfig, MpccError, MpccStep, MpccStream, Prediction, QpStatus};
