//! Which processes a supervisor runs, from the run configuration and the command line: the learner (`learner run`),
//! the expert server (`expert-server serve`, none under `expert.placement = "in-actor"`), the collecting actors and
//! the evaluators (`actor`, `actor --eval`), each with its log under `<run>/logs/`; and, when asked for
//! (`--roles router,...`), a standalone router (`zenohd`, deploy/SCALE-OUT.md §2) that every other process dials.

use cabc_proto::config::{ExpertPlacement, RunConfig};
use cabc_runfolder::Status;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A process's role in the run: what its restarts are counted under.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    /// A standalone zenoh router (`zenohd`) on the run's `bus.connect` endpoints: not one of [`Role::ALL`], it runs
    /// where `--roles` names it.
    Router,
    Learner,
    Expert,
    Actor,
    Evaluator,
}

impl Role {
    /// The roles of every run (the default of `--roles`).
    pub const ALL: [Role; 4] = [Role::Learner, Role::Expert, Role::Actor, Role::Evaluator];

    /// The name in `supervision.json`, `metrics.csv` (`restarts_<role>`) and `--roles`.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Router => "router",
            Role::Learner => "learner",
            Role::Expert => "expert",
            Role::Actor => "actor",
            Role::Evaluator => "evaluator",
        }
    }
}

/// When a role's process is started again, OTP's restart kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Restart {
    /// Whenever it ends, exit 0 too (the router: the run needs it as long as it goes on).
    Permanent,
    /// When it fails (a signal, an exit status but 0); exit 0 means it is done (an actor after the learner's stop).
    Transient,
}

/// What the supervisor does with a role's processes, as data (OTP's child specification): when it restarts one,
/// which of its exits end the whole run, and how long it has to stop. The supervisor starts the roles in the order
/// of [`Roster::specs`] and stops them in the reverse order, each with its `shutdown`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChildSpec {
    pub restart: Restart,
    /// Its exit 0 ends the run (OTP's significant child): the learner's, at early stop or its budget.
    pub significant: bool,
    /// An exit status that ends the run with an error instead of a restart: the learner's `exit::NO_ACTORS` (it
    /// waited `bus.no_actor_timeout_s` with no live actor; restarted, it would only wait again).
    pub gives_up: Option<i32>,
    /// How long it has after SIGINT before SIGTERM, and then before SIGKILL.
    pub shutdown: Duration,
}

impl Role {
    /// The role's [`ChildSpec`].
    pub fn child_spec(self) -> ChildSpec {
        let transient = ChildSpec {
            restart: Restart::Transient,
            significant: false,
            gives_up: None,
            shutdown: Duration::from_secs(5),
        };
        match self {
            Role::Router => ChildSpec {
                restart: Restart::Permanent,
                ..transient
            },
            // The learner stops last but the router: the others' last words reach it. It may be writing its
            // checkpoint when asked to stop, so it has longer.
            Role::Learner => ChildSpec {
                significant: true,
                gives_up: Some(cabc_runfolder::exit::NO_ACTORS),
                shutdown: Duration::from_secs(15),
                ..transient
            },
            Role::Expert | Role::Actor | Role::Evaluator => transient,
        }
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Role {
    type Err = String;

    /// `router`, `learner`, `expert`, `actor` or `evaluator` (plurals too: `actors`, `evaluators`).
    fn from_str(s: &str) -> Result<Self, String> {
        let singular = s.strip_suffix('s').unwrap_or(s);
        std::iter::once(Role::Router)
            .chain(Role::ALL)
            .find(|r| r.as_str() == singular)
            .ok_or_else(|| {
                format!("a role is router, learner, expert, actor or evaluator, not `{s}`")
            })
    }
}

/// One supervised process.
#[derive(Clone, Debug, PartialEq)]
pub struct Spec {
    /// Its name: `learner`, `expert-server-0`, `actor-3`, `eval` (also its log's name).
    pub name: String,
    pub role: Role,
    pub program: PathBuf,
    pub args: Vec<String>,
    /// Where its stderr goes (appended to across restarts).
    pub log: PathBuf,
}

impl Spec {
    /// The arguments of a restart: the learner's with `--resume` (and without `--fresh`) once the run folder holds a
    /// checkpoint; any other process's as at its start.
    pub fn restart_args(&self, run_dir: &Path) -> Vec<String> {
        if self.role != Role::Learner || !has_checkpoint(run_dir) {
            return self.args.clone();
        }
        let mut args: Vec<String> = self
            .args
            .iter()
            .filter(|a| *a != "--fresh" && *a != "--resume")
            .cloned()
            .collect();
        args.push("--resume".into());
        args
    }
}

pub use cabc_runfolder::has_checkpoint;

/// What a supervisor runs.
#[derive(Clone, Debug)]
pub struct Roster {
    /// The folder of the binaries (`learner`, `actor`, `expert-server`).
    pub bin: PathBuf,
    /// The run configuration's file, as the processes take it (`--config`).
    pub config_file: PathBuf,
    pub run_dir: PathBuf,
    /// The roles to run here (all four on one machine; `actor`, `evaluator` on a machine that adds actors).
    pub roles: Vec<Role>,
    /// How many collecting actors (default: `actors.count`), named `actor-<first_actor>` on.
    pub actors: Option<u32>,
    pub first_actor: u32,
    /// `--connect` for every process but the learner (default: the configuration's `bus.connect`).
    pub connect: Vec<String>,
    /// The learner's own arguments (`--resume`, `--fresh`, ...).
    pub learner_args: Vec<String>,
    /// This machine's name where several machines share the run folder (a cluster's shared filesystem): a
    /// supervisor that runs no learner then keeps its record in `supervision-<node>.json` ([`Roster::record`]).
    pub node: Option<String>,
    /// A secured run's router configuration: zenohd's JSON5 with the run's TLS and access control, made by the
    /// caller from the run configuration (`cabc_bus::zenohd::config`, as `cabc zenohd-config`); None on a plain bus,
    /// whose router is [`router_config`].
    pub router_config: Option<String>,
}

impl Roster {
    /// Where this supervisor keeps its record: `supervision.json` (the file the learner reads, so the learner's
    /// machine always writes it), or `supervision-<node>.json` for another machine of a shared run folder.
    pub fn record(&self) -> PathBuf {
        match &self.node {
            Some(node) if !self.roles.contains(&Role::Learner) => {
                self.run_dir.join(format!("supervision-{node}.json"))
            }
            _ => Status::path(&self.run_dir),
        }
    }

    /// The processes, in the order they start: the router, the learner, the expert server, the actors, the evaluators.
    pub fn specs(&self, config: &RunConfig) -> Vec<Spec> {
        let logs = self.run_dir.join("logs");
        let config_file = self.config_file.display().to_string();
        let connect: Vec<String> = self
            .connect
            .iter()
            .flat_map(|c| ["--connect".to_string(), c.clone()])
            .collect();
        let spec = |name: String, role: Role, program: &str, args: Vec<String>| Spec {
            log: logs.join(format!("{name}.log")),
            name,
            role,
            program: self.bin.join(program),
            args,
        };
        let runs = |role| self.roles.contains(&role);
        let mut specs = Vec::new();
        if runs(Role::Router) {
            let file = self.run_dir.join(ROUTER_CONFIG).display().to_string();
            specs.push(spec(
                "router".into(),
                Role::Router,
                "zenohd",
                vec!["-c".into(), file],
            ));
        }
        if runs(Role::Learner) {
            let mut args = vec![
                "run".to_string(),
                "--config".into(),
                config_file.clone(),
                "--run-dir".into(),
                self.run_dir.display().to_string(),
            ];
            args.extend(self.learner_args.iter().cloned());
            specs.push(spec("learner".into(), Role::Learner, "learner", args));
        }
        if runs(Role::Expert) && config.expert.placement == ExpertPlacement::Server {
            let mut args = vec![
                "--config".to_string(),
                config_file.clone(),
                "serve".into(),
                "--id".into(),
                "0".into(),
            ];
            args.extend(connect.iter().cloned());
            specs.push(spec(
                "expert-server-0".into(),
                Role::Expert,
                "expert-server",
                args,
            ));
        }
        if runs(Role::Actor) {
            let count = self.actors.unwrap_or(config.actors.count);
            for i in self.first_actor..self.first_actor + count {
                let id = format!("actor-{i}");
                // Each actor journals what it publishes into the run folder (`cabc audit`).
                let journal = self.run_dir.join(cabc_runfolder::journal::JOURNAL);
                let mut args = vec![
                    "--config".to_string(),
                    config_file.clone(),
                    "--id".into(),
                    id.clone(),
                    "--journal".into(),
                    journal.display().to_string(),
                ];
                args.extend(connect.iter().cloned());
                specs.push(spec(id, Role::Actor, "actor", args));
            }
        }
        if runs(Role::Evaluator) {
            let n = config.actors.evaluators;
            for i in 0..n {
                // One evaluator is `eval`; several are eval-0 .. eval-<n-1> (evaluator i takes v mod n = i).
                let id = if n == 1 {
                    "eval".to_string()
                } else {
                    format!("eval-{i}")
                };
                let mut args = vec![
                    "--config".to_string(),
                    config_file.clone(),
                    "--id".into(),
                    id.clone(),
                    "--eval".into(),
                ];
                args.extend(connect.iter().cloned());
                specs.push(spec(id, Role::Evaluator, "actor", args));
            }
        }
        specs
    }
}

/// The supervised router's configuration file, in the run folder ([`router_config`]).
pub const ROUTER_CONFIG: &str = "router.json5";

/// The endpoints a supervised router listens on: the run's `bus.connect`, which every other process dials; the
/// learner then dials them too, so `bus.listen` must be empty. On a secured bus the router needs the run's access
/// control, `secured_config` (deploy/SCALE-OUT.md §2's zenohd configuration, which `cabc supervise` makes).
pub fn router_endpoints(
    config: &RunConfig,
    connect: &[String],
    secured_config: bool,
) -> Result<Vec<String>, String> {
    use cabc_proto::config::SecurityMode;
    if !config.bus.listen.is_empty() {
        return Err(format!(
            "a supervised router listens for the run, so the learner must not: bus.listen is {:?} (--set \
             'bus.listen=[]'; deploy/run-local.sh --router does)",
            config.bus.listen
        ));
    }
    if config.bus.security.mode != SecurityMode::None && !secured_config {
        return Err(
            "a secured run's supervised router needs zenohd's configuration with the run's access control \
             (cabc supervise makes it from the run configuration: cabc_bus::zenohd::config)"
                .into(),
        );
    }
    let endpoints = if connect.is_empty() {
        config.bus.connect.clone()
    } else {
        connect.to_vec()
    };
    if endpoints.is_empty() {
        return Err("a supervised router listens on bus.connect, which is empty".into());
    }
    Ok(endpoints)
}

/// A standalone router's configuration (zenohd's JSON5) listening on `endpoints`, without multicast scouting (the
/// run's processes dial it).
pub fn router_config(endpoints: &[String]) -> String {
    let quoted: Vec<String> = endpoints.iter().map(|e| format!("{e:?}")).collect();
    format!(
        "{{ mode: \"router\", listen: {{ endpoints: [{}] }}, scouting: {{ multicast: {{ enabled: false }} }} }}\n",
        quoted.join(", ")
    )
}

/// The (host, port) of each TCP or TLS endpoint of `bus.listen` (`tcp/HOST:PORT`, `tls/[V6]:PORT#iface=..`), with
/// the unspecified addresses as loopback: where the learner's bus accepts connections once it is up.
pub fn listen_addresses(listen: &[String]) -> Vec<(String, u16)> {
    listen
        .iter()
        .filter_map(|endpoint| {
            let address = endpoint
                .strip_prefix("tcp/")
                .or_else(|| endpoint.strip_prefix("tls/"))?;
            let address = address.split(['#', '?']).next()?;
            let (host, port) = address.rsplit_once(':')?;
            let port: u16 = port.parse().ok()?;
            let host = host.trim_start_matches('[').trim_end_matches(']');
            let host = match host {
                "0.0.0.0" | "" => "127.0.0.1",
                "::" => "::1",
                h => h,
            };
            Some((host.to_string(), port))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roster(roles: Vec<Role>) -> Roster {
        Roster {
            bin: "/b".into(),
            config_file: "/r/config.toml".into(),
            run_dir: "/r".into(),
            roles,
            actors: None,
            first_actor: 0,
            connect: Vec::new(),
            learner_args: vec!["--fresh".into()],
            node: None,
            router_config: None,
        }
    }

    #[test]
    fn a_node_of_a_shared_run_folder_keeps_its_own_record_unless_it_runs_the_learner() {
        let mut actors = roster(vec![Role::Actor]);
        assert_eq!(actors.record(), Path::new("/r/supervision.json"));
        actors.node = Some("n2".into());
        assert_eq!(actors.record(), Path::new("/r/supervision-n2.json"));
        let mut head = roster(vec![Role::Learner, Role::Actor]);
        head.node = Some("n1".into());
        assert_eq!(head.record(), Path::new("/r/supervision.json"));
    }

    #[test]
    fn one_machine_runs_every_role_in_order() {
        let mut config = RunConfig::default();
        config.actors.count = 2;
        config.expert.placement = ExpertPlacement::Server;
        let specs = roster(Role::ALL.to_vec()).specs(&config);
        let names: Vec<_> = specs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            ["learner", "expert-server-0", "actor-0", "actor-1", "eval"]
        );
        assert_eq!(specs[0].args[..2], ["run", "--config"]);
        assert_eq!(specs[2].log, PathBuf::from("/r/logs/actor-0.log"));
        assert_eq!(specs[4].args.last().map(String::as_str), Some("--eval"));
        config.expert.placement = ExpertPlacement::InActor;
        config.actors.evaluators = 2;
        let names: Vec<_> = roster(Role::ALL.to_vec())
            .specs(&config)
            .into_iter()
            .map(|s| s.name)
            .collect();
        assert_eq!(names, ["learner", "actor-0", "actor-1", "eval-0", "eval-1"]);
    }

    #[test]
    fn a_machine_that_adds_actors_names_them_from_its_first() {
        let config = RunConfig::default();
        let mut r = roster(vec![Role::Actor]);
        r.actors = Some(2);
        r.first_actor = 4;
        r.connect = vec!["tcp/10.0.0.1:7447".into()];
        let specs = r.specs(&config);
        let names: Vec<_> = specs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["actor-4", "actor-5"]);
        assert!(specs[0]
            .args
            .windows(2)
            .any(|w| w == ["--connect", "tcp/10.0.0.1:7447"]));
    }

    #[test]
    fn the_learner_restarts_with_resume_once_there_is_a_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = roster(vec![Role::Learner]);
        r.run_dir = dir.path().to_path_buf();
        let learner = &r.specs(&RunConfig::default())[0];
        assert_eq!(
            learner.restart_args(dir.path()),
            learner.args,
            "no checkpoint yet: started as before"
        );
        std::fs::create_dir(dir.path().join("checkpoint")).unwrap();
        let again = learner.restart_args(dir.path());
        assert_eq!(again.last().map(String::as_str), Some("--resume"));
        assert!(!again.iter().any(|a| a == "--fresh"));
    }

    #[test]
    fn roles_are_read_in_both_numbers() {
        assert_eq!("actors".parse::<Role>(), Ok(Role::Actor));
        assert_eq!("evaluator".parse::<Role>(), Ok(Role::Evaluator));
        assert_eq!("router".parse::<Role>(), Ok(Role::Router));
        assert!("zenohd".parse::<Role>().is_err());
    }

    #[test]
    fn a_supervised_router_starts_first_on_bus_connect_and_only_for_a_plain_bus() {
        let mut config = RunConfig::default();
        config.bus.connect = vec!["tcp/127.0.0.1:7500".into()];
        let mut roles = vec![Role::Router];
        roles.extend(Role::ALL);
        let specs = roster(roles).specs(&config);
        assert_eq!(specs[0].name, "router");
        assert_eq!(specs[0].program, PathBuf::from("/b/zenohd"));
        assert_eq!(specs[0].args, ["-c", "/r/router.json5"]);
        assert_eq!(specs[1].name, "learner");
        // The learner listens by default: it would hold the router's port.
        assert!(router_endpoints(&config, &[], false)
            .unwrap_err()
            .contains("bus.listen"));
        config.bus.listen.clear();
        let endpoints = router_endpoints(&config, &[], false).unwrap();
        assert_eq!(endpoints, ["tcp/127.0.0.1:7500"]);
        assert_eq!(
            router_config(&endpoints),
            "{ mode: \"router\", listen: { endpoints: [\"tcp/127.0.0.1:7500\"] }, scouting: { multicast: { \
             enabled: false } } }\n"
        );
        // --connect wins over bus.connect, as for the other processes.
        let other = ["tcp/10.0.0.1:7447".to_string()];
        assert_eq!(router_endpoints(&config, &other, false).unwrap(), other);
        config.bus.security.mode = cabc_proto::config::SecurityMode::Mtls;
        assert!(router_endpoints(&config, &[], false)
            .unwrap_err()
            .contains("access control"));
        // With the secured configuration made, the same endpoints.
        assert_eq!(
            router_endpoints(&config, &[], true).unwrap(),
            ["tcp/127.0.0.1:7500"]
        );
    }

    #[test]
    fn the_listen_endpoints_are_dialled_on_loopback() {
        let listen = [
            "tcp/0.0.0.0:7447".to_string(),
            "tls/[::]:7448#iface=lo".into(),
            "tcp/10.1.2.3:7449".into(),
            "udp/1.2.3.4:1".into(),
        ];
        assert_eq!(
            listen_addresses(&listen),
            vec![
                ("127.0.0.1".to_string(), 7447),
                ("::1".into(), 7448),
                ("10.1.2.3".into(), 7449)
            ]
        );
    }
}
