//! `cabc._core`: the cabc simulator and experts for Python (PyO3). The Gymnasium classes are Python, in `cabc/`;
//! this module holds what they step: one environment ([`env::Sim`]), n environments in one call
//! ([`vector::VecSim`]), the experts ([`expert::Expert`]), and the simulator's numbers, taken from `cabc-sim` so that
//! each stays defined in one place. Bad input (shapes, NaN, names) is a Python exception; nothing here panics on it.

mod arrays;
mod car;
mod env;
mod expert;
mod vector;

use cabc_sim::env::{DT, MAX_LAPS};
use cabc_sim::{ACTION_HIGH, ACTION_LOW};
use pyo3::prelude::*;

/// The bounds of the state observation [v_long, v_tran, ω, s, x_tran, e_psi]: the velocities are unbounded; s lies
/// on the centreline [0, L]; x_tran within the Frenet band (the simulator keeps the last value inside it); e_psi in
/// [-π, π].
fn state_bounds() -> ([f64; 6], [f64; 6]) {
    let track = car::track();
    let (inf, pi) = (f64::INFINITY, std::f64::consts::PI);
    let (band, length) = (track.band(), track.length());
    (
        [-inf, -inf, -inf, 0.0, -band, -pi],
        [inf, inf, inf, length, band, pi],
    )
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<env::Sim>()?;
    m.add_class::<vector::VecSim>()?;
    m.add_class::<expert::Expert>()?;
    m.add("ACTION_LOW", ACTION_LOW)?;
    m.add("ACTION_HIGH", ACTION_HIGH)?;
    let (low, high) = state_bounds();
    m.add("STATE_LOW", low)?;
    m.add("STATE_HIGH", high)?;
    m.add("DT", DT)?;
    m.add("MAX_LAPS", MAX_LAPS)?;
    m.add("TRACK_LENGTH", car::track().length())?;
    m.add("HALF_WIDTH", car::track().half_width())?;
    m.add("VERSION", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
