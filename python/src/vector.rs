//! `_core.VecSim`: n environments stepped in one call (`cabc.make_vec`), NumPy arrays in and out. An environment
//! whose episode ends is reset in the same call (Gymnasium's `AutoresetMode.SAME_STEP`): the returned observation is
//! the new episode's, the last one's is in `info["final_obs"]`. The stepping runs without the GIL.

use cabc_proto::messages::EndReason;
use cabc_sim::camera::Camera;
use cabc_sim::{EnvObservation, Input};
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{f64s, rows, u8s};
use crate::car::{parse_spawn, see, sim_section, state_bounds, Car, Kind, Lens, Setup};
use crate::env::observation;

/// Most environments in one object, and most bytes of their images (bounds on what one call allocates).
const MAX_ENVS: usize = 65_536;
const MAX_IMAGE_BYTES: usize = 1 << 32;

/// What one environment's step left for the arrays.
#[derive(Clone, Copy, Default)]
struct Outcome {
    reward: f64,
    terminated: bool,
    truncated: bool,
    laps: u32,
    lap_time: Option<f64>,
    end: Option<EndReason>,
    /// The last observation of an episode that ended (the returned one is the next episode's).
    last: Option<EnvObservation>,
}

/// n environments, env i drawing from stream i of the seed.
#[pyclass(module = "cabc._core")]
pub struct VecSim {
    setup: Setup,
    kind: Kind,
    lens: Lens,
    camera: Camera,
    cars: Vec<Car>,
    outcomes: Vec<Outcome>,
    /// The images of the observation (camera), n x H x W x 3, filled without the GIL.
    images: Vec<u8>,
    /// The last images of the episodes that ended in this call (camera), by environment.
    last_images: Vec<Option<Vec<u8>>>,
}

impl VecSim {
    fn render_all(&mut self) {
        let len = self.lens.image_len();
        if self.kind == Kind::Camera {
            for (car, out) in self.cars.iter().zip(self.images.chunks_exact_mut(len)) {
                see(&mut self.camera, &self.setup.road, &car.env, out);
            }
        }
    }

    /// Observations of every environment: (n, 6), or {"image": (n, H, W, 3), "velocity": (n, 3)}.
    fn observations<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let n = self.cars.len();
        let states: Vec<f64> = self
            .cars
            .iter()
            .flat_map(|c| c.env.observation().state)
            .collect();
        match self.kind {
            Kind::State => f64s(py, states, &[n, 6]),
            Kind::Camera => {
                let velocity: Vec<f64> = states
                    .chunks_exact(6)
                    .flat_map(|s| [s[0], s[1], s[2]])
                    .collect();
                let dict = PyDict::new(py);
                let (h, w) = (self.lens.height, self.lens.width);
                dict.set_item("image", u8s(py, self.images.clone(), &[n, h, w, 3])?)?;
                dict.set_item("velocity", f64s(py, velocity, &[n, 3])?)?;
                Ok(dict.into_any())
            }
        }
    }
}

#[pymethods]
impl VecSim {
    /// `n` environments; the other arguments as `Sim`'s.
    #[new]
    #[pyo3(signature = (n, observation="state", spawn="random", width=None, height=None, fov=None, max_laps=None, max_episode_steps=None, track=None, track_scale=None, track_half_width=None))]
    #[allow(clippy::too_many_arguments)] // Gymnasium's keyword arguments
    fn new(
        n: usize,
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
    ) -> PyResult<VecSim> {
        if !(1..=MAX_ENVS).contains(&n) {
            return Err(PyValueError::new_err(format!(
                "n must be within 1..={MAX_ENVS}, got {n}"
            )));
        }
        let setup = Setup::new(
            &sim_section(track, track_scale, track_half_width),
            spawn,
            max_laps,
            max_episode_steps,
        )?;
        let kind: Kind = observation.parse()?;
        let lens = Lens::new(width, height, fov)?;
        let image_bytes = match kind {
            Kind::Camera => n * lens.image_len(),
            Kind::State => 0,
        };
        if image_bytes > MAX_IMAGE_BYTES {
            return Err(PyValueError::new_err(format!(
                "{n} cameras of {}x{} need {image_bytes} bytes of images a step, more than {MAX_IMAGE_BYTES}",
                lens.width, lens.height
            )));
        }
        Ok(VecSim {
            cars: (0..n as u64).map(|i| Car::new(&setup, 0, i)).collect(),
            outcomes: vec![Outcome::default(); n],
            images: vec![0; image_bytes],
            last_images: vec![None; n],
            camera: lens.camera(),
            lens,
            kind,
            setup,
        })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.cars.len()
    }

    /// Starts every environment's episode; with `seed`, env i draws from stream i of it (as the actors' batches).
    #[pyo3(signature = (seed=None, spawn=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<u64>,
        spawn: Option<&str>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let spawn = spawn
            .map(parse_spawn)
            .transpose()?
            .unwrap_or(self.setup.spawn);
        for (i, car) in self.cars.iter_mut().enumerate() {
            if let Some(seed) = seed {
                car.reseed(seed, i as u64);
            }
            car.reset(spawn);
        }
        self.render_all();
        self.observations(py)
    }

    /// Steps env i with `actions[i]` ((n, 2), finite; clipped to the box). Returns (observations, rewards,
    /// terminated, truncated, info) with Gymnasium's vector conventions (`info[key]` with its mask `info["_key"]`):
    /// `laps` (this step's episode's), `lap_time` (where a lap ended), and where an episode ended `end_reason`,
    /// `final_obs` (that episode's last observation; the returned one is the next episode's first).
    #[allow(clippy::type_complexity)] // Gymnasium's step tuple
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: &Bound<'py, PyAny>,
    ) -> PyResult<(
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyDict>,
    )> {
        let n = self.cars.len();
        let (actions, _) = rows::<2>(actions, "actions", Some(n), false)?;
        py.detach(|| self.advance(&actions));
        let obs = self.observations(py)?;
        let o = &self.outcomes;
        let rewards = PyArray1::from_iter(py, o.iter().map(|o| o.reward));
        let terminated = PyArray1::from_iter(py, o.iter().map(|o| o.terminated));
        let truncated = PyArray1::from_iter(py, o.iter().map(|o| o.truncated));
        let info = PyDict::new(py);
        info.set_item(
            "laps",
            PyArray1::from_iter(py, o.iter().map(|o| o.laps as i64)),
        )?;
        info.set_item("_laps", PyArray1::from_iter(py, o.iter().map(|_| true)))?;
        let lap_time = o.iter().map(|o| o.lap_time.unwrap_or(f64::NAN));
        info.set_item("lap_time", PyArray1::from_iter(py, lap_time))?;
        let laps_now = o.iter().map(|o| o.lap_time.is_some());
        info.set_item("_lap_time", PyArray1::from_iter(py, laps_now))?;
        if o.iter().any(|o| o.end.is_some()) {
            let ended = PyArray1::from_iter(py, o.iter().map(|o| o.end.is_some()));
            let numpy = py.import("numpy")?;
            let none = py.None();
            let reasons = numpy.call_method1("full", (n, &none, "object"))?;
            let finals = numpy.call_method1("full", (n, &none, "object"))?;
            for (i, o) in self.outcomes.iter().enumerate() {
                if let (Some(end), Some(last)) = (o.end, o.last) {
                    reasons.set_item(i, end.to_string())?;
                    let image = self.last_images[i].take().map(|rgb| (rgb, &self.lens));
                    finals.set_item(i, observation(py, self.kind, &last, image)?)?;
                }
            }
            info.set_item("end_reason", reasons)?;
            info.set_item("_end_reason", ended.clone())?;
            info.set_item("final_obs", finals)?;
            info.set_item("_final_obs", ended)?;
        }
        Ok((
            obs,
            rewards.into_any(),
            terminated.into_any(),
            truncated.into_any(),
            info,
        ))
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

    /// The track's half-width (m).
    #[getter]
    fn half_width(&self) -> f64 {
        self.setup.road.track.half_width()
    }

    /// The bounds of one state observation on this track: (low, high).
    #[getter]
    fn state_bounds(&self) -> ([f64; 6], [f64; 6]) {
        state_bounds(&self.setup.road.track)
    }

    /// The track in words.
    #[getter]
    fn track(&self) -> String {
        self.setup.road.track.describe().to_string()
    }
}

impl VecSim {
    /// Steps every environment, resetting those whose episode ended (no Python objects touched).
    fn advance(&mut self, actions: &[Input]) {
        let camera = self.kind == Kind::Camera;
        let len = self.lens.image_len();
        for (i, (car, a)) in self.cars.iter_mut().zip(actions).enumerate() {
            let t = car.step(a, &self.setup);
            let mut outcome = Outcome {
                reward: t.reward,
                terminated: t.terminated,
                truncated: t.truncated,
                laps: t.laps,
                lap_time: t.lap_time,
                end: t.end,
                last: None,
            };
            if t.end.is_some() {
                outcome.last = Some(car.env.observation());
                if camera {
                    let mut rgb = vec![0; len];
                    see(&mut self.camera, &self.setup.road, &car.env, &mut rgb);
                    self.last_images[i] = Some(rgb);
                }
                car.reset(self.setup.spawn);
            }
            self.outcomes[i] = outcome;
        }
        self.render_all();
    }
}
