//! cabc-tests: end-to-end tests that start the real binaries on loopback (see `tests/tests/`).
//!
//! [`Cluster`] starts the learner, expert servers and actors of a run as child processes, each with its log in
//! the run folder, and stops them all when dropped. The binaries are the release builds in `target/release`
//! (`deploy/test.sh` builds them first). [`make_certs`] runs `deploy/make-certs.sh`; [`netns`] makes a pair of
//! network namespaces for runs over a (virtual) network.

pub mod netns;
pub mod slurm;

use anyhow::{bail, Context, Result};
use cabc_runfolder::audit::{Audit, Fate};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The folder of the release binaries: next to this test's own executable (`target/release/deps/..`).
pub fn bin_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>");
    let release = dir
        .parent()
        .map(|t| t.join("release"))
        .unwrap_or_else(|| dir.to_path_buf());
    if release.join("learner").exists() {
        release
    } else {
        dir.to_path_buf()
    }
}

/// Path of one binary; fails with the command that builds it.
pub fn bin(name: &str) -> Result<PathBuf> {
    let path = bin_dir().join(name);
    if !path.exists() {
        bail!(
            "{} is missing: run `cargo build --release --bins` first (deploy/test.sh does)",
            path.display()
        );
    }
    Ok(path)
}

/// A free TCP port on loopback.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

/// Runs `deploy/make-certs.sh ARGS OUT` (a CA and per-component certificates for `[bus.security]`).
pub fn make_certs(out: &Path, args: &[&str]) -> Result<()> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/make-certs.sh");
    let output = Command::new("bash")
        .arg(&script)
        .args(args)
        .arg(out)
        .output()
        .with_context(|| format!("running {}", script.display()))?;
    if !output.status.success() {
        bail!(
            "make-certs.sh failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    Ok(())
}

/// A scratch folder for one test, removed afterwards unless `CABC_KEEP_TEST_DIRS=1` (then its path is printed,
/// so that the logs of a failed run can be read).
pub fn test_dir() -> tempfile::TempDir {
    let mut dir = tempfile::tempdir().expect("a temporary folder");
    if std::env::var("CABC_KEEP_TEST_DIRS").is_ok_and(|v| v == "1") {
        dir.disable_cleanup(true);
        eprintln!("test folder kept: {}", dir.path().display());
    }
    dir
}

/// The column `name` of a CSV file (`metrics.csv`, `evals.csv`), as integers (a value that is not one: u64::MAX).
pub fn csv_column(path: &Path, name: &str) -> Vec<u64> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let i = header
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("{} has no column {name}", path.display()));
    lines
        .map(|l| {
            l.split(',')
                .nth(i)
                .unwrap_or("")
                .parse()
                .unwrap_or(u64::MAX)
        })
        .collect()
}

/// The collecting actors of the tests' runs ([`Cluster::start_all`] with 2).
pub const ACTORS: u64 = 2;

/// A run's child processes; all are killed on drop.
pub struct Cluster {
    pub dir: PathBuf,
    pub config: PathBuf,
    children: Vec<(String, Child)>,
}

impl Cluster {
    /// A smoke-sized run named `name` in `dir`, on its own loopback port, that never stops early (it runs
    /// `max_epochs`); `extra` is appended to the TOML (sections
    /// other than run, expert, algorithm, collection, replay, networks, training and bus; `[bus.security]` is fine).
    pub fn new(dir: &Path, name: &str, max_epochs: u64, extra: &str) -> Result<Self> {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        Self::on(dir, name, max_epochs, &endpoint, &endpoint, extra)
    }

    /// [`Cluster::new`] with the learner listening on `listen` and the others connecting to `connect` (for
    /// instance `tls/...` endpoints with a `[bus.security]` section in `extra`); an empty `listen` makes the
    /// learner a client of a standalone router at `connect` (`bus.listen = []`).
    pub fn on(
        dir: &Path,
        name: &str,
        max_epochs: u64,
        listen: &str,
        connect: &str,
        extra: &str,
    ) -> Result<Self> {
        let listen = match listen {
            "" => String::new(),
            e => format!("\"{e}\""),
        };
        let text = format!(
            "[run]\nname = \"{name}\"\nexperiment = \"smoke\"\nseed = 7\nmax_epochs = {max_epochs}\nruns_dir = \"{}\"\n\n\
             [expert]\nkind = \"pid\"\n\n\
             [algorithm]\nlambda = 1.0\nrho = 1.0\nautolabel_every = 2\n\n\
             [collection]\nsteps_per_epoch = 256\ninitial_steps = 256\neval_laps = 2\nearly_stop_successes = 1000\n\n\
             [replay]\ncapacity = 20000\n\n\
             [networks]\npolicy = {{ layers = 2, width = 32 }}\ndynamics = {{ layers = 2, width = 32 }}\ncritic = {{ layers = 2, width = 32 }}\n\n\
             [training]\ninitial_passes = 2\ndynamics_every = 1\ncritic_every = 2\naux_passes = 2\ncritic_min_uncertain = 4\ndevice = \"cpu\"\n\n\
             [bus]\nlisten = [{listen}]\nconnect = [\"{connect}\"]\nepoch_timeout_s = 30.0\n\n{extra}",
            dir.display()
        );
        std::fs::create_dir_all(dir)?;
        let config = dir.join(format!("{name}.toml"));
        std::fs::write(&config, text)?;
        Ok(Cluster {
            dir: dir.join(name),
            config,
            children: Vec::new(),
        })
    }

    /// Starts a binary with `args`; its stderr goes to `<dir>/<label>.log`.
    pub fn start(&mut self, label: &str, binary: &str, args: &[&str]) -> Result<()> {
        self.start_in(label, &[], binary, args)
    }

    /// [`Cluster::start`] under a wrapper command (e.g. `ip netns exec <ns>`, which execs the binary, so the
    /// child is the binary itself).
    pub fn start_in(
        &mut self,
        label: &str,
        wrapper: &[&str],
        binary: &str,
        args: &[&str],
    ) -> Result<()> {
        // Every collecting actor journals into the run folder, as under `cabc supervise`: the audit reads it.
        let journal = self.dir.join(cabc_runfolder::journal::JOURNAL);
        let journal = journal.display().to_string();
        let mut args = args.to_vec();
        if binary == "actor" && !args.contains(&"--eval") && !args.contains(&"--journal") {
            args.extend(["--journal", journal.as_str()]);
        }
        self.spawn(label, wrapper, &bin(binary)?, &args, "info", false)
    }

    /// [`Cluster::start_in`] for a program outside the workspace's binaries (a `zenohd`), with its `RUST_LOG`;
    /// its stdout goes to the log too.
    pub fn start_program(
        &mut self,
        label: &str,
        wrapper: &[&str],
        program: &Path,
        args: &[&str],
        rust_log: &str,
    ) -> Result<()> {
        self.spawn(label, wrapper, program, args, rust_log, true)
    }

    fn spawn(
        &mut self,
        label: &str,
        wrapper: &[&str],
        program: &Path,
        args: &[&str],
        rust_log: &str,
        stdout_to_log: bool,
    ) -> Result<()> {
        std::fs::create_dir_all(&self.dir)?;
        let log = std::fs::File::create(self.dir.join(format!("{label}.log")))?;
        let stdout = match stdout_to_log {
            true => Stdio::from(log.try_clone()?),
            false => Stdio::piped(),
        };
        let mut command = match wrapper.split_first() {
            Some((first, rest)) => {
                let mut c = Command::new(first);
                c.args(rest).arg(program);
                c
            }
            None => Command::new(program),
        };
        let child = command
            .args(args)
            .env("RUST_LOG", rust_log)
            .stdout(stdout)
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {}", program.display()))?;
        self.children.push((label.to_string(), child));
        Ok(())
    }

    /// The learner, one PID expert server, `actors` actors and an eval actor.
    pub fn start_all(&mut self, actors: usize, resume: bool) -> Result<()> {
        self.start_all_in(actors, resume, &[], &[])
    }

    /// [`Cluster::start_all`] with the learner and the expert server under `servers` and the actors under
    /// `actors_in` (wrappers as in [`Cluster::start_in`]).
    pub fn start_all_in(
        &mut self,
        actors: usize,
        resume: bool,
        servers: &[&str],
        actors_in: &[&str],
    ) -> Result<()> {
        self.start_learner_in("learner", servers, resume)?;
        let config = self.config.display().to_string();
        let serve = ["--config", &config, "serve", "--id", "0"];
        self.start_in("expert-server", servers, "expert-server", &serve)?;
        // The evaluator first, on the bus before any actor: a short run's epochs can otherwise all pass before a
        // slow start (a loaded machine loading libtorch) joins, and the learner does not wait for evaluations.
        let eval = ["--config", &config, "--id", "eval", "--eval"];
        self.start_in("eval", actors_in, "actor", &eval)?;
        self.wait_for_log("eval", "actor started", Duration::from_secs(120))?;
        for i in 0..actors {
            let id = format!("actor-{i}");
            self.start_in(&id, actors_in, "actor", &["--config", &config, "--id", &id])?;
        }
        Ok(())
    }

    /// Waits until the log of child `label` holds `needle` (`timeout` at most).
    pub fn wait_for_log(&self, label: &str, needle: &str, timeout: Duration) -> Result<()> {
        let path = self.dir.join(format!("{label}.log"));
        let started = Instant::now();
        while !std::fs::read_to_string(&path).is_ok_and(|t| t.contains(needle)) {
            if started.elapsed() > timeout {
                bail!(
                    "{label}'s log has no {needle:?} after {timeout:?}:\n{}",
                    self.log_tail(label)
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Ok(())
    }

    /// The learner of this run as `label`, resuming its run folder with `resume` (a fresh label for each restart,
    /// so that each process keeps its own log).
    pub fn start_learner(&mut self, label: &str, resume: bool) -> Result<()> {
        self.start_learner_in(label, &[], resume)
    }

    /// [`Cluster::start_learner`] under a wrapper (as in [`Cluster::start_in`]).
    pub fn start_learner_in(&mut self, label: &str, wrapper: &[&str], resume: bool) -> Result<()> {
        let config = self.config.display().to_string();
        let run_dir = self.dir.display().to_string();
        let mut args = vec!["run", "--config", &config, "--run-dir", &run_dir];
        if resume {
            args.push("--resume");
        }
        self.start_in(label, wrapper, "learner", &args)
    }

    /// Kills one child (as a crash would).
    pub fn kill(&mut self, label: &str) -> Result<()> {
        let (_, child) = self
            .children
            .iter_mut()
            .find(|(l, _)| l == label)
            .with_context(|| format!("no process {label}"))?;
        child.kill()?;
        child.wait()?;
        Ok(())
    }

    /// Sends `signal` (`STOP`, `CONT`, ...) to a child with kill(1).
    pub fn signal(&mut self, label: &str, signal: &str) -> Result<()> {
        let (_, child) = self
            .children
            .iter()
            .find(|(l, _)| l == label)
            .with_context(|| format!("no process {label}"))?;
        let status = std::process::Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()?;
        anyhow::ensure!(status.success(), "kill -{signal} {label}");
        Ok(())
    }

    /// Whether a child is still running.
    pub fn running(&mut self, label: &str) -> bool {
        self.children
            .iter_mut()
            .find(|(l, _)| l == label)
            .is_some_and(|(_, c)| matches!(c.try_wait(), Ok(None)))
    }

    /// Waits for a child to exit; returns its status and stdout.
    pub fn wait(
        &mut self,
        label: &str,
        timeout: Duration,
    ) -> Result<(std::process::ExitStatus, String)> {
        let start = Instant::now();
        let index = self
            .children
            .iter()
            .position(|(l, _)| l == label)
            .with_context(|| format!("no process {label}"))?;
        loop {
            if let Some(status) = self.children[index].1.try_wait()? {
                let (_, mut child) = self.children.remove(index);
                let mut out = String::new();
                if let Some(mut stdout) = child.stdout.take() {
                    use std::io::Read;
                    stdout.read_to_string(&mut out)?;
                }
                return Ok((status, out));
            }
            if start.elapsed() > timeout {
                bail!(
                    "{label} still running after {timeout:?}; logs in {}",
                    self.dir.display()
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Waits for the child `label` to end (`timeout` at most) and checks that it succeeded; returns its stdout.
    /// Panics with its log otherwise.
    pub fn wait_success(&mut self, label: &str, timeout: Duration) -> String {
        let (status, stdout) = self
            .wait(label, timeout)
            .unwrap_or_else(|e| panic!("{e}\n--- {label} log ---\n{}", self.log_tail(label)));
        assert!(
            status.success(),
            "{label} failed:\n{}",
            self.log_tail(label)
        );
        stdout
    }

    /// Waits for the learner `label` to end (400 s at most), checks that it succeeded and returns its
    /// `summary.json` as printed on its stdout; panics with its log otherwise.
    pub fn summary(&mut self, label: &str) -> serde_json::Value {
        let stdout = self.wait_success(label, Duration::from_secs(400));
        serde_json::from_str(&stdout)
            .unwrap_or_else(|e| panic!("{label}'s stdout is not the summary ({e}): {stdout}"))
    }

    /// Waits until the run's `metrics.csv` holds `epochs` rows (240 s at most; then panics with `learner`'s log).
    pub fn wait_for_epochs(&self, epochs: usize, learner: &str) {
        self.wait_for_rows("metrics.csv", epochs, learner);
    }

    /// Waits (4 min at most) until the learner has `n` evaluations in `evals.csv`: an evaluator is up and follows
    /// the run's versions.
    pub fn wait_for_evaluations(&self, n: usize, learner: &str) {
        self.wait_for_rows("evals.csv", n, learner);
    }

    fn wait_for_rows(&self, file: &str, rows: usize, learner: &str) {
        let path = self.dir.join(file);
        let started = Instant::now();
        while std::fs::read_to_string(&path).map_or(0, |t| t.lines().count().saturating_sub(1))
            < rows
        {
            assert!(
                started.elapsed() < Duration::from_secs(240),
                "{rows} rows of {file} not written:\n{}",
                self.log_tail(learner)
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Nothing was lost: the run's audit accounts for every segment the actors journalled ([`Cluster::audit`]), and
    /// every epoch of `metrics.csv` closed with at least `budget` steps taken. Returns (stored, published) per epoch.
    pub fn assert_nothing_lost(&self, budget: u64) -> (Vec<u64>, Vec<u64>) {
        let metrics = self.dir.join("metrics.csv");
        let stored = csv_column(&metrics, "steps_collected");
        let published = csv_column(&metrics, "steps_published");
        self.audit();
        // At least the budget: an actor taken for lost whose marker comes after all (a link back within the epoch)
        // adds its steps to the share dealt again, so an epoch may take more, never less.
        let taken = csv_column(&metrics, "steps_taken");
        assert!(
            taken.iter().all(|&t| t >= budget),
            "every epoch closed with its whole budget: {taken:?}\n{}",
            self.log_lines(&["epoch done", "WARN", "ERROR"], 60)
        );
        (stored, published)
    }

    /// The run's audit (`cabc audit`, issue 74): every segment the actors journalled accounted for, one by one, and
    /// the learner's final ledger in agreement with the journals; the test fails with the audit's report otherwise.
    pub fn audit(&self) -> Audit {
        let audit = Audit::of(&self.dir).unwrap_or_else(|e| panic!("auditing the run: {e}"));
        assert!(
            audit.ok(),
            "{audit}\n{}",
            self.log_lines(&["epoch done", "WARN", "ERROR"], 60)
        );
        audit
    }

    /// Over a run whose actors lived to its end, every segment they published was stored once (the audit): none
    /// lost on the wire (an actor's outbox publishes again what the learner did not receive), none with a learner
    /// killed (what it received and never committed in a checkpoint goes again to the resumed one), none twice (the
    /// ledger drops the copies).
    pub fn assert_each_step_stored_once(&self) {
        let audit = self.audit();
        assert_eq!(
            audit.count(Fate::Stored),
            audit.published(),
            "every published segment stored:\n{audit}"
        );
    }

    /// The last lines of a child's log (for failure messages).
    /// The lines of every log of the run (`<label>.log`) that hold one of `needles`, at most `limit` a log, each
    /// under its log's name: what a failed count needs to show (the epochs' closings, the warnings).
    pub fn log_lines(&self, needles: &[&str], limit: usize) -> String {
        let mut out = String::new();
        let mut logs: Vec<PathBuf> = std::fs::read_dir(&self.dir)
            .map(|d| d.filter_map(|e| Some(e.ok()?.path())).collect())
            .unwrap_or_default();
        logs.retain(|p| p.extension().is_some_and(|e| e == "log"));
        logs.sort();
        for log in logs {
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            let lines: Vec<&str> = text
                .lines()
                .filter(|l| needles.iter().any(|n| l.contains(n)))
                .take(limit)
                .collect();
            if !lines.is_empty() {
                out.push_str(&format!("[{}]\n{}\n", log.display(), lines.join("\n")));
            }
        }
        out
    }

    pub fn log_tail(&self, label: &str) -> String {
        let text =
            std::fs::read_to_string(self.dir.join(format!("{label}.log"))).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        let tail = lines.len().saturating_sub(30);
        // Errors and panics from before the tail too: they are what a failing test needs to show.
        let earlier: Vec<&str> = lines[..tail]
            .iter()
            .filter(|l| {
                l.contains("ERROR") || l.contains("panicked") || l.contains("allocation of")
            })
            .take(20)
            .copied()
            .collect();
        let mut out = String::new();
        if !earlier.is_empty() {
            out.push_str("[errors before the tail]\n");
            out.push_str(&earlier.join("\n"));
            out.push_str("\n[tail]\n");
        }
        out.push_str(&lines[tail..].join("\n"));
        out
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for (_, child) in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}
