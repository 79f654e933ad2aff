//! The actor's camera: renders what the vision policy sees, in the protocol's image type.

use cabc_proto::config::{RunConfig, SimSection};
use cabc_proto::messages::Image;
use cabc_sim::camera::{Camera, TrackLookup};
use cabc_sim::env::Env;
use cabc_sim::track::{Pose, Track, TrackError};
use std::sync::{Arc, Mutex, OnceLock};

/// Lookup-grid resolution (m) of the renderer's track map.
const LOOKUP_RESOLUTION: f64 = 0.01;

/// A camera and the track map it renders from.
pub struct Eyes {
    camera: Camera,
    lookup: Arc<TrackLookup>,
}

impl Eyes {
    /// The camera of `config.observation` on the track of `config.sim.track`.
    pub fn new(config: &RunConfig) -> Result<Self, TrackError> {
        let observation = &config.observation;
        Ok(Eyes {
            camera: Camera::new(
                observation.width as usize,
                observation.height as usize,
                observation.fov_deg,
            ),
            lookup: lookup(&config.sim)?,
        })
    }

    /// The first-person image of `env`'s car under `env`'s sun (a new buffer, moved on to the segment).
    pub fn see(&mut self, env: &Env) -> Image {
        let [x, y, psi] = env.observation().pose;
        self.camera
            .render_owned(&self.lookup, Pose { x, y, psi }, env.sun())
            .into()
    }
}

/// The track map of the run's track, built once a process and shared: an evaluation's camera no longer builds its
/// own (0.1-0.2 s of every epoch's evaluation in a camera run).
fn lookup(sim: &SimSection) -> Result<Arc<TrackLookup>, TrackError> {
    type Built = Mutex<Vec<(SimSection, Arc<TrackLookup>)>>;
    static BUILT: OnceLock<Built> = OnceLock::new();
    let mut built = BUILT
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((_, lookup)) = built.iter().find(|(k, _)| k == sim) {
        return Ok(lookup.clone());
    }
    let lookup = Arc::new(TrackLookup::new(
        Track::of(sim)?.as_ref(),
        LOOKUP_RESOLUTION,
    ));
    built.push((sim.clone(), lookup.clone()));
    Ok(lookup)
}
