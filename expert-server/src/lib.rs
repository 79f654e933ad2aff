//! cabc-expert: the experts (MPCC-conv on Clarabel, the PID lane follower) and the expert server.
//!
//! The library is the controller: [`mpcc`] (expert.md §1–§9), the RK4 prediction model with exact Jacobians
//! ([`rk4`]), the not-a-knot track splines ([`spline`]), and closed-loop drives and the step-time benchmark
//! ([`drive`]: `drive`, `drive_from`, `bench`). The `expert-server` binary (feature `server`) is a thin zenoh
//! shell over it. The PID expert lives in `cabc-sim` (`PidLaneFollower`).

pub mod drive;
pub mod mpcc;
pub mod relabel;
pub mod rk4;
pub mod spline;

pub use drive::{
    bench, drive, drive_from, fixed_spawn, BenchReport, DriveEnd, DriveOptions, DriveReport,
    DriveStep,
};
pub use mpcc::{Mpcc, MpccConfig, MpccError, MpccStep, MpccStream, Prediction, QpStatus};
