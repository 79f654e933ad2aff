//! cabc-analysis: the analysis over finished (or running) run folders, `cabc compare`:
//!
//! * [`runs`]: a run folder read back ([`runs::RunRecord`]: its configuration, `metrics.csv`, `evals.csv`,
//!   `summary.json`);
//! * [`compare`]: the paper's figures for a set of runs and the table of runs;
//! * [`seeds`]: the figures over seeds per method; [`groups`]: the view over groups (a row per group and method, a
//!   column per seed);
//! * [`intervals`]: the statistics a reviewer accepts (IQM, stratified bootstrap, Wilson) over runs, on the
//!   numerics of [`stats`].
//!
//! Imports go one way: stats ← runs ← intervals ← seeds, groups ← compare.

pub mod compare;
pub mod groups;
pub mod intervals;
pub mod runs;
pub mod seeds;
pub mod stats;
