//! One measurement of `cabc bench-bus`: a real learner (`Learner` of the kind's preset: its replay, ledger and
//! policy) behind the real [`ZenohActors`], fed by `actors` synthetic actors in a child process, on the embedded
//! router or through a standalone zenohd; epoch after epoch until the time is up, each publishing the policy
//! (the broadcast), gathering its share from every actor ([`Learner::store`]) and partitioning it into the replay
//! ([`Learner::partition`]), without training. Every segment offered to the learner is counted by (actor, seq)
//! against what the actors say they published.

use super::actors::ActorsReport;
use super::{cpu, CapacityError, Case, Measurement, Router};
use cabc_bus::receipts::ReceiptTimes;
use cabc_bus::rollouts::{Waits, ZenohActors};
use cabc_bus::{interrupt::Interrupt, Bus, Role};
use cabc_learning::checkpointer::InMemory;
use cabc_learning::learner::Learner;
use cabc_learning::record::Record;
use cabc_learning::sink::{Sink, SinkError};
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::Segment;
use cabc_proto::ports::Rollouts;
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The hidden subcommand of the same binary that runs the actors ([`super::actors::serve`]).
pub const ACTORS_SUBCOMMAND: &str = "bench-bus-actors";

/// A sink that keeps nothing: the bench measures the intake, not the run's files.
struct NoSink;

impl Sink for NoSink {
    fn write(&mut self, _record: &Record) -> Result<(), SinkError> {
        Ok(())
    }
}

fn free_port() -> Result<u16, CapacityError> {
    let listener =
        TcpListener::bind("127.0.0.1:0").map_err(|e| CapacityError::io("a free port", e))?;
    Ok(listener
        .local_addr()
        .map_err(|e| CapacityError::io("a free port", e))?
        .port())
}

fn unix_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// A child process, killed when dropped (a bench that fails leaves no router or actors behind).
struct Owned(Child);

impl Drop for Owned {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// A standalone zenohd for the measurement, on `endpoint`, with the run's plain configuration
/// (`cabc_bus::zenohd::config`, as `deploy/zenohd.json5`).
fn start_zenohd(
    zenohd: &Path,
    config: &RunConfig,
    keys: &Keys,
    endpoint: &str,
    port: u16,
    folder: &Path,
) -> Result<Owned, CapacityError> {
    let text = cabc_bus::zenohd::config(&config.bus, keys, &[endpoint.to_string()])?;
    let path = folder.join("zenohd.json5");
    std::fs::write(&path, text)
        .map_err(|e| CapacityError::io("writing zenohd's configuration", e))?;
    let child = Command::new(zenohd)
        .arg("-c")
        .arg(&path)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| CapacityError::io(&format!("starting {}", zenohd.display()), e))?;
    let router = Owned(child);
    let until = Instant::now() + Duration::from_secs(20);
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        if Instant::now() > until {
            return Err(CapacityError::Setup(format!(
                "zenohd did not listen on {endpoint} within 20 s"
            )));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(router)
}

/// The learner's side of the books: how often each (actor, seq) was offered to the learner.
#[derive(Default)]
struct Offered(HashMap<String, Vec<u32>>);

/// The seqs the books follow per actor (a segment past it is not counted offered, so it shows as missing).
const MAX_SEQ: u64 = 1 << 24;

impl Offered {
    fn offer(&mut self, segment: &Segment) {
        if segment.seq >= MAX_SEQ {
            return;
        }
        let seqs = match self.0.get_mut(segment.actor.as_str()) {
            Some(seqs) => seqs,
            None => self.0.entry(segment.actor.clone()).or_default(),
        };
        let seq = segment.seq as usize;
        if seqs.len() <= seq {
            seqs.resize(seq + 1, 0);
        }
        seqs[seq] += 1;
    }
}

/// Times of the learner's main thread and what it took, all measured epochs together.
#[derive(Default)]
pub(super) struct MainTimes {
    pub store: Duration,
    pub partition: Duration,
    pub publish: Duration,
    /// Putting the committed receipts of the epoch's segments.
    pub commit: Duration,
    /// Segments and steps offered to the learner.
    pub segments: u64,
    pub steps: u64,
}

/// One epoch: publish version `epoch`, gather its segments into the learner, partition them. The publication's
/// time (µs since the Unix epoch).
fn epoch(
    learner: &mut Learner,
    actors: &mut ZenohActors,
    epoch: u64,
    offered: &mut Offered,
    times: &mut MainTimes,
) -> Result<u64, CapacityError> {
    learner.begin_epoch(epoch);
    let started = Instant::now();
    let update = learner.policy_update(epoch);
    let published = unix_us();
    actors.publish(&update)?;
    times.publish += started.elapsed();
    let mut store = |segment: Segment| {
        offered.offer(&segment);
        times.segments += 1;
        times.steps += segment.steps.len() as u64;
        let started = Instant::now();
        learner.store(segment);
        times.store += started.elapsed();
    };
    let collected = actors
        .gather(&update, &mut store)?
        .ok_or_else(|| CapacityError::Setup("interrupted".into()))?;
    let started = Instant::now();
    learner.partition(&collected);
    times.partition += started.elapsed();
    // The committed receipts, as the real learner puts them after its checkpoint: the actors forget the epoch's
    // segments (without them every outbox grows until it drops its oldest, counted lost).
    let started = Instant::now();
    actors.commit(&learner.settled());
    times.commit += started.elapsed();
    Ok(published)
}

/// Where the CPU was at one moment.
pub(super) struct Reading {
    pub at: Instant,
    pub process: Duration,
    /// The learner's main thread (this one).
    pub main: Duration,
    pub threads: BTreeMap<String, Duration>,
    pub actors: Option<Duration>,
    pub router: Option<Duration>,
    pub receipts: ReceiptTimes,
}

/// The measured epochs: the readings around them, the main thread's times, and each version's publication (µs
/// since the Unix epoch).
pub(super) struct Window {
    pub before: Reading,
    pub after: Reading,
    pub times: MainTimes,
    pub published: BTreeMap<u64, u64>,
}

impl Reading {
    fn now(actors: &ZenohActors, actors_pid: u32, router_pid: Option<u32>) -> Reading {
        Reading {
            at: Instant::now(),
            process: cpu::process(),
            main: cpu::this_thread(),
            threads: cpu::by_thread_name(),
            actors: cpu::of_process(actors_pid),
            router: router_pid.and_then(cpu::of_process),
            receipts: actors.receipt_times(),
        }
    }
}

/// `case`, measured for `seconds` after a warm-up epoch.
pub fn measure(
    case: &Case,
    seconds: f64,
    zenohd: &Path,
    actors_exe: &Path,
) -> Result<Measurement, CapacityError> {
    let folder = tempfile_dir()?;
    let port = free_port()?;
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut config = RunConfig::load(case.kind.preset())?;
    config.run.name = format!("bench-bus-{}-{}", std::process::id(), unix_us());
    config.actors.count = case.actors as u32;
    config.actors.evaluators = 0;
    // The warm-up: every actor joins and sends a few segments; then the measured epochs.
    config.collection.initial_steps = (case.actors * case.steps_per_segment * 4) as u64;
    config.collection.steps_per_epoch = case.epoch_steps;
    config.bus.epoch_timeout_s = 600.0;
    config.bus.no_actor_timeout_s = 60.0;
    if let Some(ms) = case.segment_batch_ms {
        config.bus.segment_batch_ms = ms;
    }
    let batching = (
        config.bus.segment_batch_ms.to_string(),
        config.bus.segment_batch_kib.to_string(),
    );
    match case.router {
        Router::Embedded => {
            config.bus.listen = vec![endpoint.clone()];
            config.bus.connect = Vec::new();
        }
        Router::Zenohd => {
            config.bus.listen = Vec::new();
            config.bus.connect = vec![endpoint.clone()];
        }
    }
    let keys = Keys::new(&config.run.name).map_err(|e| CapacityError::Setup(e.to_string()))?;
    let router = match case.router {
        Router::Zenohd => Some(start_zenohd(
            zenohd, &config, &keys, &endpoint, port, &folder.0,
        )?),
        Router::Embedded => None,
    };
    let waits = Waits {
        epoch_timeout: Duration::from_secs_f64(config.bus.epoch_timeout_s),
        no_actor_timeout: Duration::from_secs_f64(config.bus.no_actor_timeout_s),
    };
    let bus = Bus::join(&config.bus, Role::of_learner(&config.bus), keys, "learner")?;
    let mut actors = ZenohActors::new(bus, &config, waits, Interrupt::default())?;
    let run = config.run.name.clone();
    let mut learner = Learner::new(
        config,
        Box::new(NoSink),
        Box::new(InMemory::default()),
        Box::new(BTreeMap::new),
    )?
    .restore(false)?;
    let mut child = Command::new(actors_exe)
        .args([ACTORS_SUBCOMMAND, "--connect", &endpoint, "--run", &run])
        .args(["--kind", case.kind.name()])
        .args(["--count", &case.actors.to_string()])
        .args(["--steps-per-segment", &case.steps_per_segment.to_string()])
        .args(["--segment-batch-ms", &batching.0])
        .args(["--segment-batch-kib", &batching.1])
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into()),
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| CapacityError::io(&format!("starting {}", actors_exe.display()), e))?;
    let stdout = child.stdout.take();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut out) = stdout {
            let _ = out.read_to_string(&mut text);
        }
        text
    });
    let child = Owned(child);
    let (actors_pid, router_pid) = (child.0.id(), router.as_ref().map(|r| r.0.id()));

    let mut offered = Offered::default();
    let mut warm_up = MainTimes::default();
    epoch(&mut learner, &mut actors, 0, &mut offered, &mut warm_up)?;
    let mut times = MainTimes::default();
    let before = Reading::now(&actors, actors_pid, router_pid);
    let mut published = BTreeMap::new();
    let mut version = 1;
    while before.at.elapsed().as_secs_f64() < seconds {
        let at = epoch(&mut learner, &mut actors, version, &mut offered, &mut times)?;
        published.insert(version, at);
        version += 1;
    }
    let after = Reading::now(&actors, actors_pid, router_pid);
    actors.stop("the bench is over")?;
    let rejected = actors.rejected();
    let summary = learner.finish("the bench is over", true, rejected)?;
    let report = wait_for_actors(child, reader)?;
    if let Err(e) = actors.into_bus().close_blocking() {
        tracing::warn!("closing the learner's bus: {e}");
    }
    drop(router);
    let window = Window {
        before,
        after,
        times,
        published,
    };
    Ok(Measurement::assemble(
        case, &window, &report, &offered.0, &summary, rejected,
    ))
}

/// A temporary folder of this process (zenohd's configuration), removed when dropped.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn tempfile_dir() -> Result<TempDir, CapacityError> {
    let path = std::env::temp_dir().join(format!(
        "cabc-bench-bus-{}-{}",
        std::process::id(),
        unix_us()
    ));
    std::fs::create_dir_all(&path).map_err(|e| CapacityError::io("a temporary folder", e))?;
    Ok(TempDir(path))
}

/// The actors' report, once their process ended (it ends on the learner's Stop).
fn wait_for_actors(
    mut child: Owned,
    reader: std::thread::JoinHandle<String>,
) -> Result<ActorsReport, CapacityError> {
    let until = Instant::now() + Duration::from_secs(60);
    let status = loop {
        match child.0.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if Instant::now() < until => std::thread::sleep(Duration::from_millis(20)),
            Ok(None) => {
                return Err(CapacityError::Setup(
                    "the actors did not stop within 60 s of the Stop".into(),
                ))
            }
            Err(e) => return Err(CapacityError::io("waiting for the actors", e)),
        }
    };
    let text = reader
        .join()
        .map_err(|_| CapacityError::Setup("reading the actors' report".into()))?;
    if !status.success() {
        return Err(CapacityError::Setup(format!(
            "the actors' process ended with {status}"
        )));
    }
    serde_json::from_str(text.trim())
        .map_err(|e| CapacityError::Setup(format!("the actors' report: {e}")))
}
