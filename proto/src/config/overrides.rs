//! `--set KEY=VALUE`: a configuration with single values changed, checked as a file would be.

use super::{ConfigError, RunConfig};

impl RunConfig {
    /// The configuration with `key=value` settings applied (`run.seed=3`, `run.name=v-a-s3`,
    /// `observation.state_noise_std=[0.01,0,0,0,0,0]`): each key must exist, each value is TOML (a bare word is
    /// taken as a string), and the result is validated as a file would be.
    pub fn with_overrides(self, settings: &[String]) -> Result<Self, ConfigError> {
        if settings.is_empty() {
            return Ok(self);
        }
        let mut value: toml::Value =
            toml::from_str(&self.to_toml()).expect("a RunConfig's TOML parses");
        for setting in settings {
            let fail = |why: &str| ConfigError::Override {
                setting: setting.clone(),
                why: why.to_string(),
            };
            let (key, text) = setting
                .split_once('=')
                .ok_or_else(|| fail("expected key=value"))?;
            let parsed = toml::from_str::<toml::Table>(&format!("v = {text}"))
                .ok()
                .and_then(|mut t| t.remove("v"))
                .unwrap_or_else(|| toml::Value::String(text.to_string()));
            let (path, last) = match key.trim().rsplit_once('.') {
                Some((path, last)) => (path.split('.').collect::<Vec<_>>(), last),
                None => (Vec::new(), key.trim()),
            };
            let mut table = &mut value;
            for part in path {
                table = table
                    .get_mut(part)
                    .ok_or_else(|| fail(&format!("no section {part}")))?;
            }
            let table = table.as_table_mut().ok_or_else(|| fail("not a section"))?;
            match table.get_mut(last) {
                Some(slot) => *slot = parsed,
                // An optional key left out (e.g. algorithm.baseline_rho): parsing below refuses an unknown one.
                None => {
                    table.insert(last.to_string(), parsed);
                }
            }
        }
        let text = toml::to_string(&value).expect("a TOML value serialises");
        let origin = format!("--set {}", settings.join(" --set "));
        Self::from_toml(&text, &origin).map_err(|e| match e {
            // A value of the wrong type: toml's message names the key; the line is of the generated text.
            ConfigError::Parse { message, .. } => ConfigError::Override {
                setting: settings.join(" --set "),
                why: message.lines().last().unwrap_or_default().to_string(),
            },
            other => other,
        })
    }
}
