//! What the types of the run configuration cannot check.

use super::SimSection;
use super::{ConfigError, ObservationKind, RunConfig, Velocity, REPLAY_STEP_BYTES};

impl RunConfig {
    /// Checks values that types cannot.
    pub fn validate(&self, origin: &str) -> Result<(), ConfigError> {
        let invalid = |key: &'static str, value: String, why: &'static str| {
            Err(ConfigError::Invalid {
                origin: origin.to_string(),
                key,
                value,
                why,
            })
        };
        if crate::keys::check_chunk(&self.run.name).is_err() {
            return invalid(
                "run.name",
                self.run.name.clone(),
                "use letters, digits, '-', '_' or '.'",
            );
        }
        for (key, value) in [
            ("bus.epoch_timeout_s", self.bus.epoch_timeout_s),
            ("bus.no_actor_timeout_s", self.bus.no_actor_timeout_s),
            ("supervision.window_s", self.supervision.window_s),
            ("supervision.backoff_s", self.supervision.backoff_s),
            ("supervision.backoff_max_s", self.supervision.backoff_max_s),
        ] {
            if !(value > 0.0 && value.is_finite()) {
                return invalid(
                    key,
                    value.to_string(),
                    "must be a positive number of seconds",
                );
            }
        }
        if !(self.bus.segment_batch_ms >= 0.0 && self.bus.segment_batch_ms <= 10_000.0) {
            return invalid(
                "bus.segment_batch_ms",
                self.bus.segment_batch_ms.to_string(),
                "must be between 0 (no batching) and 10000 milliseconds",
            );
        }
        for (key, value) in [
            ("expert.mpcc_tol_gap", self.expert.mpcc_tol_gap),
            ("expert.mpcc_tol_feas", self.expert.mpcc_tol_feas),
        ] {
            if !(1e-10..=0.1).contains(&value) {
                return invalid(
                    key,
                    value.to_string(),
                    "must be between 1e-10 and 0.1 (the reference's: 1e-5 and 1e-6)",
                );
            }
        }
        if !(1..=65_536).contains(&self.bus.segment_batch_kib) {
            return invalid(
                "bus.segment_batch_kib",
                self.bus.segment_batch_kib.to_string(),
                "must be between 1 and 65536 KiB (64 MiB)",
            );
        }
        if !self.sim.track_is_file() && !SimSection::NAMES.contains(&self.sim.track.as_str()) {
            return invalid(
                "sim.track",
                self.sim.track.clone(),
                "name a track (l-track-barc, oval, chicane, long) or a file (.csv: an F1TENTH centre line; .toml: pieces)",
            );
        }
        if !(self.sim.track_scale > 0.0 && self.sim.track_scale.is_finite()) {
            return invalid(
                "sim.track_scale",
                self.sim.track_scale.to_string(),
                "must be a positive number",
            );
        }
        if let Some(h) = self
            .sim
            .track_half_width
            .filter(|h| !(*h > 0.0 && h.is_finite()))
        {
            return invalid(
                "sim.track_half_width",
                h.to_string(),
                "must be a positive number of metres",
            );
        }
        for track in &self.sim.actor_tracks {
            if !SimSection::is_file(track) && !SimSection::NAMES.contains(&track.as_str()) {
                return invalid(
                    "sim.actor_tracks",
                    track.clone(),
                    "name a track (l-track-barc, oval, chicane, long) or a file (.csv, .toml)",
                );
            }
        }
        if !self.sim.actor_tracks.is_empty()
            && self.expert.placement != super::ExpertPlacement::InActor
        {
            return invalid(
                "sim.actor_tracks",
                format!("{:?}", self.sim.actor_tracks),
                "needs expert.placement = \"in-actor\": an expert server answers on one track",
            );
        }
        if !(self.observation.preview_m > 0.0 && self.observation.preview_m.is_finite()) {
            return invalid(
                "observation.preview_m",
                self.observation.preview_m.to_string(),
                "must be a positive number of metres",
            );
        }
        if !(self.algorithm.lambda >= 0.0 && self.algorithm.lambda.is_finite()) {
            return invalid(
                "algorithm.lambda",
                self.algorithm.lambda.to_string(),
                "must be >= 0",
            );
        }
        if !(self.algorithm.rho > 0.0 && self.algorithm.rho.is_finite()) {
            return invalid(
                "algorithm.rho",
                self.algorithm.rho.to_string(),
                "must be > 0",
            );
        }
        if let Some(start) = self.algorithm.lambda_start {
            if !(start >= 0.0 && start.is_finite()) {
                return invalid("algorithm.lambda_start", start.to_string(), "must be >= 0");
            }
        }
        if !(self.algorithm.lambda_growth >= 1.0 && self.algorithm.lambda_growth.is_finite()) {
            return invalid(
                "algorithm.lambda_growth",
                self.algorithm.lambda_growth.to_string(),
                "must be >= 1 (a warm-up grows towards algorithm.lambda)",
            );
        }
        if !(0.0..1.0).contains(&self.training.policy_ema) {
            return invalid(
                "training.policy_ema",
                self.training.policy_ema.to_string(),
                "must lie in [0, 1): the share of the old average kept each epoch (0: no average)",
            );
        }
        if !(0.0..1.0).contains(&self.collection.shield) {
            return invalid(
                "collection.shield",
                self.collection.shield.to_string(),
                "must lie in [0, 1): the probability of safety below which the expert drives (0: no shield)",
            );
        }
        if self.collection.shield > 0.0 && self.training.standardise {
            return invalid(
                "collection.shield",
                self.collection.shield.to_string(),
                "needs training.standardise = false: the actors feed f_hat and p_hat raw states",
            );
        }
        if !(0.0..=1.0).contains(&self.training.safety_gate) {
            return invalid(
                "training.safety_gate",
                self.training.safety_gate.to_string(),
                "must lie in [0, 1]: a balanced accuracy (0: no gate)",
            );
        }
        if !(self.training.lr_min >= 0.0 && self.training.lr_min.is_finite()) {
            return invalid(
                "training.lr_min",
                self.training.lr_min.to_string(),
                "must be >= 0",
            );
        }
        if !(0.0..=1.0).contains(&self.algorithm.beta_decay) {
            return invalid(
                "algorithm.beta_decay",
                self.algorithm.beta_decay.to_string(),
                "must lie in [0, 1]",
            );
        }
        if !(0.0..=1.0).contains(&self.algorithm.negative_label) {
            return invalid(
                "algorithm.negative_label",
                self.algorithm.negative_label.to_string(),
                "must lie in [0, 1]",
            );
        }
        // Counts and periods that must be at least 1.
        let counts: [(&'static str, u64); 9] = [
            ("algorithm.autolabel_every", self.algorithm.autolabel_every),
            (
                "collection.steps_per_epoch",
                self.collection.steps_per_epoch,
            ),
            ("actors.count", self.actors.count.into()),
            ("actors.auto_max", self.actors.auto_max.into()),
            ("actors.evaluators", self.actors.evaluators.into()),
            ("actors.envs_per_actor", self.actors.envs_per_actor.into()),
            ("training.batch_size", self.training.batch_size as u64),
            (
                "training.dynamics_every / critic_every",
                self.training.dynamics_every.min(self.training.critic_every),
            ),
            ("replay.capacity", self.replay.capacity as u64),
        ];
        if let Some(&(key, _)) = counts.iter().find(|(_, n)| *n == 0) {
            return invalid(key, "0".into(), "must be >= 1");
        }
        if self.replay.max_bytes > 0 && self.plus_capacity() < self.training.batch_size {
            let per_step = REPLAY_STEP_BYTES + self.image_bytes();
            let need = self.replay_reserve() + per_step * self.training.batch_size as u64;
            return invalid(
                "replay.max_bytes",
                format!("{} (at least {need} needed)", self.replay.max_bytes),
                "too small for one batch of D+ besides D?, D- and the dynamics-only store at replay.capacity",
            );
        }
        if self.observation.kind == ObservationKind::Camera
            && (self.observation.width < 16 || self.observation.height < 16)
        {
            return invalid(
                "observation.width/height",
                format!("{}x{}", self.observation.width, self.observation.height),
                "images must be at least 16x16",
            );
        }
        let seen = &self.observation.velocity_inputs;
        let all = seen.len() == Velocity::ALL.len();
        if seen.windows(2).any(|w| w[0] >= w[1])
            || (self.observation.kind == ObservationKind::State && !all)
        {
            return invalid(
                "observation.velocity_inputs",
                format!("{:?}", seen.iter().map(|v| v.as_str()).collect::<Vec<_>>()),
                "names each of v_long, v_tran, omega at most once, in that order; a full-state policy sees all three",
            );
        }
        let noise = &self.observation;
        if !deviations(noise.state_noise_std.iter().chain([&noise.pixel_noise_std])) {
            return invalid(
                "observation.state_noise_std / pixel_noise_std",
                format!("{:?} / {}", noise.state_noise_std, noise.pixel_noise_std),
                "standard deviations must be finite and >= 0",
            );
        }
        let action_noise = self.collection.action_noise_std;
        if !deviations(&action_noise) {
            return invalid(
                "collection.action_noise_std",
                format!("{action_noise:?}"),
                "standard deviations must be finite and >= 0",
            );
        }
        let early_stop = &self.collection;
        if !deviations(
            early_stop
                .early_stop_action_noise_std
                .iter()
                .chain(&early_stop.early_stop_state_noise_std),
        ) {
            return invalid(
                "collection.early_stop_action_noise_std / early_stop_state_noise_std",
                format!(
                    "{:?} / {:?}",
                    early_stop.early_stop_action_noise_std, early_stop.early_stop_state_noise_std
                ),
                "standard deviations must be finite and >= 0",
            );
        }
        // An empty `bus.listen` makes the learner a client of the routers in `bus.connect` (a standalone zenohd,
        // deploy/SCALE-OUT.md §2); the others always need somewhere to connect to.
        if self.bus.connect.is_empty() {
            return invalid("bus.connect", "[]".into(), "need at least one endpoint");
        }
        let (listen, connect) = (&self.bus.listen, &self.bus.connect);
        if let Err((key, value, why)) = self.bus.security.check(listen, connect) {
            return invalid(key, value, why);
        }
        Ok(())
    }
}

/// Whether every value is a standard deviation: finite and >= 0.
fn deviations<'a>(values: impl IntoIterator<Item = &'a f64>) -> bool {
    values.into_iter().all(|s| s.is_finite() && *s >= 0.0)
}
