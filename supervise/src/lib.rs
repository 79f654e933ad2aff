//! The run's supervisor (issue 64): starts the processes of a run ([`roster`]), restarts each one that dies with a
//! backoff ([`policy`]; the learner with `--resume`), says so on the terminal and in the process's log, counts the
//! restarts by role in the run folder's `supervision.json` ([`status`], which the learner puts in `metrics.csv` and
//! `summary.json`), and stops the run with an error naming the process and its log when one keeps dying. One Ctrl-C
//! (or SIGTERM) stops every process; the run ends when the learner does.
//!
//! `cabc supervise` is its command; `deploy/run-local.sh` runs it for the main job, and a machine that adds actors to a
//! running run runs it with `--roles actor` (deploy/SCALE-OUT.md).
//!
//! A process that exits 0 has finished (an actor after the learner's stop) and is not started again; the learner's
//! exit 0 ends the run, and its [`exit::NO_ACTORS`] (it waited `bus.no_actor_timeout_s` with no live actor) ends it
//! with an error: restarting the learner would not bring actors back.

pub mod chaos;
mod error;
pub mod policy;
mod process;
pub mod roster;
pub use cabc_runfolder::{exit, status};

pub use error::SuperviseError;
pub use process::describe;

use cabc_proto::config::SupervisionSection;
use policy::{Deaths, Decision};
use process::{accepting, append, catch_signals, interrupted, spawn};
use roster::{Restart, Role, Roster, Spec};
use status::{ProcessStatus, Status};
use std::process::Child;
use std::time::{Duration, Instant};

/// How long the learner's bus may take to accept connections before the others start regardless.
const BUS_WAIT: Duration = Duration::from_secs(60);
/// How often the processes are looked at.
const POLL: Duration = Duration::from_millis(100);
/// How long the processes have after the learner's end (its stop reached them) before they are interrupted.
const AFTER_LEARNER: Duration = Duration::from_secs(5);

/// How a supervised run ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Ended {
    /// The learner ended by itself (early stop, budget, its own Ctrl-C): its exit status.
    Learner { code: i32, after: Duration },
    /// Ctrl-C or SIGTERM reached the supervisor.
    Interrupted,
    /// No learner here, and every process finished (the learner's stop reached them).
    Finished,
    /// Its [`Watcher`] stopped it, for this reason (the chaos's time limit).
    Stopped(String),
}

/// The exit status of a command whose supervised run ended so: the learner's own, 0 for a stop asked for or a
/// machine whose processes finished, 1 for a watcher's stop, the error's for an error.
pub fn exit_code(ended: &Result<Ended, SuperviseError>) -> i32 {
    match ended {
        Ok(Ended::Learner { code, .. }) => *code,
        Ok(Ended::Interrupted | Ended::Finished) => 0,
        Ok(Ended::Stopped(_)) => 1,
        Err(e) => e.exit_code(),
    }
}

/// A running process as a [`Watcher`] sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Live {
    pub name: String,
    pub role: Role,
    pub pid: u32,
}

/// What runs in the supervisor's loop beside it (the chaos of [`chaos`]): it sees the running processes at every
/// poll, from the supervisor itself, and may end the run.
pub trait Watcher {
    /// At each poll, the processes running now; `Some(why)` stops the run as an interrupt does
    /// ([`Ended::Stopped`]).
    fn poll(&mut self, live: &[Live]) -> Option<String>;
    /// Once, before the processes are stopped, however the run ends (a process it paused is continued here).
    fn before_stop(&mut self) {}
}

/// The watcher of a plain supervised run: none.
struct Unwatched;

impl Watcher for Unwatched {
    fn poll(&mut self, _: &[Live]) -> Option<String> {
        None
    }
}

/// One supervised process.
struct Managed {
    spec: Spec,
    child: Option<Child>,
    started: Instant,
    deaths: Deaths,
    /// When it is started again, after a death.
    restart_at: Option<Instant>,
    /// It exited 0: not started again.
    finished: bool,
}

/// Runs a [`Roster`]'s processes until the run ends.
pub struct Supervisor {
    roster: Roster,
    policy: SupervisionSection,
    /// Where the learner's bus accepts connections (empty: no TCP endpoint, or no learner here).
    listen: Vec<(String, u16)>,
    /// The supervised router's endpoints, when it runs here (or why it cannot).
    router: Option<Result<Vec<String>, String>>,
    /// The learner draws its progress bar on this terminal (and writes its own log file).
    brief: bool,
    procs: Vec<Managed>,
    status: Status,
}

impl Supervisor {
    /// A supervisor of `roster` under `config`'s `[supervision]`; with `brief` the learner draws its progress bar on
    /// the terminal, else its lines go to its log and to this process's stderr.
    pub fn new(roster: Roster, config: &cabc_proto::config::RunConfig, brief: bool) -> Self {
        let specs = roster.specs(config);
        let listen = if roster.roles.contains(&Role::Learner) {
            roster::listen_addresses(&config.bus.listen)
        } else {
            Vec::new()
        };
        let router = roster.roles.contains(&Role::Router).then(|| {
            roster::router_endpoints(config, &roster.connect, roster.router_config.is_some())
        });
        let procs = specs
            .into_iter()
            .map(|spec| Managed {
                spec,
                child: None,
                started: Instant::now(),
                deaths: Deaths::new(&config.supervision),
                restart_at: None,
                finished: false,
            })
            .collect();
        Supervisor {
            roster,
            policy: config.supervision.clone(),
            listen,
            router,
            brief,
            procs,
            status: Status::new(Role::ALL.iter().map(|r| r.as_str())),
        }
    }

    /// The names of the processes, in the order they start.
    pub fn names(&self) -> Vec<String> {
        self.procs.iter().map(|p| p.spec.name.clone()).collect()
    }

    /// Starts the run's processes and supervises them until the run ends.
    pub fn run(&mut self) -> Result<Ended, SuperviseError> {
        self.run_watched(&mut Unwatched)
    }

    /// [`Supervisor::run`] with `watcher` in its loop.
    pub fn run_watched(&mut self, watcher: &mut dyn Watcher) -> Result<Ended, SuperviseError> {
        catch_signals();
        let router = match &self.router {
            Some(Ok(endpoints)) => roster::listen_addresses(endpoints),
            Some(Err(why)) => return Err(SuperviseError::Router(why.clone())),
            None => Vec::new(),
        };
        // A bus endpoint another run holds: refused before anything starts (this run's actors would join that bus).
        if let Some((host, port)) = self.listen.iter().chain(&router).find(|a| accepting(a)) {
            return Err(SuperviseError::PortInUse {
                endpoint: format!("{host}:{port}"),
            });
        }
        let logs = self.roster.run_dir.join("logs");
        std::fs::create_dir_all(&logs).map_err(|source| SuperviseError::Io {
            what: format!("creating {}", logs.display()),
            source,
        })?;
        for p in &self.procs {
            self.status.processes.insert(
                p.spec.name.clone(),
                ProcessStatus {
                    role: p.spec.role.as_str().into(),
                    restarts: 0,
                    pid: None,
                    last_exit: None,
                    log: p.spec.log.display().to_string(),
                },
            );
        }
        if let Some(Ok(endpoints)) = &self.router {
            let file = self.roster.run_dir.join(roster::ROUTER_CONFIG);
            let text = self
                .roster
                .router_config
                .clone()
                .unwrap_or_else(|| roster::router_config(endpoints));
            std::fs::write(&file, text).map_err(|source| SuperviseError::Io {
                what: format!("writing {}", file.display()),
                source,
            })?;
        }
        self.write_status()?;
        let started = Instant::now();
        let result = self.start_and_watch(started, &router, watcher);
        watcher.before_stop();
        self.stop_all(Duration::ZERO);
        for entry in self.status.processes.values_mut() {
            entry.pid = None;
        }
        if let Err(e) = &result {
            self.status.ended = Some(e.to_string());
        }
        let _ = self.write_status();
        result
    }

    /// Starts the router (when it runs here) and waits for it to accept on `router`, then the learner and waits for
    /// its bus, then the others; watches them until the run ends.
    fn start_and_watch(
        &mut self,
        started: Instant,
        router: &[(String, u16)],
        watcher: &mut dyn Watcher,
    ) -> Result<Ended, SuperviseError> {
        let position = |role| self.procs.iter().position(|p| p.spec.role == role);
        let (first, learner) = (position(Role::Router), position(Role::Learner));
        for (i, addresses) in [(first, router.to_vec()), (learner, self.listen.clone())] {
            let Some(i) = i else { continue };
            self.start(i, false)?;
            if !self.wait_for_bus(i, &addresses)? {
                return Ok(Ended::Interrupted);
            }
        }
        for i in 0..self.procs.len() {
            if Some(i) != learner && Some(i) != first {
                self.start(i, false)?;
            }
        }
        loop {
            if interrupted() {
                return Ok(Ended::Interrupted);
            }
            let now = Instant::now();
            for i in 0..self.procs.len() {
                if let Some(ended) = self.look_at(i, now, started)? {
                    return Ok(ended);
                }
            }
            if learner.is_none() && self.procs.iter().all(|p| p.finished) {
                return Ok(Ended::Finished);
            }
            if let Some(why) = watcher.poll(&self.live()) {
                return Ok(Ended::Stopped(why));
            }
            std::thread::sleep(POLL);
        }
    }

    /// The processes running now.
    pub fn live(&self) -> Vec<Live> {
        self.procs
            .iter()
            .filter_map(|p| {
                Some(Live {
                    name: p.spec.name.clone(),
                    role: p.spec.role,
                    pid: p.child.as_ref()?.id(),
                })
            })
            .collect()
    }

    /// Process `i`: handles its death (a restart planned, or the run's end), or starts it again when due.
    fn look_at(
        &mut self,
        i: usize,
        now: Instant,
        started: Instant,
    ) -> Result<Option<Ended>, SuperviseError> {
        let exited = match self.procs[i].child.as_mut().map(Child::try_wait) {
            Some(Ok(Some(status))) => status,
            Some(Ok(None)) | None => {
                if self.procs[i].restart_at.is_some_and(|at| now >= at) {
                    self.procs[i].restart_at = None;
                    self.start(i, true)?;
                }
                return Ok(None);
            }
            Some(Err(e)) => {
                return Err(SuperviseError::Io {
                    what: format!("waiting for {}", self.procs[i].spec.name),
                    source: e,
                })
            }
        };
        let p = &mut self.procs[i];
        p.child = None;
        let (name, role, log) = (p.spec.name.clone(), p.spec.role, p.spec.log.clone());
        let how = describe(exited);
        let lived = now.duration_since(p.started);
        let child = role.child_spec();
        let gave_up = child.gives_up.is_some() && exited.code() == child.gives_up;
        let done = exited.success() && child.restart == Restart::Transient;
        let decision = if done || gave_up || interrupted() {
            None
        } else {
            Some(p.deaths.died(now))
        };
        if done && !child.significant {
            p.finished = true;
        }
        if let Some(Decision::Restart(wait)) = decision {
            p.restart_at = Some(now + wait);
        }
        if let Some(entry) = self.status.processes.get_mut(&name) {
            entry.last_exit = Some(how.clone());
            entry.pid = None;
        }
        match decision {
            None if child.significant && exited.success() => {
                self.write_status()?;
                self.wind_down(AFTER_LEARNER);
                Ok(Some(Ended::Learner {
                    code: 0,
                    after: now.duration_since(started),
                }))
            }
            None if gave_up => Err(SuperviseError::NoActors { log }),
            None if interrupted() => Ok(Some(Ended::Interrupted)),
            None => {
                self.write_status()?;
                Ok(None)
            }
            Some(Decision::GiveUp { deaths }) => Err(SuperviseError::CrashLoop {
                name,
                deaths,
                window_s: self.policy.window_s,
                how,
                log,
            }),
            Some(Decision::Restart(wait)) => {
                let count = match self.status.processes.get_mut(&name) {
                    Some(entry) => {
                        entry.restarts += 1;
                        entry.restarts
                    }
                    None => 1,
                };
                *self
                    .status
                    .restarts
                    .entry(role.as_str().to_string())
                    .or_default() += 1;
                self.write_status()?;
                let line = format!(
                    "[supervise] warning: {name} died ({how}) after {:.0} s; restarting it in {:.1} s (restart \
                     {count}; log {})",
                    lived.as_secs_f64(),
                    wait.as_secs_f64(),
                    log.display()
                );
                eprintln!("{line}");
                append(&log, &line);
                Ok(None)
            }
        }
    }

    /// Starts process `i` (again, with its restart arguments, when `restart`).
    fn start(&mut self, i: usize, restart: bool) -> Result<(), SuperviseError> {
        let p = &mut self.procs[i];
        let args = if restart {
            p.spec.restart_args(&self.roster.run_dir)
        } else {
            p.spec.args.clone()
        };
        let child = spawn(&p.spec, &args, self.brief).map_err(|source| SuperviseError::Spawn {
            name: p.spec.name.clone(),
            program: p.spec.program.clone(),
            source,
        })?;
        let pid = child.id();
        p.child = Some(child);
        p.started = Instant::now();
        let name = p.spec.name.clone();
        if let Some(entry) = self.status.processes.get_mut(&name) {
            entry.pid = Some(pid);
        }
        self.write_status()
    }

    /// Waits until process `i` (the router, the learner) accepts connections on `addresses` (up to [`BUS_WAIT`]; a
    /// second without a TCP endpoint). False on an interrupt; an error when the process ends first.
    fn wait_for_bus(
        &mut self,
        i: usize,
        addresses: &[(String, u16)],
    ) -> Result<bool, SuperviseError> {
        if addresses.is_empty() {
            std::thread::sleep(Duration::from_secs(1));
            return Ok(true);
        }
        let until = Instant::now() + BUS_WAIT;
        while Instant::now() < until {
            if interrupted() {
                return Ok(false);
            }
            let p = &mut self.procs[i];
            if let Some(Ok(Some(status))) = p.child.as_mut().map(Child::try_wait) {
                p.child = None;
                return Err(SuperviseError::DidNotStart {
                    name: p.spec.name.clone(),
                    how: describe(status),
                    code: status.code(),
                    log: p.spec.log.clone(),
                });
            }
            if addresses.iter().all(accepting) {
                return Ok(true);
            }
            std::thread::sleep(POLL);
        }
        Ok(true)
    }

    /// Waits up to `wait` for the processes to end by themselves, then stops the rest.
    fn wind_down(&mut self, wait: Duration) {
        let until = Instant::now() + wait;
        while Instant::now() < until && self.reap() > 0 {
            std::thread::sleep(POLL);
        }
    }

    /// Stops every process still running, in the reverse of their start order (the evaluators and actors first,
    /// the learner and then the router last): each gets SIGINT (it ends cleanly: the learner keeps its
    /// checkpoint), then after its role's `shutdown` SIGTERM, then SIGKILL. `first` waits before anything is sent.
    fn stop_all(&mut self, first: Duration) {
        self.wind_down(first);
        for i in (0..self.procs.len()).rev() {
            let shutdown = self.procs[i].spec.role.child_spec().shutdown;
            for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGKILL] {
                let p = &mut self.procs[i];
                let Some(child) = p.child.as_mut() else { break };
                if !matches!(child.try_wait(), Ok(None)) {
                    p.child = None;
                    break;
                }
                // SAFETY: kill(2) on a child's pid that has not been reaped (try_wait just saw it running).
                unsafe {
                    libc::kill(child.id() as libc::pid_t, signal);
                }
                let until = Instant::now() + shutdown;
                while Instant::now() < until && matches!(child.try_wait(), Ok(None)) {
                    std::thread::sleep(POLL / 10);
                }
            }
            self.procs[i].child = None;
        }
    }

    /// Reaps the processes that ended; returns how many still run.
    fn reap(&mut self) -> usize {
        let mut running = 0;
        for p in &mut self.procs {
            if let Some(child) = &mut p.child {
                match child.try_wait() {
                    Ok(Some(_)) | Err(_) => p.child = None,
                    Ok(None) => running += 1,
                }
            }
        }
        running
    }

    fn write_status(&self) -> Result<(), SuperviseError> {
        let record = self.roster.record();
        self.status
            .write(&record)
            .map_err(|source| SuperviseError::Io {
                what: format!("writing {}", record.display()),
                source,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::config::{ExpertPlacement, RunConfig};
    use std::os::unix::fs::PermissionsExt;

    /// A program that notes, on SIGINT, who it was (its name and arguments) in `order`, and ends.
    fn noting_program(bin: &std::path::Path, name: &str, order: &std::path::Path) {
        let path = bin.join(name);
        let script = format!(
            "#!/bin/sh\ntrap 'echo \"{name} $*\" >> {}; exit 0' INT\nwhile :; do sleep 0.02; done\n",
            order.display()
        );
        std::fs::write(&path, script).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }

    #[test]
    fn the_processes_stop_in_the_reverse_of_their_start_order() {
        let dir = tempfile::tempdir().unwrap();
        let (bin, run_dir, order) = (
            dir.path().join("bin"),
            dir.path().join("run"),
            dir.path().join("order"),
        );
        std::fs::create_dir_all(&bin).unwrap();
        std::fs::create_dir_all(run_dir.join("logs")).unwrap();
        for name in ["learner", "expert-server", "actor"] {
            noting_program(&bin, name, &order);
        }
        let mut config = RunConfig::default();
        config.actors.count = 2;
        config.expert.placement = ExpertPlacement::Server;
        let roster = Roster {
            bin,
            config_file: dir.path().join("config.toml"),
            run_dir,
            roles: Role::ALL.to_vec(),
            actors: None,
            first_actor: 0,
            connect: Vec::new(),
            learner_args: Vec::new(),
            node: None,
            router_config: None,
        };
        let mut supervisor = Supervisor::new(roster, &config, false);
        assert_eq!(
            supervisor.names(),
            ["learner", "expert-server-0", "actor-0", "actor-1", "eval"]
        );
        for i in 0..supervisor.procs.len() {
            supervisor.start(i, false).unwrap();
        }
        // Each has set its trap.
        std::thread::sleep(Duration::from_millis(500));
        supervisor.stop_all(Duration::ZERO);
        let noted = std::fs::read_to_string(&order).unwrap();
        let who: Vec<String> = noted
            .lines()
            .map(|l| {
                let words: Vec<&str> = l.split_whitespace().collect();
                match words[0] {
                    "actor" if words.contains(&"--eval") => "eval".to_string(),
                    "actor" => {
                        let id = words.iter().position(|w| *w == "--id").unwrap();
                        words[id + 1].to_string()
                    }
                    other => other.to_string(),
                }
            })
            .collect();
        assert_eq!(
            who,
            ["eval", "actor-1", "actor-0", "expert-server", "learner"]
        );
        assert!(supervisor.procs.iter().all(|p| p.child.is_none()));
    }

    #[test]
    fn the_child_specs_say_who_restarts_and_who_ends_the_run() {
        let learner = Role::Learner.child_spec();
        assert!(learner.significant);
        assert_eq!(learner.gives_up, Some(exit::NO_ACTORS));
        assert_eq!(Role::Router.child_spec().restart, Restart::Permanent);
        for role in [Role::Expert, Role::Actor, Role::Evaluator] {
            let spec = role.child_spec();
            assert_eq!(spec.restart, Restart::Transient);
            assert!(!spec.significant && spec.gives_up.is_none());
            assert!(spec.shutdown <= learner.shutdown);
        }
    }
}
