//! deploy/slurm/cabc.sbatch on real Slurm daemons (deploy/slurm/cluster.sh: slurmctld, munged and two slurmd, each
//! node in its own network namespace with its own address, so the bus rides on the nodes' network, not on
//! loopback): the run submitted with sbatch over two nodes reaches its end; one node's step killed mid-run, the run
//! goes on with the other; the job requeued mid-run resumes its run folder and stores every step once.
//! The run is the smoke preset under mutual TLS (the job's default), one actor per node, without the early stop.

use cabc_runfolder::audit::Audit;
use cabc_runfolder::Table;
use cabc_tests::slurm::SlurmCluster;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// One cluster at a time: each test makes its own, and they share the machine's two cores.
static SERIAL: Mutex<()> = Mutex::new(());

const BUDGET: u64 = 256; // smoke's collection.steps_per_epoch

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm/cabc.sbatch")
}

fn cluster(tmp: &Path) -> SlurmCluster {
    SlurmCluster::up(&tmp.join("slurm"), 2).unwrap_or_else(|e| panic!("{e:#}"))
}

/// Submits the smoke run over 2 nodes for `epochs` epochs; (job id, its run folder).
fn submit(cluster: &SlurmCluster, tmp: &Path, epochs: u64) -> (u64, PathBuf) {
    let runs = tmp.join("runs");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin = cabc_tests::bin_dir();
    let (out, script) = (
        tmp.join("job-%j.out").display().to_string(),
        script().display().to_string(),
    );
    let (dir, max_epochs) = (
        tmp.display().to_string(),
        format!("run.max_epochs={epochs}"),
    );
    let job = cluster
        .sbatch(
            &[
                "-N",
                "2",
                "-D",
                &dir,
                "-o",
                &out,
                &script,
                "--config",
                "smoke",
                "--actors-per-node",
                "1",
                "--set",
                &max_epochs,
                "--set",
                "collection.early_stop_successes=1000",
            ],
            &[
                ("CABC_BIN", &bin),
                ("CABC_ROOT", &root),
                ("CABC_RUNS", &runs),
            ],
        )
        .unwrap_or_else(|e| panic!("{e:#}"));
    (job, runs.join(format!("smoke-job{job}")))
}

/// What a failed wait shows: the job's output and the learner's last lines.
fn report(tmp: &Path, job: u64, run: &Path) -> String {
    let read = |p: PathBuf| {
        std::fs::read_to_string(&p).unwrap_or_else(|e| format!("{}: {e}", p.display()))
    };
    let learner = read(run.join("logs/learner.log"));
    let tail: Vec<&str> = learner.lines().rev().take(15).collect();
    // The controller's and the nodes' daemons on this job: why a launch failed, a requeue held, a node drained.
    let mut daemons = String::new();
    let logs = std::fs::read_dir(tmp.join("slurm/log")).map_or(Vec::new(), |d| {
        let mut logs: Vec<PathBuf> = d.filter_map(|e| Some(e.ok()?.path())).collect();
        logs.sort();
        logs
    });
    let (needle, id) = (format!("JobId={job}"), format!("job {job}"));
    for log in logs {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let lines: Vec<&str> = text
            .lines()
            .filter(|l| l.contains(&needle) || l.contains(&id) || l.contains("error"))
            .collect();
        let from = lines.len().saturating_sub(25);
        daemons.push_str(&format!(
            "[{}]\n{}\n",
            log.display(),
            lines[from..].join("\n")
        ));
    }
    format!(
        "job output:\n{}\nlearner.log (last lines, newest first):\n{}\nSlurm's logs on the job:\n{daemons}",
        read(tmp.join(format!("job-{job}.out"))),
        tail.join("\n")
    )
}

fn wait_done(cluster: &SlurmCluster, tmp: &Path, job: u64, run: &Path) {
    let state = cluster
        .wait_state(
            job,
            &["COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "NODE_FAIL"],
            Duration::from_secs(240),
        )
        .unwrap_or_else(|e| panic!("{e:#}\n{}", report(tmp, job, run)));
    assert_eq!(state, "COMPLETED", "{}", report(tmp, job, run));
}

/// The run's epochs recorded in metrics.csv (rows), waited for.
fn wait_epochs(tmp: &Path, job: u64, run: &Path, n: usize) {
    let start = Instant::now();
    let metrics = run.join("metrics.csv");
    while std::fs::read_to_string(&metrics).map_or(0, |t| t.lines().count().saturating_sub(1)) < n {
        assert!(
            start.elapsed() < Duration::from_secs(180),
            "{n} epochs not recorded in 180 s\n{}",
            report(tmp, job, run)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn summary(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap()
}

/// A column of seconds of metrics.csv.
fn seconds(run: &Path, name: &str) -> Vec<f64> {
    let table = Table::read(&run.join(cabc_runfolder::METRICS)).unwrap();
    let cells = table.parsed::<f64>(name).unwrap();
    cells.into_iter().map(|c| c.unwrap_or(f64::NAN)).collect()
}

/// The run's summary, once it says the run ran its `epochs` to its end (`run.max_epochs`).
fn ran_to(run: &Path, epochs: u64) -> serde_json::Value {
    let s = summary(run);
    assert_eq!(s["epochs"], epochs, "{s:#}");
    assert_eq!(s["ended"], format!("max_epochs {epochs} reached"), "{s:#}");
    s
}

/// Nothing lost: every epoch closed with at least its budget (a lost actor counts with the steps of the segments
/// it was heard to deliver, and a segment carries the staged steps of earlier epochs' unfinished laps too, so a
/// struck epoch's sum once came to 308 of 256), and the run's audit (`cabc audit`) accounts for every segment the
/// actors journalled, one by one; printed, or its report on failure.
fn assert_nothing_lost(run: &Path) {
    let taken = column(run, "steps_taken");
    assert!(
        taken.iter().all(|&t| t >= BUDGET),
        "every epoch with its whole budget: {taken:?}\n{}",
        epoch_lines(run)
    );
    let audit = Audit::of(run).unwrap_or_else(|e| panic!("auditing {}: {e}", run.display()));
    assert!(audit.ok(), "{audit}\n{}", epoch_lines(run));
    print!("{audit}");
}

fn column(run: &Path, name: &str) -> Vec<u64> {
    cabc_tests::csv_column(&run.join("metrics.csv"), name)
}

/// The lines at ERROR in the run's logs.
fn errors(run: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(run.join("logs")).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        found.extend(
            text.lines()
                .filter(|l| l.contains("ERROR"))
                .map(|l| format!("{}: {l}", path.display())),
        );
    }
    found
}

/// The learner's lines that tell an epoch's end or an interrupt, for a failed count.
fn epoch_lines(run: &Path) -> String {
    let log = std::fs::read_to_string(run.join("logs/learner.log")).unwrap_or_default();
    log.lines()
        .filter(|l| {
            [
                "epoch done",
                "interrupted",
                "resumed",
                "run ends",
                "left",
                "WARN",
            ]
            .iter()
            .any(|n| l.contains(n))
        })
        .map(|l| l.chars().take(260).collect::<String>())
        .collect::<Vec<_>>()
        .join("\n")
}

/// The steps an actor's log says it published over its life (its last "final metrics" line), if it ended cleanly.
fn final_steps(run: &Path, actor: &str) -> Option<u64> {
    let log = std::fs::read_to_string(run.join(format!("logs/{actor}.log"))).ok()?;
    let line = log.lines().rev().find(|l| l.contains("final metrics"))?;
    let rest = &line[line.find("\"steps\":")? + 8..];
    rest.split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

#[test]
fn an_sbatch_run_over_two_nodes_runs_to_its_end() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = cabc_tests::test_dir();
    let cluster = cluster(tmp.path());
    let (job, run) = submit(&cluster, tmp.path(), 8);
    wait_done(&cluster, tmp.path(), job, &run);
    let s = ran_to(&run, 8);
    assert_eq!(s["duplicate_segments"], 0, "{s:#}");
    // Every epoch closed with its budget, and stored exactly what its markers said was published.
    assert!(column(&run, "steps_taken").iter().all(|&t| t == BUDGET));
    assert_eq!(
        column(&run, "steps_collected"),
        column(&run, "steps_published")
    );
    // The bus ran over the nodes' network: the actors dialled the first node's address, not loopback.
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("tls/10.201."), "{config}");
    // Both nodes collected: actor-0 on n1, actor-1 on n2, each under its node's supervisor.
    for actor in ["actor-0", "actor-1"] {
        let steps = final_steps(&run, actor);
        assert!(
            steps.is_some_and(|s| s > 0),
            "{actor}: {steps:?}\n{}",
            report(tmp.path(), job, &run)
        );
    }
    assert!(run.join("supervision.json").is_file());
    assert!(run.join("supervision-n2.json").is_file());
    let errors = errors(&run);
    assert!(errors.is_empty(), "{errors:#?}");
    println!(
        "slurm: job {job} over n1, n2: {} epochs, actor-0 {:?} and actor-1 {:?} steps",
        s["epochs"],
        final_steps(&run, "actor-0"),
        final_steps(&run, "actor-1")
    );
}

#[test]
fn a_node_lost_mid_run_costs_its_epoch_and_the_run_goes_on() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = cabc_tests::test_dir();
    let cluster = cluster(tmp.path());
    let (job, run) = submit(&cluster, tmp.path(), 24);
    wait_epochs(tmp.path(), job, &run, 4);
    let steps = cluster.steps(job).unwrap();
    let (step, _) = steps
        .iter()
        .find(|(_, nodes)| nodes == "n2")
        .unwrap_or_else(|| panic!("no step on n2: {steps:?}"));
    // The node's step killed: SIGKILL to its supervisor and its actor at once, as a node that dies.
    let struck = column(&run, "steps_taken").len();
    cluster.run("scancel", &["--signal=KILL", step]).unwrap();
    wait_done(&cluster, tmp.path(), job, &run);
    let s = ran_to(&run, 24);
    // Every epoch, the struck one too, closed with its whole budget: actor-1's share went to actor-0.
    assert_nothing_lost(&run);
    assert_eq!(
        final_steps(&run, "actor-1"),
        None,
        "actor-1 was killed, it cannot have ended cleanly"
    );
    assert!(final_steps(&run, "actor-0").is_some_and(|s| s > 0));
    let collect_s = seconds(&run, "collect_s");
    println!(
        "slurm: job {job}: n2's step ({step}) killed during epoch {struck}; the run went on to {} epochs; \
         collection s per epoch: {collect_s:?}",
        s["epochs"]
    );
}

/// A node that vanishes without closing its links (its link cut for longer than zenoh's 10 s lease, then mended):
/// the learner waits the lease, deals the node's share to the other, and the run goes on; the node's actor comes
/// back when the link does.
#[test]
fn a_node_cut_off_mid_run_costs_the_lease_and_the_run_goes_on() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = cabc_tests::test_dir();
    let cluster = cluster(tmp.path());
    let (job, run) = submit(&cluster, tmp.path(), 40);
    wait_epochs(tmp.path(), job, &run, 4);
    let struck = column(&run, "steps_taken").len();
    cluster.set_node_link(2, false).unwrap();
    std::thread::sleep(Duration::from_secs(14));
    cluster.set_node_link(2, true).unwrap();
    wait_done(&cluster, tmp.path(), job, &run);
    let s = ran_to(&run, 40);
    assert_nothing_lost(&run);
    // actor-1 left with the lease and came back with the link, and ended with the run.
    let learner = std::fs::read_to_string(run.join("logs/learner.log")).unwrap();
    let joined = learner
        .lines()
        .filter(|l| l.contains("actor joined") && l.contains("actor-1"))
        .count();
    assert!(learner.contains("actor left"), "{}", epoch_lines(&run));
    assert_eq!(joined, 2, "{}", epoch_lines(&run));
    assert!(final_steps(&run, "actor-1").is_some_and(|s| s > 0));
    let collect_s = seconds(&run, "collect_s");
    println!(
        "slurm: job {job}: n2's link cut for 14 s during epoch {struck}; the run went on to {} epochs; \
         collection s per epoch: {collect_s:?}",
        s["epochs"]
    );
}

#[test]
fn a_requeued_job_resumes_its_run_and_stores_every_step_once() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = cabc_tests::test_dir();
    let cluster = cluster(tmp.path());
    let (job, run) = submit(&cluster, tmp.path(), 20);
    let id = job.to_string();
    // First `scontrol requeue` (what an operator or a preemption does), then the script's own requeue: the USR1
    // that `#SBATCH --signal=B:USR1@120` sends its batch shell before the time limit.
    let mut at_requeue = Vec::new();
    for (after, how) in [(4, "scontrol requeue"), (10, "USR1 to the batch shell")] {
        wait_epochs(tmp.path(), job, &run, after);
        if how == "scontrol requeue" {
            cluster.run("scontrol", &["requeue", &id]).unwrap();
        } else {
            cluster
                .run("scancel", &["--batch", "--signal=USR1", &id])
                .unwrap();
        }
        cluster
            .wait_state(job, &["PENDING"], Duration::from_secs(60))
            .unwrap_or_else(|e| panic!("{how}: {e:#}\n{}", report(tmp.path(), job, &run)));
        at_requeue.push(column(&run, "steps_taken").len());
        // Slurm holds a requeued job back (its BeginTime, 120 s on), which gives its last run time to end on the
        // nodes; the test lets it start as soon as the nodes are idle. (Started at once, the job once went from
        // PENDING to FAILED without starting, in CI, while srun still waited up to 32 s for the last run's steps
        // to end: likely the new launch meeting the old one on a node; the report now holds Slurm's own logs.)
        cluster
            .wait_idle(Duration::from_secs(90))
            .unwrap_or_else(|e| panic!("{how}: {e:#}\n{}", report(tmp.path(), job, &run)));
        cluster
            .run(
                "scontrol",
                &["update", &format!("JobId={id}"), "StartTime=now"],
            )
            .unwrap();
        cluster
            .wait_state(job, &["RUNNING", "COMPLETED"], Duration::from_secs(60))
            .unwrap_or_else(|e| panic!("{how}: {e:#}\n{}", report(tmp.path(), job, &run)));
    }
    wait_done(&cluster, tmp.path(), job, &run);
    let output = std::fs::read_to_string(tmp.path().join(format!("job-{job}.out"))).unwrap();
    assert!(output.contains("(start 3)"), "{output}");
    assert!(output.contains("resuming"), "{output}");
    assert!(output.contains("requeueing job"), "{output}");
    let learner = std::fs::read_to_string(run.join("logs/learner.log")).unwrap();
    // The learner stopped on the scheduler's SIGTERM with its checkpoint, and the requeued job went on from it.
    assert!(
        learner.contains("interrupted (SIGTERM)"),
        "{}",
        report(tmp.path(), job, &run)
    );
    assert_eq!(
        learner.matches("resumed from").count(),
        2,
        "{}",
        report(tmp.path(), job, &run)
    );
    let s = ran_to(&run, 20);
    assert_eq!(s["duplicate_segments"], 0, "{s:#}");
    // Each epoch once, in order, across the requeue; each stored exactly the steps its markers said were published.
    let epochs = column(&run, "epoch");
    assert_eq!(epochs, (0..20).collect::<Vec<u64>>());
    let (stored, published) = (
        column(&run, "steps_collected"),
        column(&run, "steps_published"),
    );
    assert_eq!(stored, published);
    println!(
        "slurm: job {job} requeued after {at_requeue:?} recorded epochs, resumed each time, {} epochs in all; \
         steps stored {} = published {}",
        s["epochs"],
        stored.iter().sum::<u64>(),
        published.iter().sum::<u64>()
    );
    // Every epoch whole, and one by one: what the stopped jobs' learners held unsaved is counted apart, nothing
    // else is missing.
    assert_nothing_lost(&run);
}

/// The pids a node's supervisor recorded for its processes (the supervisor's own is its step's).
fn recorded_pids(run: &Path, record: &str) -> Vec<u32> {
    let text = std::fs::read_to_string(run.join(record)).unwrap_or_default();
    let status: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    status["processes"]
        .as_object()
        .map(|p| {
            p.values()
                .filter_map(|v| v["pid"].as_u64())
                .map(|p| p as u32)
                .collect()
        })
        .unwrap_or_default()
}

fn alive(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
        && !std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .unwrap_or_default()
            .contains(") Z ")
}

#[test]
fn scancel_stops_every_process_of_the_run_cleanly() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = cabc_tests::test_dir();
    let cluster = cluster(tmp.path());
    let (job, run) = submit(&cluster, tmp.path(), 500);
    wait_epochs(tmp.path(), job, &run, 3);
    let mut pids = recorded_pids(&run, "supervision.json");
    pids.extend(recorded_pids(&run, "supervision-n2.json"));
    // The learner, the expert server, the evaluator and actor-0 on n1, actor-1 on n2.
    assert_eq!(pids.len(), 5, "{pids:?}");
    cluster.run("scancel", &[&job.to_string()]).unwrap();
    let state = cluster
        .wait_state(job, &["CANCELLED"], Duration::from_secs(60))
        .unwrap_or_else(|e| panic!("{e:#}\n{}", report(tmp.path(), job, &run)));
    assert_eq!(state, "CANCELLED");
    let start = Instant::now();
    while pids.iter().any(|&p| alive(p)) && start.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(100));
    }
    let left: Vec<u32> = pids.iter().copied().filter(|&p| alive(p)).collect();
    assert!(left.is_empty(), "still running after scancel: {left:?}");
    // The learner ended on the SIGTERM, cleanly, with a checkpoint that a later `--resume` continues.
    let learner = std::fs::read_to_string(run.join("logs/learner.log")).unwrap();
    assert!(
        learner.contains("interrupted (SIGTERM)"),
        "{}",
        epoch_lines(&run)
    );
    assert!(
        learner.contains("run ends: interrupted"),
        "{}",
        epoch_lines(&run)
    );
    assert!(run.join("checkpoint").is_dir());
    let s = summary(&run);
    assert_eq!(s["ended"], "interrupted", "{s:#}");
    // The actors on both nodes and the evaluator stopped as on Ctrl-C: their last metrics, no error exit.
    for process in ["actor-0", "actor-1", "eval"] {
        let log = std::fs::read_to_string(run.join(format!("logs/{process}.log"))).unwrap();
        assert!(
            log.contains("final metrics") && !log.lines().any(|l| l.starts_with("Error:")),
            "{process}: {}",
            log.lines().rev().take(12).collect::<Vec<_>>().join("\n")
        );
    }
    println!(
        "slurm: job {job} cancelled after {} recorded epochs: its {} processes stopped, the learner with its checkpoint",
        column(&run, "epoch").len(),
        pids.len()
    );
}
