//! The actor's camera: renders what the vision policy sees, in the protocol's image type.

use cabc_proto::config::ObservationSection;
use cabc_proto::messages::Image;
use cabc_sim::camera::{Camera, TrackLookup};
use cabc_sim::env::Env;
use cabc_sim::track::Pose;
use std::sync::Arc;

/// Lookup-grid resolution (m) of the renderer's track map.
const LOOKUP_RESOLUTION: f64 = 0.01;

/// A camera and the track map it renders from.
pub struct Eyes {
    camera: Camera,
    lookup: Option<Arc<TrackLookup>>,
}

impl Eyes {
    pub fn new(observation: &ObservationSection) -> Self {
        Eyes {
            camera: Camera::new(
                observation.width as usize,
                observation.height as usize,
                observation.fov_deg,
            ),
            lookup: None,
        }
    }

    /// The first-person image of `env`'s car under `env`'s sun (a new buffer, moved on to the segment).
    pub fn see(&mut self, env: &Env) -> Image {
        let lookup = self
            .lookup
            .get_or_insert_with(|| Arc::new(TrackLookup::new(env.track(), LOOKUP_RESOLUTION)))
            .clone();
        let [x, y, psi] = env.observation().pose;
        self.camera
            .render_owned(&lookup, Pose { x, y, psi }, env.sun())
            .into()
    }
}
