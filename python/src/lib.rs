//! `cabc._core`: the cabc simulator and experts for Python (PyO3). The Gymnasium classes are Python, in `cabc/`;
//! this module holds what they step: one environment ([`env::Sim`]), n environments in one call
//! ([`vector::VecSim`]), the experts ([`expert::Expert`]), and the simulator's numbers, taken from `cabc-sim` so that
//! each stays defined in one place (the track's, `TRACK_LENGTH`, `HALF_WIDTH`, `STATE_LOW`, `STATE_HIGH`, are the
//! default L-track's; an environment on another track has its own). Bad input (shapes, NaN, names, tracks) is a
//! Python exception; nothing here panics on it.

mod arrays;
mod car;
mod env;
mod expert;
mod vector;

use cabc_sim::env::{DT, MAX_LAPS};
use cabc_sim::{Track, ACTION_HIGH, ACTION_LOW};
use pyo3::prelude::*;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<env::Sim>()?;
    m.add_class::<vector::VecSim>()?;
    m.add_class::<expert::Expert>()?;
    m.add("ACTION_LOW", ACTION_LOW)?;
    m.add("ACTION_HIGH", ACTION_HIGH)?;
    // The L-track's, the default track: an environment's own are its `state_low`, `track_length`, ...
    let l_track = Track::l_track_barc();
    let (low, high) = car::state_bounds(&l_track);
    m.add("STATE_LOW", low)?;
    m.add("STATE_HIGH", high)?;
    m.add("DT", DT)?;
    m.add("MAX_LAPS", MAX_LAPS)?;
    m.add("TRACK_LENGTH", l_track.length())?;
    m.add("HALF_WIDTH", l_track.half_width())?;
    m.add("VERSION", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
