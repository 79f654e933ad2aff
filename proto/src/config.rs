//! The run configuration: one TOML file describes a run, and it is the one place for every number that defines
//! an experiment. Defaults are the reference values of algorithm.md; the presets for the paper's experiments
//! (V-A, V-B, V-C) and a tiny `smoke` run live in `deploy/configs/` and are embedded here too, so that the binaries
//! can be started with `--config v-b` without a file.
//!
//! Unknown keys are refused (`deny_unknown_fields`), and every error names the key and its line.

use crate::messages::image_bytes;
use serde::{Deserialize, Serialize};
use std::path::Path;

mod actors;
mod choices;
mod overrides;
mod security;
mod validate;
pub use actors::ActorCount;
pub use choices::{
    ClipScope, CriticNegatives, Episodes, ExpertFailureStaged, ExpertKind, ExpertPlacement, Flush,
    ObservationKind, Precision, SafetyStates, SafetyTerm, ScheduleKind, Spawn, StoredAction,
    TrackFeature, Velocity, VisionTrunk,
};
pub use security::{SecurityMode, SecuritySection};

mod deployment;
mod sections;
pub use deployment::*;
pub use sections::*;

/// One run, as written in a TOML file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    pub run: RunSection,
    pub sim: SimSection,
    pub expert: ExpertSection,
    pub observation: ObservationSection,
    pub algorithm: AlgorithmSection,
    pub collection: CollectionSection,
    pub replay: ReplaySection,
    pub networks: NetworksSection,
    pub training: TrainingSection,
    pub actors: ActorsSection,
    pub bus: BusSection,
    pub supervision: SupervisionSection,
}

/// A configuration that could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// toml's message names the key, the line and the column.
    #[error("{origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("{origin}: {key} = {value}: {why}")]
    Invalid {
        origin: String,
        key: &'static str,
        value: String,
        why: &'static str,
    },
    #[error("no preset named `{0}`; presets: {presets}", presets = PRESETS.iter().map(|p| p.0).collect::<Vec<_>>().join(", "))]
    UnknownPreset(String),
    #[error("--set {setting}: {why}")]
    Override { setting: String, why: String },
}

/// The preset the binaries and `deploy/run-local.sh` use when none is named (issue 59): V-B's recipe (`v-b-recipe`,
/// issue 30: the reference's protocol with DAgger's aggregate, lambda's warm-up and D- as the critic's negatives)
/// with the safety term as the paper writes it (issue 45: frozen f_hat and p_hat, eq. (14)'s rows, the hinged term),
/// which reached the early stop on every seed of the campaign in about half the recipe's epochs
/// (docs/REPRODUCTION.md); `v-b-ref` is the reference's protocol alone.
pub const DEFAULT_PRESET: &str = "v-b";

/// The presets of deploy/configs/, embedded.
pub const PRESETS: &[(&str, &str)] = &[
    ("v-a", include_str!("../../deploy/configs/v-a.toml")),
    ("v-b", include_str!("../../deploy/configs/v-b.toml")),
    ("v-c", include_str!("../../deploy/configs/v-c.toml")),
    ("smoke", include_str!("../../deploy/configs/smoke.toml")),
    ("v-a-cpu", include_str!("../../deploy/configs/v-a-cpu.toml")),
    ("v-c-cpu", include_str!("../../deploy/configs/v-c-cpu.toml")),
    (
        "smoke-camera",
        include_str!("../../deploy/configs/smoke-camera.toml"),
    ),
    ("v-a-ref", include_str!("../../deploy/configs/v-a-ref.toml")),
    ("v-b-ref", include_str!("../../deploy/configs/v-b-ref.toml")),
    (
        "v-b-recipe",
        include_str!("../../deploy/configs/v-b-recipe.toml"),
    ),
    ("v-c-ref", include_str!("../../deploy/configs/v-c-ref.toml")),
    ("v-c-224", include_str!("../../deploy/configs/v-c-224.toml")),
    (
        "v-b-term",
        include_str!("../../deploy/configs/v-b-term.toml"),
    ),
];

impl RunConfig {
    /// Parses TOML; `origin` names the source in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let mut config: RunConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: origin.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        // `actors.count = "auto"` was resolved without `collection.overlap`, which keeps a core for the learner.
        if config.collection.overlap && actors_count_is_auto(text) {
            let a = &mut config.actors;
            a.count = ActorsSection::auto_count(ActorsSection::machine_cores(), a.auto_max, true);
        }
        let (actors, evaluators) = (config.actors.count, config.actors.evaluators);
        config.bus.security.resolve(actors, evaluators, None);
        config.validate(origin)?;
        Ok(config)
    }

    /// A preset name ([`PRESETS`]: `v-a`, `v-b`, `v-c`, `smoke`, `v-a-cpu`, `v-c-cpu`, `smoke-camera`, and the
    /// reference protocol's `v-a-ref`, `v-b-ref`, `v-c-ref`, and `v-c-224` on a GPU) or a path to a TOML file.
    pub fn load(name_or_path: &str) -> Result<Self, ConfigError> {
        if let Some((name, text)) = PRESETS.iter().find(|(n, _)| *n == name_or_path) {
            return Self::from_toml(text, &format!("preset {name}"));
        }
        let path = Path::new(name_or_path);
        if !path.exists() && !name_or_path.contains(['/', '.']) {
            return Err(ConfigError::UnknownPreset(name_or_path.to_string()));
        }
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let mut config = Self::from_toml(&text, &path.display().to_string())?;
        let folder = path.parent().filter(|p| !p.as_os_str().is_empty());
        config.sim.resolve(folder.unwrap_or(Path::new(".")));
        let security = &mut config.bus.security;
        let (actors, evaluators) = (config.actors.count, config.actors.evaluators);
        security.resolve(actors, evaluators, Some(folder.unwrap_or(Path::new("."))));
        Ok(config)
    }

    /// [`RunConfig::load`], or with `baseline` the behaviour-cloning baseline of the same run: lambda = 0, under the
    /// run name suffixed with `-baseline`.
    pub fn load_variant(name_or_path: &str, baseline: bool) -> Result<Self, ConfigError> {
        let mut config = Self::load(name_or_path)?;
        if baseline {
            config.make_baseline();
        }
        Ok(config)
    }

    /// Turns this run into its baseline: lambda = `algorithm.baseline_lambda` (0: plain behaviour cloning), rho =
    /// `algorithm.baseline_rho` when given, under the run name suffixed with `-baseline` (unless it ends so already,
    /// as `--set run.name=...-baseline` gives it). A run that already is its
    /// own baseline is left as it is.
    pub fn make_baseline(&mut self) {
        let a = &mut self.algorithm;
        let rho = a.baseline_rho.unwrap_or(a.rho);
        if a.lambda == a.baseline_lambda && a.rho == rho {
            return;
        }
        (a.lambda, a.rho) = (a.baseline_lambda, rho);
        if !self.run.name.ends_with("-baseline") {
            self.run.name = format!("{}-baseline", self.run.name);
        }
    }

    /// One value of the configuration by its dotted key (e.g. `actors.count`), as text.
    pub fn show(&self, key: &str) -> Option<String> {
        let value: toml::Value = toml::from_str(&self.to_toml()).ok()?;
        match key.split('.').try_fold(&value, |v, k| v.get(k))? {
            toml::Value::String(s) => Some(s.clone()),
            other => Some(other.to_string()),
        }
    }

    /// Writes the configuration as TOML (for the run folder).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a RunConfig always serialises")
    }

    /// Bytes of one image of the run (0 for a full-state run).
    pub fn image_bytes(&self) -> u64 {
        match self.observation.kind {
            ObservationKind::State => 0,
            ObservationKind::Camera => image_bytes(
                self.observation.width.into(),
                self.observation.height.into(),
            ) as u64,
        }
    }

    /// Whether D? keeps its steps' images: a camera policy that clones D? too (`training.clone_uncertain`) reads
    /// them; otherwise only D+'s images are read.
    pub fn uncertain_images(&self) -> bool {
        self.training.clone_uncertain && self.observation.kind == ObservationKind::Camera
    }

    /// What the replay sets aside for D? (with its images when [`RunConfig::uncertain_images`]), the
    /// dynamics-only store (steps without images) and D- (states), at full capacity.
    fn replay_reserve(&self) -> u64 {
        let capacity = self.replay.capacity as u64;
        let uncertain_images = if self.uncertain_images() {
            capacity * self.image_bytes()
        } else {
            0
        };
        2 * capacity * REPLAY_STEP_BYTES + capacity * 6 * 4 + uncertain_images
    }

    /// D+'s capacity in steps: `replay.capacity`, or fewer when `replay.max_bytes` cannot hold that many steps
    /// with their images besides the other stores.
    pub fn plus_capacity(&self) -> usize {
        let capacity = self.replay.capacity;
        if self.replay.max_bytes == 0 {
            return capacity;
        }
        let per_step = REPLAY_STEP_BYTES + self.image_bytes();
        let room = self.replay.max_bytes.saturating_sub(self.replay_reserve()) / per_step;
        capacity.min(room as usize)
    }

    /// beta_j of Algorithm 1.
    pub fn beta(&self, epoch: u64) -> f64 {
        self.algorithm
            .beta_decay
            .powi(epoch.min(i32::MAX as u64) as i32)
    }

    /// lambda_j, the weight of L_safety in epoch j (eq. (14)): `algorithm.lambda`, or its warm-up from
    /// `lambda_start`, growing by `lambda_growth` an epoch up to `lambda`.
    pub fn lambda(&self, epoch: u64) -> f64 {
        let a = &self.algorithm;
        match a.lambda_start {
            None => a.lambda,
            Some(start) => {
                let j = epoch.min(i32::MAX as u64) as i32;
                (start * a.lambda_growth.powi(j)).min(a.lambda)
            }
        }
    }

    /// Environment steps of epoch `epoch`, all actors together.
    pub fn epoch_steps(&self, epoch: u64) -> u64 {
        if epoch == 0 {
            self.collection.initial_steps
        } else {
            self.collection.steps_per_epoch
        }
    }

    /// The configuration actor `index` collects under: its own track under `sim.actor_tracks`, else this one.
    pub fn for_actor(&self, index: u64) -> RunConfig {
        let mut config = self.clone();
        let tracks = &self.sim.actor_tracks;
        if !tracks.is_empty() {
            config.sim.track = tracks[(index % tracks.len() as u64) as usize].clone();
        }
        config
    }

    /// Each actor's share of an epoch's steps (rounded up, so the epoch collects at least its budget).
    pub fn steps_per_actor(&self, epoch: u64) -> u64 {
        self.epoch_steps(epoch).div_ceil(self.actors.count as u64)
    }
}

/// Whether a configuration's text (one that parsed) writes `actors.count = "auto"`.
fn actors_count_is_auto(text: &str) -> bool {
    let table: toml::Table = toml::from_str(text).unwrap_or_default();
    table
        .get("actors")
        .and_then(|a| a.get("count"))
        .is_some_and(|c| c.as_str() == Some("auto"))
}

#[cfg(test)]
mod tests;
