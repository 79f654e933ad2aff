//! A real Slurm cluster on this machine for the tests of `deploy/slurm/cabc.sbatch`: `deploy/slurm/cluster.sh up`
//! (slurmctld, munged and one slurmd per node, each node in its own network namespace) and `down` on drop, also
//! when a test fails. Needs root; installs Debian's packages when missing. It never skips: a machine where Slurm
//! cannot start fails the test with the script's error.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm/cluster.sh")
}

/// A cluster made in `dir`, taken down on drop.
pub struct SlurmCluster {
    pub dir: PathBuf,
    conf: PathBuf,
}

impl SlurmCluster {
    /// `deploy/slurm/cluster.sh up DIR NODES`; its error (and log) on failure.
    pub fn up(dir: &Path, nodes: u32) -> Result<SlurmCluster> {
        std::fs::create_dir_all(dir)?;
        let out = Command::new("bash")
            .arg(script())
            .args(["up", &dir.display().to_string(), &nodes.to_string()])
            .output()
            .context("running deploy/slurm/cluster.sh")?;
        let cluster = SlurmCluster {
            dir: dir.to_path_buf(),
            conf: dir.join("slurm.conf"),
        };
        if !out.status.success() {
            bail!(
                "deploy/slurm/cluster.sh up {} {nodes} failed: {}",
                dir.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        Ok(cluster)
    }

    /// A Slurm client command (`sbatch`, `scontrol`, ...) that talks to this cluster.
    pub fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// Runs a client command; its stdout, or an error with its stderr.
    pub fn run(&self, program: &str, args: &[&str]) -> Result<String> {
        let out = self
            .command(program)
            .args(args)
            .output()
            .with_context(|| format!("running {program}"))?;
        if !out.status.success() {
            bail!(
                "{program} {}: {}",
                args.join(" "),
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// `sbatch --parsable ARGS` with `env` added; the job's id.
    pub fn sbatch(&self, args: &[&str], env: &[(&str, &Path)]) -> Result<u64> {
        let mut c = self.command("sbatch");
        c.arg("--parsable").args(args);
        for (k, v) in env {
            c.env(k, v);
        }
        let out = c.output().context("running sbatch")?;
        if !out.status.success() {
            bail!("sbatch: {}", String::from_utf8_lossy(&out.stderr).trim());
        }
        let text = String::from_utf8_lossy(&out.stdout);
        text.trim()
            .split(';')
            .next()
            .and_then(|id| id.parse().ok())
            .with_context(|| format!("sbatch printed {text:?}, not a job id"))
    }

    /// A job's `JobState` (`PENDING`, `RUNNING`, `COMPLETED`, ...) as `scontrol show job` says.
    pub fn job_state(&self, job: u64) -> Result<String> {
        let text = self.run("scontrol", &["show", "job", "-o", &job.to_string()])?;
        text.split_whitespace()
            .find_map(|f| f.strip_prefix("JobState="))
            .map(str::to_string)
            .with_context(|| format!("no JobState in {text:?}"))
    }

    /// Waits until `job` is in one of `states`; the state, or an error with the last one seen.
    pub fn wait_state(&self, job: u64, states: &[&str], timeout: Duration) -> Result<String> {
        let start = Instant::now();
        loop {
            let state = self.job_state(job)?;
            if states.contains(&state.as_str()) {
                return Ok(state);
            }
            if start.elapsed() > timeout {
                bail!("job {job} is {state} after {timeout:?}, not one of {states:?}");
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Waits until every node is idle (a requeued job's last run cleaned up on them: its steps ended, its epilog
    /// done); the nodes' states on timeout.
    pub fn wait_idle(&self, timeout: Duration) -> Result<()> {
        let start = Instant::now();
        loop {
            let states = self.run("sinfo", &["-h", "-N", "-o", "%N %T"])?;
            if states.lines().all(|l| l.trim().ends_with(" idle")) {
                return Ok(());
            }
            if start.elapsed() > timeout {
                bail!(
                    "the nodes are not idle after {timeout:?}: {}",
                    states.trim()
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Cuts node `n<k>`'s link to the others (its end of the bridge down: no packet passes, and the connections over
    /// it stay open until their own timeouts, zenoh's lease, end them), or mends it.
    pub fn set_node_link(&self, k: u32, up: bool) -> Result<()> {
        let tag = std::fs::read_to_string(self.dir.join("tag")).context("the cluster's tag")?;
        let link = format!("c{}n{k}h", tag.trim());
        let state = if up { "up" } else { "down" };
        let out = Command::new("ip")
            .args(["link", "set", &link, state])
            .output()
            .context("running ip")?;
        if !out.status.success() {
            bail!(
                "ip link set {link} {state}: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        Ok(())
    }

    /// The running steps of `job`: (step id `<job>.<n>`, node list), the batch step left out.
    pub fn steps(&self, job: u64) -> Result<Vec<(String, String)>> {
        let text = self.run(
            "squeue",
            &["-h", "-s", "-j", &job.to_string(), "-o", "%i %N"],
        )?;
        Ok(text
            .lines()
            .filter_map(|l| l.split_once(' '))
            .filter(|(id, _)| !id.ends_with(".batch") && !id.ends_with(".extern"))
            .map(|(id, nodes)| (id.to_string(), nodes.trim().to_string()))
            .collect())
    }
}

impl Drop for SlurmCluster {
    fn drop(&mut self) {
        let out = Command::new("bash")
            .arg(script())
            .args(["down", &self.dir.display().to_string()])
            .output();
        match out {
            Ok(o) if o.status.success() => {}
            Ok(o) => eprintln!(
                "cluster.sh down: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ),
            Err(e) => eprintln!("cluster.sh down: {e}"),
        }
    }
}
