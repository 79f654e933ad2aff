//! `actor`: collects trajectory segments for the learner (or, with `--eval`, evaluates each new policy).
//!
//! It fetches the latest policy on start (the learner's queryable), follows updates, asks the expert server for a
//! batch of labels per step (waiting and retrying while no server answers), and publishes segments reliably on
//! `cabc/<run>/traj/<id>`, then the epoch's "done" marker.

use anyhow::{anyhow, Context, Result};
use cabc_actor::collect::{Collector, PolicyInput};
use cabc_actor::evaluate::evaluate;
use cabc_bus::{decode_sample, encoding_of, Bus, Role};
use cabc_models::policy::{Observation, Policy};
use cabc_proto::codec;
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{
    EpochDone, ExpertAnswer, ExpertQuery, ExpertReply, ExpertRequest, PolicyUpdate, Segment, Stop,
    TrajMessage,
};
use clap::Parser;
use serde_json::json;
use std::time::{Duration, Instant};
use tch::Device;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

#[derive(Parser)]
#[command(
    name = "actor",
    version,
    about = "The cabc actor: collects segments under the expert/policy mixture"
)]
struct Cli {
    /// Run configuration: a preset (v-a, v-b, v-c, smoke) or a TOML file.
    #[arg(long, short, default_value = "v-b")]
    config: String,
    /// This actor's name (a key chunk: letters, digits, '-', '_', '.').
    #[arg(long, default_value = "actor-0")]
    id: String,
    /// Index of this actor's random streams (default: the number at the end of --id, else 0).
    #[arg(long)]
    index: Option<u64>,
    /// Evaluate each new policy from the fixed spawn instead of collecting.
    #[arg(long)]
    eval: bool,
    /// Zenoh endpoints to connect to, overriding the configuration's `bus.connect`.
    #[arg(long)]
    connect: Vec<String>,
}

fn main() -> Result<()> {
    cabc_proto::telemetry::init();
    let cli = Cli::parse();
    let mut config = RunConfig::load(&cli.config)
        .with_context(|| format!("loading configuration {}", cli.config))?;
    cabc_proto::keys::check_chunk(&cli.id)?;
    if !cli.connect.is_empty() {
        config.bus.connect = cli.connect.clone();
    }
    // One inference thread: actors are many, cores are few.
    tch::set_num_threads(1);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(run(config, cli))
}

/// What the actor waits for between epochs.
enum Next {
    Policy(Box<PolicyUpdate>),
    Stop(String),
}

struct Actor {
    config: RunConfig,
    id: String,
    bus: Bus,
    policy_sub: Subscriber<FifoChannelHandler<Sample>>,
    control_sub: Subscriber<FifoChannelHandler<Sample>>,
    request_id: u64,
    /// Seconds spent waiting on the expert, and collecting, since start.
    expert_wait: Duration,
    collecting: Duration,
    /// Time on the wire: expert round trips less the server's batch time, plus publishing segments.
    transport: Duration,
    /// Broadcast latencies of policy updates received by subscription (ms).
    policy_latency_ms: Vec<f64>,
    steps: u64,
    versions: u64,
}

async fn run(config: RunConfig, cli: Cli) -> Result<()> {
    let keys = Keys::new(&config.run.name)?;
    let component = if cli.eval {
        format!("eval/{}", cli.id)
    } else {
        format!("actor/{}", cli.id)
    };
    let bus = Bus::connect(&config.bus, Role::Connect, keys.clone(), &component)
        .await
        .context("joining the bus")?;
    let policy_sub = bus
        .session
        .declare_subscriber(keys.policy())
        .await
        .map_err(|e| anyhow!("subscribing to {}: {e}", keys.policy()))?;
    let control_sub = bus
        .session
        .declare_subscriber(keys.control())
        .await
        .map_err(|e| anyhow!("subscribing to {}: {e}", keys.control()))?;
    tracing::info!(component, run = keys.run(), "actor started");
    let index = cli.index.unwrap_or_else(|| trailing_number(&cli.id));
    let mut actor = Actor {
        config,
        id: cli.id.clone(),
        bus,
        policy_sub,
        control_sub,
        request_id: 0,
        expert_wait: Duration::ZERO,
        collecting: Duration::ZERO,
        transport: Duration::ZERO,
        policy_latency_ms: Vec::new(),
        steps: 0,
        versions: 0,
    };
    let mut collector = Collector::new(&cli.id, index, &actor.config);
    let mut last_update: Option<PolicyUpdate> = None;
    let mut pending = actor
        .fetch_latest_policy()
        .await
        .map(|u| Next::Policy(Box::new(u)));
    loop {
        let next = match pending.take() {
            Some(next) => next,
            None => actor.wait_next().await?,
        };
        let update = match next {
            Next::Stop(reason) => {
                tracing::info!("stop: {reason}");
                break;
            }
            Next::Policy(update) => *update,
        };
        let policy = match Policy::from_bytes(&update.weights, Device::Cpu) {
            Ok(p) => p,
            Err(e) => {
                tracing::error!(version = update.version, "refusing policy weights: {e}");
                continue;
            }
        };
        actor.versions += 1;
        if cli.eval {
            let started = Instant::now();
            let report = evaluate(&actor.id, update.version, &actor.config, |input| {
                act(&policy, input)
            })?;
            tracing::info!(
                version = update.version,
                laps = report.laps,
                end = %report.end_reason,
                secs = started.elapsed().as_secs_f64(),
                "evaluated"
            );
            let key = actor.bus.keys.eval(&actor.id);
            actor.bus.put(&key, &report).await?;
        } else {
            pending = actor.collect(&mut collector, &update, &policy).await?;
        }
        actor.publish_metrics(&update).await;
        last_update = Some(update);
    }
    if let Some(update) = &last_update {
        tracing::info!("final metrics: {}", actor.metrics(update));
    }
    actor.bus.close().await?;
    Ok(())
}

fn trailing_number(id: &str) -> u64 {
    let digits: String = id
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect();
    digits
        .chars()
        .rev()
        .collect::<String>()
        .parse()
        .unwrap_or(0)
}

fn act(policy: &Policy, input: &PolicyInput) -> Result<Vec<[f32; 2]>> {
    let observations: Vec<Observation> = if input.images.is_empty() {
        input.states.iter().map(Observation::State).collect()
    } else {
        input
            .states
            .iter()
            .zip(input.images)
            .map(|(s, image)| Observation::Camera {
                image,
                velocity: [s[0], s[1], s[2]],
            })
            .collect()
    };
    Ok(policy.act(&observations)?)
}

impl Actor {
    /// The learner's latest policy, if it is up (late joiners start at once).
    async fn fetch_latest_policy(&self) -> Option<PolicyUpdate> {
        let key = self.bus.keys.policy();
        let replies = self
            .bus
            .session
            .get(&key)
            .timeout(Duration::from_secs(3))
            .await
            .ok()?;
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                let bytes = sample.payload().to_bytes();
                if let Some(update) = decode_sample::<PolicyUpdate>(&key, &bytes, &self.bus.rejects)
                {
                    return Some(update);
                }
            }
        }
        None
    }

    /// Blocks until a policy update or a stop arrives; a burst of updates yields the newest.
    async fn wait_next(&mut self) -> Result<Next> {
        loop {
            tokio::select! {
                sample = self.policy_sub.recv_async() => {
                    let sample = sample.map_err(|e| anyhow!("policy subscription closed: {e}"))?;
                    if let Some(mut update) = self.decode_policy(&sample) {
                        while let Ok(Some(newer)) = self.policy_sub.try_recv() {
                            if let Some(newer) = self.decode_policy(&newer) {
                                update = newer;
                            }
                        }
                        return Ok(Next::Policy(Box::new(update)));
                    }
                }
                sample = self.control_sub.recv_async() => {
                    let sample = sample.map_err(|e| anyhow!("control subscription closed: {e}"))?;
                    let bytes = sample.payload().to_bytes();
                    if let Some(stop) = decode_sample::<Stop>(sample.key_expr().as_str(), &bytes, &self.bus.rejects) {
                        return Ok(Next::Stop(stop.reason));
                    }
                }
                _ = tokio::signal::ctrl_c() => return Ok(Next::Stop("interrupted".into())),
            }
        }
    }

    fn decode_policy(&mut self, sample: &Sample) -> Option<PolicyUpdate> {
        let bytes = sample.payload().to_bytes();
        let update =
            decode_sample::<PolicyUpdate>(sample.key_expr().as_str(), &bytes, &self.bus.rejects)?;
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        self.policy_latency_ms
            .push(now.saturating_sub(update.published_unix_ms) as f64);
        Some(update)
    }

    /// A stop that arrived meanwhile.
    fn stop_requested(&mut self) -> Option<Next> {
        while let Ok(Some(sample)) = self.control_sub.try_recv() {
            let bytes = sample.payload().to_bytes();
            if let Some(stop) =
                decode_sample::<Stop>(sample.key_expr().as_str(), &bytes, &self.bus.rejects)
            {
                return Some(Next::Stop(stop.reason));
            }
        }
        None
    }

    /// A newer policy or a stop that arrived during collection (the learner moved on without us).
    fn interrupted(&mut self) -> Option<Next> {
        if let Some(stop) = self.stop_requested() {
            return Some(stop);
        }
        let mut newest = None;
        while let Ok(Some(sample)) = self.policy_sub.try_recv() {
            if let Some(update) = self.decode_policy(&sample) {
                newest = Some(Next::Policy(Box::new(update)));
            }
        }
        newest
    }

    /// Collects this actor's share of an epoch. Returns a newer policy or a stop if one interrupted the epoch.
    async fn collect(
        &mut self,
        collector: &mut Collector,
        update: &PolicyUpdate,
        policy: &Policy,
    ) -> Result<Option<Next>> {
        let started = Instant::now();
        let budget = update.steps_per_actor;
        let first_seq = collector.segments_cut();
        collector.begin_epoch();
        let mut out: Vec<Segment> = Vec::new();
        let mut interrupted = None;
        let mut published_steps = 0u64;
        while collector.taken() < budget {
            if let Some(next) = self.interrupted() {
                interrupted = Some(next);
                break;
            }
            let active = collector.active(budget);
            let queries = collector.queries(active);
            let answers = match self.relabel(queries).await {
                Ok(answers) => answers,
                Err(stop) => {
                    interrupted = Some(stop);
                    break;
                }
            };
            let input = collector.observations(active);
            let actions = act(policy, &input)?;
            collector.step(&answers, &actions, update.beta, update.version, &mut out);
            published_steps += self.publish(&mut out).await?;
        }
        collector.end_epoch(update.version, &mut out);
        published_steps += self.publish(&mut out).await?;
        let done = EpochDone {
            actor: self.id.clone(),
            version: update.version,
            segments: collector.segments_cut() - first_seq,
            steps: published_steps,
        };
        let key = self.bus.keys.traj(&self.id);
        self.bus.put(&key, &TrajMessage::EpochDone(done)).await?;
        self.steps += published_steps;
        self.collecting += started.elapsed();
        tracing::info!(
            version = update.version,
            steps = published_steps,
            secs = started.elapsed().as_secs_f64(),
            "epoch collected"
        );
        Ok(interrupted)
    }

    async fn publish(&mut self, out: &mut Vec<Segment>) -> Result<u64> {
        let started = Instant::now();
        let key = self.bus.keys.traj(&self.id);
        let mut steps = 0;
        for segment in out.drain(..) {
            steps += segment.steps.len() as u64;
            self.bus.put(&key, &TrajMessage::Segment(segment)).await?;
        }
        self.transport += started.elapsed();
        Ok(steps)
    }

    /// Asks the expert server for a batch of labels, waiting and retrying while none answers; gives up only for a
    /// stop (returned as the error).
    async fn relabel(
        &mut self,
        queries: Vec<ExpertQuery>,
    ) -> std::result::Result<Vec<ExpertAnswer>, Next> {
        let key = self.bus.keys.expert(self.config.expert.kind.as_str());
        let started = Instant::now();
        self.request_id += 1;
        let n = queries.len();
        let request = ExpertRequest {
            request_id: self.request_id,
            queries,
        };
        let payload = codec::encode(&request);
        let timeout = Duration::from_secs_f64(self.config.expert.timeout_s);
        let mut attempt = 0u32;
        loop {
            attempt += 1;
            match self.ask(&key, &payload, timeout).await {
                Ok(reply) if reply.request_id == request.request_id && reply.answers.len() == n => {
                    let waited = started.elapsed();
                    self.expert_wait += waited;
                    self.transport +=
                        waited.saturating_sub(Duration::from_micros(reply.batch_time_us));
                    if attempt > 1 {
                        tracing::info!(%key, attempt, "expert answered again");
                    }
                    return Ok(reply.answers);
                }
                Ok(reply) => tracing::warn!(
                    %key,
                    "expert reply does not match the request ({} answers for {n} queries, id {} for {})",
                    reply.answers.len(),
                    reply.request_id,
                    request.request_id
                ),
                Err(why) => {
                    if attempt == 1 || attempt.is_multiple_of(10) {
                        tracing::warn!(%key, attempt, "waiting for an expert server: {why}");
                    }
                }
            }
            if let Some(stop) = self.stop_requested() {
                return Err(stop);
            }
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
    }

    async fn ask(
        &self,
        key: &str,
        payload: &[u8],
        timeout: Duration,
    ) -> std::result::Result<ExpertReply, String> {
        let replies = self
            .bus
            .session
            .get(key)
            .payload(payload.to_vec())
            .encoding(encoding_of::<ExpertRequest>())
            .timeout(timeout)
            .await
            .map_err(|e| e.to_string())?;
        match replies.recv_async().await {
            Ok(reply) => match reply.result() {
                Ok(sample) => {
                    let bytes = sample.payload().to_bytes();
                    codec::decode::<ExpertReply>(&bytes).map_err(|e| e.to_string())
                }
                Err(err) => Err(format!(
                    "the server refused the request: {}",
                    String::from_utf8_lossy(&err.payload().to_bytes())
                )),
            },
            Err(_) => Err("no expert server answered".into()),
        }
    }

    async fn publish_metrics(&self, update: &PolicyUpdate) {
        let value = self.metrics(update);
        if let Err(e) = self.bus.metrics(&value).await {
            tracing::warn!("publishing metrics: {e}");
        }
    }

    /// Collection figures since start (published on `metrics/actor/<id>` after every epoch, logged at exit).
    fn metrics(&self, update: &PolicyUpdate) -> serde_json::Value {
        let collecting = self.collecting.as_secs_f64();
        json!({
            "version": update.version,
            "beta": update.beta,
            "versions_seen": self.versions,
            "steps": self.steps,
            "steps_per_s": if collecting > 0.0 { self.steps as f64 / collecting } else { 0.0 },
            "expert_wait_share": if collecting > 0.0 { self.expert_wait.as_secs_f64() / collecting } else { 0.0 },
            "transport_share": if collecting > 0.0 { self.transport.as_secs_f64() / collecting } else { 0.0 },
            "policy_latency_ms_last": self.policy_latency_ms.last(),
            "policy_latency_ms_mean": if self.policy_latency_ms.is_empty() { None } else {
                Some(self.policy_latency_ms.iter().sum::<f64>() / self.policy_latency_ms.len() as f64)
            },
            "rejected_messages": self.bus.rejects.count(),
        })
    }
}
