//! cabc-tests: end-to-end tests that start the real binaries on loopback (see `tests/tests/`).
//!
//! [`Cluster`] starts the learner, expert servers and actors of a run as child processes, each with its log in
//! the run folder, and stops them all when dropped. The binaries are the release builds in `target/release`
//! (`deploy/test.sh` builds them first).

use anyhow::{bail, Context, Result};
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

/// A run's child processes; all are killed on drop.
pub struct Cluster {
    pub dir: PathBuf,
    pub config: PathBuf,
    children: Vec<(String, Child)>,
}

impl Cluster {
    /// A smoke-sized run named `name` in `dir`, on its own loopback port; `extra` is appended to the TOML (sections
    /// other than run, expert, algorithm, collection, replay, networks, training and bus).
    pub fn new(dir: &Path, name: &str, max_epochs: u64, extra: &str) -> Result<Self> {
        let port = free_port();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let text = format!(
            "[run]\nname = \"{name}\"\nexperiment = \"smoke\"\nseed = 7\nmax_epochs = {max_epochs}\nruns_dir = \"{}\"\n\n\
             [expert]\nkind = \"pid\"\n\n\
             [algorithm]\nlambda = 1.0\nrho = 1.0\nautolabel_every = 2\n\n\
             [collection]\nsteps_per_epoch = 256\ninitial_steps = 256\neval_laps = 2\n\n\
             [replay]\ncapacity = 20000\n\n\
             [networks]\npolicy = {{ layers = 2, width = 32 }}\ndynamics = {{ layers = 2, width = 32 }}\ncritic = {{ layers = 2, width = 32 }}\n\n\
             [training]\ninitial_passes = 2\ndynamics_every = 1\ncritic_every = 2\naux_passes = 2\ncritic_min_uncertain = 4\ndevice = \"cpu\"\n\n\
             [bus]\nlisten = [\"{endpoint}\"]\nconnect = [\"{endpoint}\"]\nepoch_timeout_s = 30.0\n\n{extra}",
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
        std::fs::create_dir_all(&self.dir)?;
        let log = std::fs::File::create(self.dir.join(format!("{label}.log")))?;
        let child = Command::new(bin(binary)?)
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {binary}"))?;
        self.children.push((label.to_string(), child));
        Ok(())
    }

    /// The learner, one PID expert server, `actors` actors and an eval actor.
    pub fn start_all(&mut self, actors: usize, resume: bool) -> Result<()> {
        let config = self.config.display().to_string();
        let run_dir = self.dir.display().to_string();
        let mut learner = vec!["run", "--config", &config, "--run-dir", &run_dir];
        if resume {
            learner.push("--resume");
        }
        self.start("learner", "learner", &learner)?;
        self.start(
            "expert-server",
            "expert-server",
            &["--config", &config, "serve", "--id", "0"],
        )?;
        for i in 0..actors {
            let id = format!("actor-{i}");
            self.start(&id, "actor", &["--config", &config, "--id", &id])?;
        }
        self.start(
            "eval",
            "actor",
            &["--config", &config, "--id", "eval", "--eval"],
        )
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

    /// The last lines of a child's log (for failure messages).
    pub fn log_tail(&self, label: &str) -> String {
        let text =
            std::fs::read_to_string(self.dir.join(format!("{label}.log"))).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(30)..].join("\n")
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
