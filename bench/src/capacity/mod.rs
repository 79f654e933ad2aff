//! `cabc bench-bus` (issue 73, item 3): one learner's capacity, measured. N synthetic actors (a child process of the
//! same binary, [`actors`]) publish real-shaped segments at full speed through the real intake: a zenoh session per
//! actor, the codec, the outbox and its receipts, the learner's [`cabc_bus::rollouts::ZenohActors`] (sender check,
//! epoch gate, acknowledgement) and the real `Learner` (ledger, replay); the learner publishes its real policy each
//! epoch, and the time until all N actors hold it is the broadcast time ([`learner`]).
//!
//! For each kind (`state`: V-B's steps, `v-b`; `camera`: 64x64 images, `v-a-cpu`), router (`embedded`: the learner
//! listens, as deploy/run-local.sh; `zenohd`: a standalone router, both sides its clients) and N, it reports steps/s
//! and MB/s absorbed, the learner process's CPU per step (getrusage of this process: the actors and the router run
//! in others), where that CPU goes (the subscription's decode and receipts, the learner's store and partition, the
//! rest of zenoh), the receipts' round trip at the actors, the broadcast time, and the books: every segment
//! published is stored once or counted as a copy, and any difference is reported (the command then fails).

pub mod actors;
pub mod cpu;
pub mod learner;

use cabc_bus::BusError;
use cabc_learning::learner::LearnerError;
use cabc_learning::summary::Summary;
use cabc_proto::config::ConfigError;
use cabc_proto::ports::PortError;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;

/// Why a measurement could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CapacityError {
    #[error("the kind's preset: {0}")]
    Config(#[from] ConfigError),
    #[error("the bus: {0}")]
    Bus(#[from] BusError),
    #[error("the actors' port: {0}")]
    Port(#[from] PortError),
    #[error("the learner: {0}")]
    Learner(#[from] LearnerError),
    #[error("{what}: {source}")]
    Io {
        what: String,
        source: std::io::Error,
    },
    #[error("{0}")]
    Setup(String),
}

impl CapacityError {
    fn io(what: &str, source: std::io::Error) -> Self {
        CapacityError::Io {
            what: what.to_string(),
            source,
        }
    }
}

/// What the actors publish.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// V-B's full-state steps (preset `v-b`).
    State,
    /// Camera steps with a 64x64 RGB image (preset `v-a-cpu`).
    Camera,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::State => "state",
            Kind::Camera => "camera",
        }
    }

    /// The preset whose learner (replay, policy) takes the steps.
    pub fn preset(self) -> &'static str {
        match self {
            Kind::State => "v-b",
            Kind::Camera => "v-a-cpu",
        }
    }

    /// Steps of a measured epoch, all actors together, unless `--epoch-steps`: long beside an epoch's turn (the
    /// markers, the publication), at most a few hundred MB of D_new.
    fn default_epoch_steps(self) -> u64 {
        match self {
            Kind::State => 1 << 18,
            Kind::Camera => 1 << 13,
        }
    }
}

/// Where the learner's bus is routed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Router {
    /// The learner's session listens and routes (deploy/run-local.sh); actors are its clients.
    Embedded,
    /// A standalone zenohd (deploy/SCALE-OUT.md §2); the learner and the actors are its clients.
    Zenohd,
}

/// `cabc bench-bus`'s options.
#[derive(Clone, Debug, clap::Args)]
pub struct BusBenchOptions {
    /// Numbers of actors, each measured.
    #[arg(long, value_delimiter = ',', default_value = "1,8,64")]
    pub actors: Vec<usize>,
    /// Measured seconds of each case (after a warm-up epoch).
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// state, camera or both.
    #[arg(long, default_value = "both", value_parser = ["state", "camera", "both"])]
    pub kind: String,
    /// embedded, zenohd or both.
    #[arg(long, default_value = "both", value_parser = ["embedded", "zenohd", "both"])]
    pub router: String,
    /// Steps of each segment (default: V-B's runs' mean, 9: laps of ~50 steps among many short failures and
    /// one-step expert failures; docs/speed/issue-73/capacity.md).
    #[arg(long, default_value_t = 9)]
    pub steps_per_segment: usize,
    /// How long each actor gathers its segments into one message, in milliseconds (default: the kind's preset's
    /// `bus.segment_batch_ms`; 0: a message a segment, as before issue 73's batching).
    #[arg(long)]
    pub segment_batch_ms: Option<f64>,
    /// Steps of a measured epoch, all actors together (default: 262,144 state, 8,192 camera steps).
    #[arg(long)]
    pub epoch_steps: Option<u64>,
    /// Times each case is measured; the table gives the medians.
    #[arg(long, default_value_t = 1)]
    pub repeats: usize,
    /// Also write every figure as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The zenohd binary (default: beside this one, then on PATH).
    #[arg(long)]
    pub zenohd: Option<PathBuf>,
}

/// One case to measure.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Case {
    pub kind: Kind,
    pub router: Router,
    pub actors: usize,
    pub steps_per_segment: usize,
    pub epoch_steps: u64,
    /// `bus.segment_batch_ms` when not the preset's.
    #[serde(default)]
    pub segment_batch_ms: Option<f64>,
}

/// Microseconds of CPU (or of the callback's wall, for the subscription's stages) per step absorbed.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Stages {
    /// The subscription callback (a zenoh thread): the payload made contiguous, decoded, validated, held to its key.
    pub decode_us: f64,
    /// The callback putting the receipt.
    pub ack_us: f64,
    /// The callback handing the message to the gathering's queue, waiting for room when it is full (backpressure).
    pub queue_us: f64,
    /// The learner's `store` (version check, the replay's image check, the ledger, D_new).
    pub store_us: f64,
    /// The learner's `partition` (the replay's stores, the ledger's counts, the provenance).
    pub partition_us: f64,
    /// The committed receipts after the epoch (the real learner's, after its checkpoint): the actors forget them.
    pub commit_us: f64,
    /// The policy's bytes, encoding and publishing them, each epoch.
    pub publish_us: f64,
    /// The learner's main thread (the gathering: the gate, the queue, store, partition, publish).
    pub main_thread_us: f64,
    /// Every other thread of the learner: zenoh's (the links, the routing, the callback's stages above).
    pub other_threads_us: f64,
}

/// The policy's broadcasts of the measured epochs: from the learner's publication until the last of the N actors
/// has it decoded.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Broadcast {
    pub weights_bytes: usize,
    pub epochs: usize,
    /// Each epoch's time until all N held it (ms).
    pub all_ms: Vec<f64>,
    pub median_ms: Option<f64>,
    pub max_ms: Option<f64>,
    /// The median over the epochs of the time until the first actor held it (ms): the rest of `all_ms` is the
    /// spread over the N, the actors that have it already publishing meanwhile.
    pub first_median_ms: Option<f64>,
    /// Epochs that some actor did not report receiving.
    pub incomplete: usize,
}

/// The books: what the actors published against what the learner stored.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Books {
    pub published_segments: u64,
    pub published_steps: u64,
    pub stored_segments: u64,
    pub stored_steps: u64,
    /// Copies the ledger dropped (a segment published again before its receipt came).
    pub duplicates: u64,
    /// Segments the learner refused (`segments_not_stored`).
    pub not_stored: u64,
    /// Segments published and never offered to the learner, by (actor, seq).
    pub missing_segments: u64,
    /// Segments the actors' outboxes dropped, and those they published again.
    pub outbox_lost: u64,
    pub resent: u64,
    /// Messages the learner's bus refused.
    pub rejected: u64,
}

impl Books {
    /// Segments lost: missing, refused, dropped by an outbox, or stored counts short of the published.
    pub fn lost(&self) -> u64 {
        self.missing_segments
            + self.not_stored
            + self.outbox_lost
            + self.published_segments.saturating_sub(self.stored_segments)
            + self.published_steps.saturating_sub(self.stored_steps)
    }
}

/// One measurement of one case.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Measurement {
    pub case: Case,
    pub seconds: f64,
    pub epochs: usize,
    pub steps: u64,
    pub segments: u64,
    /// Segments per message of `traj/*` (markers counted as messages): the actors' batches.
    #[serde(default)]
    pub segments_per_message: f64,
    /// Payload bytes of `traj/*` the learner took.
    pub bytes: u64,
    pub steps_per_s: f64,
    pub mb_per_s: f64,
    /// The learner process's CPU seconds (getrusage, all its threads) and per step.
    pub learner_cpu_s: f64,
    pub learner_cpu_us_per_step: f64,
    /// Of the learner's CPU, the share of one core it used (CPU seconds / wall seconds).
    pub learner_cores: f64,
    /// One learner core's capacity at this cost: 1e6 / µs per step.
    pub steps_per_learner_core_s: f64,
    pub stages: Stages,
    /// CPU seconds by thread name (digits dropped), the learner's live threads.
    pub threads_cpu_s: BTreeMap<String, f64>,
    /// The actors' process and the standalone router's CPU seconds.
    pub actors_cpu_s: Option<f64>,
    pub router_cpu_s: Option<f64>,
    pub receipt_rtt_ms_p50: Option<f64>,
    pub receipt_rtt_ms_p99: Option<f64>,
    pub broadcast: Broadcast,
    pub books: Books,
}

impl Measurement {
    fn assemble(
        case: &Case,
        window: &learner::Window,
        report: &actors::ActorsReport,
        offered: &HashMap<String, Vec<u32>>,
        summary: &Summary,
        rejected: u64,
    ) -> Measurement {
        let (before, after) = (&window.before, &window.after);
        let seconds = (after.at - before.at).as_secs_f64();
        let steps = window.times.steps;
        let per_step = |s: f64| s * 1e6 / steps.max(1) as f64;
        let receipts = after.receipts.since(&before.receipts);
        let learner_cpu_s = (after.process - before.process).as_secs_f64();
        let main_s = (after.main - before.main).as_secs_f64();
        let diff = |a: Option<std::time::Duration>, b: Option<std::time::Duration>| {
            Some((a? - b?).as_secs_f64())
        };
        let stages = Stages {
            decode_us: per_step(receipts.decode_ns as f64 * 1e-9),
            ack_us: per_step(receipts.ack_ns as f64 * 1e-9),
            queue_us: per_step(receipts.queue_ns as f64 * 1e-9),
            store_us: per_step(window.times.store.as_secs_f64()),
            partition_us: per_step(window.times.partition.as_secs_f64()),
            commit_us: per_step(window.times.commit.as_secs_f64()),
            publish_us: per_step(window.times.publish.as_secs_f64()),
            main_thread_us: per_step(main_s),
            other_threads_us: per_step(learner_cpu_s - main_s),
        };
        let learner_cpu_us_per_step = per_step(learner_cpu_s);
        Measurement {
            case: case.clone(),
            seconds,
            epochs: window.published.len(),
            steps,
            segments: window.times.segments,
            segments_per_message: window.times.segments as f64 / receipts.messages.max(1) as f64,
            bytes: receipts.bytes,
            steps_per_s: steps as f64 / seconds,
            mb_per_s: receipts.bytes as f64 / seconds / 1e6,
            learner_cpu_s,
            learner_cpu_us_per_step,
            learner_cores: learner_cpu_s / seconds,
            steps_per_learner_core_s: 1e6 / learner_cpu_us_per_step.max(1e-9),
            stages,
            threads_cpu_s: cpu::since(&after.threads, &before.threads),
            actors_cpu_s: diff(after.actors, before.actors),
            router_cpu_s: diff(after.router, before.router),
            receipt_rtt_ms_p50: report.receipt_rtt_ms_p50,
            receipt_rtt_ms_p99: report.receipt_rtt_ms_p99,
            broadcast: broadcast(&window.published, report),
            books: books(report, offered, summary, rejected),
        }
    }
}

/// The broadcasts of the versions `published` (version -> its publication, µs since the Unix epoch).
fn broadcast(published: &BTreeMap<u64, u64>, report: &actors::ActorsReport) -> Broadcast {
    let mut all_ms = Vec::new();
    let mut first_ms = Vec::new();
    let mut incomplete = 0;
    let mut weights_bytes = 0;
    for (&version, &at) in published {
        let receipts: Vec<&actors::Receipt> = report
            .actors
            .iter()
            .filter_map(|a| a.receipts.iter().find(|r| r.version == version))
            .collect();
        if receipts.len() < report.actors.len() || receipts.is_empty() {
            incomplete += 1;
            continue;
        }
        weights_bytes = receipts[0].weights_bytes;
        let last = receipts.iter().map(|r| r.unix_us).max().unwrap_or(at);
        let first = receipts.iter().map(|r| r.unix_us).min().unwrap_or(at);
        all_ms.push(last.saturating_sub(at) as f64 / 1e3);
        first_ms.push(first.saturating_sub(at) as f64 / 1e3);
    }
    let mut sorted = all_ms.clone();
    Broadcast {
        weights_bytes,
        epochs: published.len(),
        median_ms: cpu::quantile(&mut sorted, 0.5),
        max_ms: sorted.last().copied(),
        first_median_ms: cpu::quantile(&mut first_ms, 0.5),
        all_ms,
        incomplete,
    }
}

/// The books of a measurement: each actor's published seqs 0 .. segments against what was offered to the learner.
fn books(
    report: &actors::ActorsReport,
    offered: &HashMap<String, Vec<u32>>,
    summary: &Summary,
    rejected: u64,
) -> Books {
    let mut books = Books {
        stored_segments: summary.segments_stored,
        stored_steps: summary.steps_stored,
        duplicates: summary.duplicate_segments,
        not_stored: summary.segments_not_stored,
        rejected,
        ..Books::default()
    };
    for actor in &report.actors {
        books.published_segments += actor.segments;
        books.published_steps += actor.steps;
        books.outbox_lost += actor.outbox_lost;
        books.resent += actor.resent;
        let seqs = offered.get(&actor.id).map_or(&[][..], Vec::as_slice);
        books.missing_segments += (0..actor.segments as usize)
            .filter(|&seq| seqs.get(seq).is_none_or(|&n| n == 0))
            .count() as u64;
    }
    books
}

/// The cases of `options`, in order: kind, router, N.
pub fn cases(options: &BusBenchOptions) -> Vec<Case> {
    let kinds: &[Kind] = match options.kind.as_str() {
        "state" => &[Kind::State],
        "camera" => &[Kind::Camera],
        _ => &[Kind::State, Kind::Camera],
    };
    let routers: &[Router] = match options.router.as_str() {
        "embedded" => &[Router::Embedded],
        "zenohd" => &[Router::Zenohd],
        _ => &[Router::Embedded, Router::Zenohd],
    };
    let mut cases = Vec::new();
    for &kind in kinds {
        for &router in routers {
            for &actors in &options.actors {
                cases.push(Case {
                    kind,
                    router,
                    actors: actors.max(1),
                    steps_per_segment: options.steps_per_segment.max(1),
                    segment_batch_ms: options.segment_batch_ms,
                    epoch_steps: options
                        .epoch_steps
                        .unwrap_or_else(|| kind.default_epoch_steps()),
                });
            }
        }
    }
    cases
}

/// The zenohd binary: `--zenohd`, else beside this executable, else `zenohd` on PATH.
fn zenohd_binary(options: &BusBenchOptions) -> PathBuf {
    if let Some(path) = &options.zenohd {
        return path.clone();
    }
    std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.join("zenohd")))
        .filter(|p| p.exists())
        .unwrap_or_else(|| PathBuf::from("zenohd"))
}

/// A case's figures over its repeats: the medians.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub case: Case,
    pub repeats: usize,
    pub steps_per_s: f64,
    pub mb_per_s: f64,
    pub learner_cpu_us_per_step: f64,
    pub learner_cores: f64,
    pub steps_per_learner_core_s: f64,
    #[serde(default)]
    pub segments_per_message: f64,
    pub decode_us: f64,
    pub ack_us: f64,
    pub store_us: f64,
    pub partition_us: f64,
    pub commit_us: f64,
    pub main_thread_us: f64,
    pub other_threads_us: f64,
    pub receipt_rtt_ms_p50: Option<f64>,
    pub receipt_rtt_ms_p99: Option<f64>,
    pub broadcast_ms: Option<f64>,
    pub broadcast_max_ms: Option<f64>,
    pub weights_bytes: usize,
    /// Segments lost, all repeats together (0: nothing lost).
    pub lost: u64,
    pub duplicates: u64,
}

fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.collect();
    cpu::quantile(&mut v, 0.5).unwrap_or(0.0)
}

fn median_some(values: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let mut v: Vec<f64> = values.flatten().collect();
    cpu::quantile(&mut v, 0.5)
}

impl Row {
    fn of(runs: &[Measurement]) -> Option<Row> {
        let first = runs.first()?;
        let m = |f: fn(&Measurement) -> f64| median(runs.iter().map(f));
        Some(Row {
            case: first.case.clone(),
            repeats: runs.len(),
            steps_per_s: m(|r| r.steps_per_s),
            mb_per_s: m(|r| r.mb_per_s),
            learner_cpu_us_per_step: m(|r| r.learner_cpu_us_per_step),
            learner_cores: m(|r| r.learner_cores),
            steps_per_learner_core_s: m(|r| r.steps_per_learner_core_s),
            segments_per_message: m(|r| r.segments_per_message),
            decode_us: m(|r| r.stages.decode_us),
            ack_us: m(|r| r.stages.ack_us),
            store_us: m(|r| r.stages.store_us),
            partition_us: m(|r| r.stages.partition_us),
            commit_us: m(|r| r.stages.commit_us),
            main_thread_us: m(|r| r.stages.main_thread_us),
            other_threads_us: m(|r| r.stages.other_threads_us),
            receipt_rtt_ms_p50: median_some(runs.iter().map(|r| r.receipt_rtt_ms_p50)),
            receipt_rtt_ms_p99: median_some(runs.iter().map(|r| r.receipt_rtt_ms_p99)),
            broadcast_ms: median_some(runs.iter().map(|r| r.broadcast.median_ms)),
            broadcast_max_ms: runs
                .iter()
                .filter_map(|r| r.broadcast.max_ms)
                .max_by(f64::total_cmp),
            weights_bytes: first.broadcast.weights_bytes,
            lost: runs.iter().map(|r| r.books.lost()).sum(),
            duplicates: runs.iter().map(|r| r.books.duplicates).sum(),
        })
    }
}

/// Everything `cabc bench-bus` measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    pub rows: Vec<Row>,
    pub measurements: Vec<Measurement>,
}

impl Report {
    /// Segments lost over every measurement.
    pub fn lost(&self) -> u64 {
        self.rows.iter().map(|r| r.lost).sum()
    }

    /// The table (Markdown) of the rows.
    pub fn table(&self) -> String {
        let mut out = String::from(
            "| kind | router | N | steps/s | MB/s | learner CPU µs/step | learner cores | steps/s per learner core \
             | segments / message | decode µs | ack µs | store µs | partition µs | commit µs | main thread µs | other threads µs | receipt RTT p50 / p99 \
             ms | broadcast ms (median / max) | policy bytes | lost | copies |\n",
        );
        out.push_str(&format!("|{}\n", "---|".repeat(21)));
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
        for r in &self.rows {
            out.push_str(&format!(
                "| {} | {} | {} | {:.0} | {:.1} | {:.2} | {:.2} | {:.0} | {:.1} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} \
                 | {:.2} | {} / {} | {} / {} | {} | {} | {} |\n",
                r.case.kind.name(),
                match r.case.router {
                    Router::Embedded => "embedded",
                    Router::Zenohd => "zenohd",
                },
                r.case.actors,
                r.steps_per_s,
                r.mb_per_s,
                r.learner_cpu_us_per_step,
                r.learner_cores,
                r.steps_per_learner_core_s,
                r.segments_per_message,
                r.decode_us,
                r.ack_us,
                r.store_us,
                r.partition_us,
                r.commit_us,
                r.main_thread_us,
                r.other_threads_us,
                ms(r.receipt_rtt_ms_p50),
                ms(r.receipt_rtt_ms_p99),
                ms(r.broadcast_ms),
                ms(r.broadcast_max_ms),
                r.weights_bytes,
                r.lost,
                r.duplicates,
            ));
        }
        out
    }
}

/// `cabc bench-bus`: every case of `options`, `repeats` times each; the actors run as `actors_exe
/// bench-bus-actors ...` (the calling binary).
pub fn run(
    options: &BusBenchOptions,
    actors_exe: &std::path::Path,
) -> Result<Report, CapacityError> {
    let zenohd = zenohd_binary(options);
    let mut rows = Vec::new();
    let mut measurements = Vec::new();
    for case in cases(options) {
        let mut runs = Vec::new();
        for repeat in 0..options.repeats.max(1) {
            tracing::info!(
                kind = case.kind.name(),
                router = ?case.router,
                actors = case.actors,
                repeat,
                "measuring"
            );
            let m = learner::measure(&case, options.seconds, &zenohd, actors_exe)?;
            tracing::info!(
                steps_per_s = m.steps_per_s as u64,
                cpu_us_per_step = m.learner_cpu_us_per_step,
                lost = m.books.lost(),
                "measured"
            );
            runs.push(m);
        }
        rows.extend(Row::of(&runs));
        measurements.extend(runs);
    }
    Ok(Report { rows, measurements })
}
