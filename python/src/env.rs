//! `_core.Sim`: one environment for `cabc.BarcTrackEnv` (the Gymnasium class in `cabc/env.py` is a thin shell over
//! it): reset, step, render, with the observation and the `info` dictionary built here.

use cabc_sim::camera::Camera;
use cabc_sim::EnvObservation;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::arrays::{row, u8s, vector};
use crate::car::{parse_spawn, see, sim_section, state_bounds, Car, Kind, Lens, Setup, Transition};

/// The observation object: the `(6,)` state, or `{"image": (H, W, 3) uint8, "velocity": (3,)}`.
pub fn observation<'py>(
    py: Python<'py>,
    kind: Kind,
    obs: &EnvObservation,
    image: Option<(Vec<u8>, &Lens)>,
) -> PyResult<Bound<'py, PyAny>> {
    match (kind, image) {
        (Kind::Camera, Some((rgb, lens))) => {
            let dict = PyDict::new(py);
            dict.set_item("image", u8s(py, rgb, &[lens.height, lens.width, 3])?)?;
            dict.set_item("velocity", velocity(py, obs))?;
            Ok(dict.into_any())
        }
        _ => Ok(vector(py, &obs.state).into_any()),
    }
}

/// [v_long, v_tran, omega]: the velocities beside a camera image (the learner's `velocity_of`).
pub fn velocity<'py>(py: Python<'py>, obs: &EnvObservation) -> Bound<'py, PyAny> {
    vector(py, &[obs.state[0], obs.state[1], obs.state[2]]).into_any()
}

/// One environment.
#[pyclass(module = "cabc._core")]
pub struct Sim {
    setup: Setup,
    kind: Kind,
    lens: Lens,
    camera: Camera,
    car: Car,
}

impl Sim {
    fn image(&mut self) -> Vec<u8> {
        let mut rgb = vec![0; self.lens.image_len()];
        see(&mut self.camera, &self.setup.road, &self.car.env, &mut rgb);
        rgb
    }

    fn obs<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let image = (self.kind == Kind::Camera).then(|| self.image());
        let obs = self.car.env.observation();
        observation(py, self.kind, &obs, image.map(|i| (i, &self.lens)))
    }

    fn info<'py>(&self, py: Python<'py>, t: &Transition) -> PyResult<Bound<'py, PyDict>> {
        let env = &self.car.env;
        let info = PyDict::new(py);
        info.set_item("laps", t.laps)?;
        info.set_item("lap_times", PyList::new(py, env.lap_times())?)?;
        info.set_item("lap_completed", t.lap_time.is_some())?;
        info.set_item("lap_time", t.lap_time)?;
        info.set_item("end_reason", t.end.map(|e| e.to_string()))?;
        info.set_item("state", vector(py, &env.observation().state))?;
        info.set_item("vehicle_state", vector(py, &env.vehicle_state()))?;
        info.set_item("time", env.time())?;
        Ok(info)
    }
}

#[pymethods]
impl Sim {
    /// observation: "state" or "camera"; spawn: "random" or "fixed" (the default of every reset); width, height,
    /// fov: the camera's (the observation's when it is "camera", the rendering's always); max_laps: the simulator's
    /// lap limit; max_episode_steps: an optional step limit; track, track_scale, track_half_width: the track (a
    /// run's `sim.track`, `sim.track_scale`, `sim.track_half_width`; the L-track when not given).
    #[new]
    #[pyo3(signature = (observation="state", spawn="random", width=None, height=None, fov=None, max_laps=None, max_episode_steps=None, track=None, track_scale=None, track_half_width=None))]
    #[allow(clippy::too_many_arguments)] // Gymnasium's keyword arguments
    fn new(
        observation: &str,
        spawn: &str,
        width: Option<usize>,
        height: Option<usize>,
        fov: Option<f64>,
        max_laps: Option<u32>,
        max_episode_steps: Option<u64>,
        track: Option<&str>,
        track_scale: Option<f64>,
        track_half_width: Option<f64>,
    ) -> PyResult<Sim> {
        let sim = sim_section(track, track_scale, track_half_width);
        let setup = Setup::new(&sim, spawn, max_laps, max_episode_steps)?;
        let lens = Lens::new(width, height, fov)?;
        Ok(Sim {
            kind: observation.parse()?,
            camera: lens.camera(),
            lens,
            car: Car::new(&setup, 0, 0),
            setup,
        })
    }

    /// Starts an episode: with `seed`, from stream 0 of that seed (as `cabc-sim rollout --seed`); `spawn` overrides
    /// the default for this episode. Returns (observation, info).
    #[pyo3(signature = (seed=None, spawn=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<u64>,
        spawn: Option<&str>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyDict>)> {
        let spawn = spawn
            .map(parse_spawn)
            .transpose()?
            .unwrap_or(self.setup.spawn);
        if let Some(seed) = seed {
            self.car.reseed(seed, 0);
        }
        self.car.reset(spawn);
        let info = self.info(py, &Transition::default())?;
        Ok((self.obs(py)?, info))
    }

    /// One step of 0.1 s with `action` = [a (m/s²), δ (rad)], clipped to the box. Returns (observation, reward,
    /// terminated, truncated, info).
    #[allow(clippy::type_complexity)] // Gymnasium's step tuple
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyAny>, f64, bool, bool, Bound<'py, PyDict>)> {
        let action = row::<2>(action, "action")?;
        let t = self.car.step(&action, &self.setup);
        let info = self.info(py, &t)?;
        Ok((self.obs(py)?, t.reward, t.terminated, t.truncated, info))
    }

    /// The first-person camera's view now, (height, width, 3) uint8.
    fn render<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let rgb = self.image();
        u8s(py, rgb, &[self.lens.height, self.lens.width, 3])
    }

    /// The camera's (height, width).
    #[getter]
    fn image_shape(&self) -> (usize, usize) {
        (self.lens.height, self.lens.width)
    }

    /// The track's centreline length (m).
    #[getter]
    fn track_length(&self) -> f64 {
        self.setup.road.track.length()
    }

    /// The track's half-width (m): the constraint |x_tran| <= half_width.
    #[getter]
    fn half_width(&self) -> f64 {
        self.setup.road.track.half_width()
    }

    /// The bounds of the state observation on this track: (low, high), each [v_long, v_tran, ω, s, x_tran, e_psi].
    #[getter]
    fn state_bounds(&self) -> ([f64; 6], [f64; 6]) {
        state_bounds(&self.setup.road.track)
    }

    /// The track in words ("the L-shaped BARC track", or its file and size).
    #[getter]
    fn track(&self) -> String {
        self.setup.road.track.describe().to_string()
    }

    #[getter]
    fn observation(&self) -> &'static str {
        match self.kind {
            Kind::State => "state",
            Kind::Camera => "camera",
        }
    }
}
