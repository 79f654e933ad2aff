//! `_core.Expert`: the PID lane follower (`cabc_sim::pid`) and MPCC-conv (`cabc_expert::mpcc`) as callables,
//! `expert(state) -> action`, for DAgger in Python.
//!
//! Both keep memory between calls, per stream: the PID its error history and rate limit, the MPCC its warm start
//! (the shifted plan) and cached solver, as the expert server keeps them per (actor, environment, episode). Row i
//! of a batch call `expert(states)` with `states` of shape (n, 6) is stream i (environment i of a vector env); a
//! single state of shape (6,) is stream 0. `reset()` (all streams) or `reset(i)` starts anew, as a new episode
//! must: the expert server cold-starts a stream at an episode's first query the same way.

use std::sync::Arc;

use cabc_expert::mpcc::{Mpcc, MpccStream};
use cabc_proto::config::RunConfig;
use cabc_sim::pid::PidLaneFollower;
use cabc_sim::{Input, State, Track};
use numpy::PyArray1;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use rayon::prelude::*;

use crate::arrays::{f64s, rows};
use crate::car::{sim_section, track_of};

/// Most streams one expert keeps.
const MAX_STREAMS: usize = 65_536;

enum Kind {
    /// The PID lane follower at this target speed (m/s).
    Pid(f64),
    Mpcc(Arc<Mpcc>),
}

enum Memory {
    Pid(Box<PidLaneFollower>),
    /// None until the stream's first state (the MPCC starts from it).
    Mpcc(Option<Box<MpccStream>>),
}

/// An expert and its streams.
#[pyclass(module = "cabc._core")]
pub struct Expert {
    kind: Kind,
    streams: Vec<Memory>,
    /// Per row of the last call: whether the expert solved its problem (the MPCC's QPs; the PID always).
    success: Vec<bool>,
    last_was_flat: bool,
}

impl Expert {
    fn fresh(&self) -> Memory {
        match &self.kind {
            Kind::Pid(target) => Memory::Pid(Box::new(PidLaneFollower::new(*target))),
            Kind::Mpcc(_) => Memory::Mpcc(None),
        }
    }
}

/// The vehicle state q = [v_x, v_y, ω, X, Y, ψ] of a Frenet state [v_long, v_tran, ω, s, x_tran, e_psi] on
/// `track`.
fn vehicle_of(track: &Track, state: &[f64; 6]) -> State {
    // s brought into [0, L) here: the track's own wrapping steps by L, slow for a huge s.
    let s = state[3].rem_euclid(track.length());
    let pose = track.local_to_global(s, state[4], state[5]);
    [state[0], state[1], state[2], pose.x, pose.y, pose.psi]
}

#[pymethods]
impl Expert {
    /// `name`: "pid" or "mpcc"; `target_speed`: the PID's (m/s; the reference's 1.0 when not given); `track`,
    /// `track_scale`, `track_half_width`: the track the MPCC drives, as the environment's (the L-track when not
    /// given; the PID follows the lane of any track, so its track is only checked).
    #[new]
    #[pyo3(signature = (name, target_speed=None, track=None, track_scale=None, track_half_width=None))]
    fn new(
        name: &str,
        target_speed: Option<f64>,
        track: Option<&str>,
        track_scale: Option<f64>,
        track_half_width: Option<f64>,
    ) -> PyResult<Expert> {
        let sim = sim_section(track, track_scale, track_half_width);
        // A bad track is the environment's ValueError, whichever the expert.
        track_of(&sim)?;
        let kind = match (name, target_speed) {
            ("pid", None) => Kind::Pid(PidLaneFollower::default().speed.x_ref),
            ("pid", Some(v)) if v.is_finite() && v > 0.0 => Kind::Pid(v),
            ("pid", Some(v)) => {
                return Err(PyValueError::new_err(format!(
                    "target_speed must be a positive number, got {v}"
                )))
            }
            // The reference MPCC (`Mpcc::reference`, the default configuration's) on the track.
            ("mpcc", None) => {
                let config = RunConfig {
                    sim,
                    ..RunConfig::default()
                };
                let mpcc = Mpcc::from_config(&config).map_err(|e| {
                    PyValueError::new_err(format!("the MPCC cannot drive this track: {e}"))
                })?;
                Kind::Mpcc(Arc::new(mpcc))
            }
            ("mpcc", Some(_)) => {
                return Err(PyValueError::new_err(
                    "target_speed is the PID's: the MPCC has none",
                ))
            }
            _ => {
                return Err(PyValueError::new_err(format!(
                    "unknown expert {name:?}: expected \"pid\" or \"mpcc\""
                )))
            }
        };
        Ok(Expert {
            kind,
            streams: Vec::new(),
            success: Vec::new(),
            last_was_flat: true,
        })
    }

    /// The action [a, δ] for `state` = [v_long, v_tran, ω, s, x_tran, e_psi] (the observation, or `info["state"]`
    /// of a camera env), shape (6,) -> (2,) or (n, 6) -> (n, 2). The MPCC measures the car's pose from the Frenet
    /// state, or takes `vehicle` = [v_x, v_y, ω, X, Y, ψ] (`info["vehicle_state"]`, same shape as `state`) when given.
    #[pyo3(signature = (state, vehicle=None))]
    fn __call__<'py>(
        &mut self,
        py: Python<'py>,
        state: &Bound<'py, PyAny>,
        vehicle: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (states, flat) = rows::<6>(state, "state", None, true)?;
        let n = states.len();
        if n > MAX_STREAMS {
            return Err(PyValueError::new_err(format!(
                "at most {MAX_STREAMS} states a call, got {n}"
            )));
        }
        while self.streams.len() < n {
            let fresh = self.fresh();
            self.streams.push(fresh);
        }
        let mut actions: Vec<Input> = vec![[0.0; 2]; n];
        let mut success = vec![true; n];
        match &self.kind {
            Kind::Pid(_) => {
                for ((memory, s), a) in self.streams.iter_mut().zip(&states).zip(&mut actions) {
                    if let Memory::Pid(pid) = memory {
                        *a = pid.action(s[0], s[4], s[5]);
                    }
                }
            }
            Kind::Mpcc(mpcc) => {
                let qs: Vec<State> = match vehicle {
                    Some(v) => {
                        let (qs, _) = rows::<6>(v, "vehicle", Some(n), flat)?;
                        qs
                    }
                    None => states.iter().map(|s| vehicle_of(mpcc.track(), s)).collect(),
                };
                let track = mpcc.track();
                // Checked before any stream moves, so a bad row leaves every stream as it was.
                if let Some((i, q)) = qs
                    .iter()
                    .enumerate()
                    .find(|(_, q)| track.global_to_local(q[3], q[4], q[5]).is_err())
                {
                    return Err(PyValueError::new_err(format!(
                        "state {i} is off the track's band (|x_tran| > {}): the MPCC cannot measure it ({q:?})",
                        track.band()
                    )));
                }
                let mpcc = mpcc.clone();
                let streams = &mut self.streams[..n];
                let solved: Vec<Result<(Input, bool), String>> = py.detach(|| {
                    streams
                        .par_iter_mut()
                        .zip(qs.par_iter())
                        .map(|(memory, q)| solve(&mpcc, memory, q))
                        .collect()
                });
                for (i, r) in solved.into_iter().enumerate() {
                    let (a, ok) = r.map_err(|e| {
                        PyRuntimeError::new_err(format!("the MPCC failed on state {i}: {e}"))
                    })?;
                    actions[i] = a;
                    success[i] = ok;
                }
            }
        }
        self.success = success;
        self.last_was_flat = flat;
        if flat {
            Ok(PyArray1::from_slice(py, &actions[0]).into_any())
        } else {
            f64s(py, actions.concat(), &[n, 2])
        }
    }

    /// Forgets the memory of every stream, or of stream `index` (an int or a sequence of ints).
    #[pyo3(signature = (index=None))]
    fn reset(&mut self, index: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let indices: Vec<usize> = match index {
            None => (0..self.streams.len()).collect(),
            Some(i) => match i.extract::<usize>() {
                Ok(one) => vec![one],
                Err(_) => i.extract::<Vec<usize>>().map_err(|_| {
                    PyValueError::new_err("index must be a non-negative int or a sequence of them")
                })?,
            },
        };
        for i in indices {
            if i >= MAX_STREAMS {
                return Err(PyValueError::new_err(format!(
                    "stream {i} is beyond the limit of {MAX_STREAMS}"
                )));
            }
            if i < self.streams.len() {
                self.streams[i] = self.fresh();
            }
        }
        Ok(())
    }

    /// Whether the expert solved its problem at the last call's state(s): a bool, or an (n,) bool array.
    #[getter]
    fn success<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        if self.last_was_flat {
            Ok(self
                .success
                .first()
                .copied()
                .unwrap_or(true)
                .into_pyobject(py)?
                .to_owned()
                .into_any())
        } else {
            Ok(PyArray1::from_slice(py, &self.success).into_any())
        }
    }

    #[getter]
    fn name(&self) -> &'static str {
        match self.kind {
            Kind::Pid(_) => "pid",
            Kind::Mpcc(_) => "mpcc",
        }
    }
}

/// One MPCC step of a stream (started at `q` on its first state): the action and whether its QPs solved.
fn solve(mpcc: &Mpcc, memory: &mut Memory, q: &State) -> Result<(Input, bool), String> {
    let Memory::Mpcc(slot) = memory else {
        return Err("a PID stream in an MPCC expert".into());
    };
    if slot.is_none() {
        *slot = Some(Box::new(mpcc.start(q).map_err(|e| e.to_string())?));
    }
    let stream = slot.as_mut().ok_or("no stream")?;
    let step = mpcc.step(stream, q).map_err(|e| e.to_string())?;
    Ok((step.action, step.success))
}
