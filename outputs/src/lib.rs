//! cabc-outputs: a run folder and what a run writes into it, the sinks of the learning core's records
//! (`cabc_learning::sink::Sink`):
//!
//! * [`rundir`]: the run folder (`config.toml`, `metrics.csv`, `evals.csv`, `summary.json`, written atomically);
//! * [`sinks`]: the sinks (the run folder's files, TensorBoard's events, the progress bar) and [`learner`], the
//!   learner of a run folder with all three;
//! * [`plots`]: the run's plots (PNG, plotters), and the drawing helpers the analysis's figures share;
//! * [`redraw`]: a kept run folder's plots redrawn from its small files (`cabc plots RUN`);
//! * [`video`]: the evaluations' GIFs (the track, the car, a camera run's view);
//! * [`tensorboard`]: TensorBoard's event files, written and read without TensorFlow.

pub mod plots;
pub mod redraw;
pub mod rundir;
pub mod sinks;
pub mod tensorboard;
pub mod video;

pub use rundir::RunDir;
pub use sinks::{learner, learner_on_bus};
