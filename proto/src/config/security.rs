//! `[bus.security]`: who may join a run's bus and how they prove it (zenoh's TLS, user/password and access
//! control; `cabc_bus::security` turns this into zenoh configuration, `deploy/make-certs.sh` makes the files).
//!
//! ```toml
//! [bus.security]
//! mode = "mtls"            # "none" (default: today's loopback bus) | "mtls" | "password"
//! certs = "certs"          # the folder of deploy/make-certs.sh; relative to the configuration file's folder
//! actors = []              # default: actor-0 .. actor-(actors.count - 1), as deploy/run-local.sh names them
//! evaluators = ["eval"]
//! expert_servers = ["0"]
//! observer = true          # the read-only certificate of the zenoh CLI
//! ```
//!
//! Every process is named on the bus by its *component* (`learner`, `actor/<id>`, `eval/<id>`,
//! `expert-server/<id>`, `observer`): the certificate's common name, the user name, the suffix of
//! `alive/<component>`. The learner's router allows each component only its own keys; the lists above are the
//! components it knows (zenoh 1.10 cannot change its access control while running: a new id needs a restart).

use serde::{Deserialize, Serialize};
use std::path::Path;

/// How the processes of a run authenticate on the bus.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SecurityMode {
    /// No authentication, no encryption: for loopback and trusted networks only (the embedded default).
    #[default]
    None,
    /// Mutual TLS: every process presents a certificate of the run's CA whose common name is its component.
    Mtls,
    /// TLS that authenticates the learner only; the others log in with user = component and a password file
    /// (`<certs>/<component>.password`; the learner checks them against `<certs>/passwords`).
    Password,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecuritySection {
    pub mode: SecurityMode,
    /// Folder of the certificates (and password files). A relative path in a configuration *file* is resolved
    /// against that file's folder when it is loaded (the run folder's copy then holds the absolute path); in an
    /// embedded preset, against the working directory.
    pub certs: String,
    /// Actor ids allowed on the bus; empty = actor-0 .. actor-(actors.count - 1), filled in when loaded.
    pub actors: Vec<String>,
    /// Evaluator ids (`actor --eval --id <id>`).
    pub evaluators: Vec<String>,
    /// Expert-server ids (`expert-server serve --id <id>`).
    pub expert_servers: Vec<String>,
    /// Allow the `observer` component to read metrics and liveliness (the zenoh CLI).
    pub observer: bool,
}

impl Default for SecuritySection {
    fn default() -> Self {
        SecuritySection {
            mode: SecurityMode::None,
            certs: "certs".into(),
            actors: Vec::new(),
            evaluators: vec!["eval".into()],
            expert_servers: vec!["0".into()],
            observer: true,
        }
    }
}

impl SecuritySection {
    pub fn enabled(&self) -> bool {
        self.mode != SecurityMode::None
    }

    /// Fills in the defaults that depend on the rest of the configuration (the actor ids) and resolves `certs`
    /// against `base` (the configuration file's folder), so that every process finds the same files.
    pub fn resolve(&mut self, actors_count: u32, evaluators_count: u32, base: Option<&Path>) {
        if !self.enabled() {
            return;
        }
        if self.actors.is_empty() {
            self.actors = (0..actors_count).map(|i| format!("actor-{i}")).collect();
        }
        // Several evaluators are started as eval-0 .. eval-{n-1} (deploy/run-local.sh).
        if evaluators_count > 1 && self.evaluators == ["eval"] {
            self.evaluators = (0..evaluators_count).map(|i| format!("eval-{i}")).collect();
        }
        if let Some(base) = base {
            let certs = Path::new(&self.certs);
            if certs.is_relative() {
                let base = std::fs::canonicalize(base).unwrap_or_else(|_| base.to_path_buf());
                self.certs = base.join(certs).display().to_string();
            }
        }
    }

    /// Checks the section against the bus endpoints: `Err((key, value, why))`.
    pub fn check(
        &self,
        listen: &[String],
        connect: &[String],
    ) -> Result<(), (&'static str, String, &'static str)> {
        if !self.enabled() {
            return Ok(());
        }
        for (key, list) in [("bus.listen", listen), ("bus.connect", connect)] {
            if let Some(e) = list.iter().find(|e| !e.starts_with("tls/")) {
                return Err((
                    key,
                    e.clone(),
                    "bus.security needs tls/ endpoints (no tcp/ or other plain links)",
                ));
            }
        }
        if self.certs.is_empty() {
            return Err(("bus.security.certs", "\"\"".into(), "must name a folder"));
        }
        for (key, ids) in [
            ("bus.security.actors", &self.actors),
            ("bus.security.evaluators", &self.evaluators),
            ("bus.security.expert_servers", &self.expert_servers),
        ] {
            if let Some(id) = ids.iter().find(|id| crate::keys::check_chunk(id).is_err()) {
                return Err((key, id.clone(), "ids use letters, digits, '-', '_' or '.'"));
            }
            let mut sorted = ids.clone();
            sorted.sort();
            if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
                return Err((key, w[0].clone(), "ids must be distinct"));
            }
        }
        Ok(())
    }
}
