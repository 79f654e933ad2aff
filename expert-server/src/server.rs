//! The zenoh queryable over [`Relabeller`]: decode, answer in parallel, reply; metrics and liveliness.
//!
//! Bounded work: at most [`MAX_IN_FLIGHT`] requests are decoded, solved or waiting for the solver at once; one
//! beyond is answered "busy" at once and counted (`busy_refusals`), and the actor asks again (it retries every
//! 0.5 s). A request's batch size is read from its length prefix and checked against `expert.max_batch` before it
//! is decoded ([`codec::decode_request`]), so memory and work per request are bounded too.

use anyhow::{Context, Result};
use cabc_bus::{decode_sample, encoding_of, Bus, Query, Rejects, Role};
use cabc_expert::relabel::{BatchStats, Expert, Relabeller};
use cabc_proto::codec::{self};
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{ExpertReply, Stop};
use serde_json::json;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Requests in this server at once (decoding, solving or queued for the solver threads). An actor has two requests
/// out at a time (one per half of its environments; three around a timeout), so this serves 20 or more actors per
/// server without a refusal.
pub const MAX_IN_FLIGHT: usize = 64;

/// Admission of requests: a permit per request in flight, none beyond [`MAX_IN_FLIGHT`].
struct Admission {
    permits: Arc<Semaphore>,
}

impl Admission {
    fn new(max: usize) -> Self {
        Admission {
            permits: Arc::new(Semaphore::new(max)),
        }
    }

    /// A permit held until the request is answered; None when the server is full.
    fn admit(&self) -> Option<OwnedSemaphorePermit> {
        self.permits.clone().try_acquire_owned().ok()
    }
}

#[derive(clap::Args, Default)]
pub struct ServeArgs {
    /// Replica id (several servers may run at once).
    #[arg(long, default_value = "0")]
    pub id: String,
    /// Zenoh endpoints to connect to, overriding the configuration's `bus.connect`.
    #[arg(long)]
    connect: Vec<String>,
    /// Worker threads for solving batches (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

/// Solve-time and request counters, published as JSON on `metrics/expert-server/<id>`.
#[derive(Default)]
struct Metrics {
    requests: u64,
    items: u64,
    failures: u64,
    cold_starts: u64,
    refused: u64,
    /// Requests refused because [`MAX_IN_FLIGHT`] were already in the server.
    busy: u64,
    max_batch: usize,
    /// Recent per-item solve times (µs), for percentiles.
    recent_us: Vec<u32>,
}

impl Metrics {
    fn record(&mut self, stats: &BatchStats) {
        self.requests += 1;
        self.items += stats.items as u64;
        self.failures += stats.failures as u64;
        self.cold_starts += stats.cold_starts as u64;
        self.max_batch = self.max_batch.max(stats.items);
        self.recent_us.extend_from_slice(&stats.solve_us);
        let excess = self.recent_us.len().saturating_sub(10_000);
        self.recent_us.drain(..excess);
    }

    fn json(&mut self, rejects: u64, cache: (usize, u64)) -> serde_json::Value {
        let mut solve_ms: Vec<f64> = self
            .recent_us
            .iter()
            .map(|&us| us as f64 / 1000.0)
            .collect();
        solve_ms.sort_by(f64::total_cmp);
        let pct = |q: f64| cabc_proto::stats::percentile_sorted(&solve_ms, q);
        json!({
            "requests": self.requests,
            "items": self.items,
            "mean_batch": if self.requests > 0 { self.items as f64 / self.requests as f64 } else { 0.0 },
            "max_batch": self.max_batch,
            "failures": self.failures,
            "cold_starts": self.cold_starts,
            "refused_requests": self.refused,
            "busy_refusals": self.busy,
            "rejected_messages": rejects,
            "streams_held": cache.0,
            "streams_evicted": cache.1,
            "solve_ms_p50": pct(0.5),
            "solve_ms_p99": pct(0.99),
        })
    }
}

/// The nice value of the solver threads. Solves are long and CPU-bound; zenoh's threads (here, in the router and in
/// the actors) wake up for a message and are done in microseconds. Below them, a solve yields its core to a
/// delivery at once instead of at the end of its time slice, which on a loaded machine was most of an actor's time
/// on the wire.
const SOLVER_NICE: i32 = 10;

/// Lowers the calling thread's priority to [`SOLVER_NICE`] (Linux keeps a nice value per thread).
fn lower_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: setpriority reads no memory of ours; who = 0 is the calling thread.
        let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, SOLVER_NICE) };
        if rc != 0 {
            tracing::warn!(
                "could not lower a solver thread's priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

pub fn serve(config: RunConfig, expert: Expert, args: ServeArgs) -> Result<()> {
    let mut pool = rayon::ThreadPoolBuilder::new().start_handler(|_| lower_priority());
    if let Some(threads) = args.threads {
        pool = pool.num_threads(threads);
    }
    pool.build_global()
        .context("configuring the solver threads")?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(serve_async(config, expert, args))
}

async fn serve_async(mut config: RunConfig, expert: Expert, args: ServeArgs) -> Result<()> {
    if !args.connect.is_empty() {
        config.bus.connect = args.connect.clone();
    }
    let keys = Keys::new(&config.run.name)?;
    let component = format!("expert-server/{}", args.id);
    let kind = expert.kind();
    let max_batch = config.expert.max_batch;
    let admission = Admission::new(MAX_IN_FLIGHT);
    let relabeller = Arc::new(Relabeller::new(
        expert,
        config.expert.max_streams,
        config.expert.max_batch,
    ));
    let bus = Bus::join(&config.bus, Role::Connect, keys.clone(), &component)
        .context("joining the bus")?;
    let key = keys.expert(kind.as_str());
    let queryable = bus
        .session
        .declare_queryable(&key)
        .await
        .map_err(|e| anyhow::anyhow!("declaring the queryable {key}: {e}"))?;
    let control = bus
        .session
        .declare_subscriber(keys.control())
        .await
        .map_err(|e| anyhow::anyhow!("subscribing to {}: {e}", keys.control()))?;
    tracing::info!(%key, component, "serving {} relabelling queries", kind.as_str());

    let metrics = Arc::new(Mutex::new(Metrics::default()));
    let mut tick = tokio::time::interval(Duration::from_secs(2));
    loop {
        tokio::select! {
            query = queryable.recv_async() => {
                let Ok(query) = query else { break };
                let Some(permit) = admission.admit() else {
                    refuse_busy(query, &metrics).await;
                    continue;
                };
                let (relabeller, metrics, rejects) = (relabeller.clone(), metrics.clone(), bus.rejects.clone());
                tokio::spawn(async move {
                    let _permit = permit;
                    answer(query, &relabeller, &metrics, &rejects, max_batch).await;
                });
            }
            sample = control.recv_async() => {
                let Ok(sample) = sample else { break };
                let bytes = sample.payload().to_bytes();
                if let Some(stop) = decode_sample::<Stop>(sample.key_expr().as_str(), &bytes, &bus.rejects) {
                    tracing::info!("stop: {}", stop.reason);
                    break;
                }
            }
            _ = tick.tick() => {
                let value = metrics.lock().unwrap_or_else(|e| e.into_inner()).json(bus.rejects.count(), relabeller.cache_stats());
                if let Err(e) = bus.metrics(&value).await {
                    tracing::warn!("publishing metrics: {e}");
                }
            }
            _ = tokio::signal::ctrl_c() => {
                tracing::info!("interrupted");
                break;
            }
        }
    }
    let value = metrics
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .json(bus.rejects.count(), relabeller.cache_stats());
    tracing::info!("final metrics: {value}");
    drop(queryable);
    bus.close().await?;
    Ok(())
}

/// Replies "busy" to a query past [`MAX_IN_FLIGHT`], counting it (and warning at the first and every 100th).
async fn refuse_busy(query: Query, metrics: &Mutex<Metrics>) {
    let busy = {
        let mut m = metrics.lock().unwrap_or_else(|e| e.into_inner());
        m.busy += 1;
        m.busy
    };
    if busy == 1 || busy.is_multiple_of(100) {
        tracing::warn!(
            busy,
            "{MAX_IN_FLIGHT} requests in flight: refusing more until one is answered"
        );
    }
    if let Err(e) = query
        .reply_err("busy: too many requests in flight, ask again")
        .await
    {
        tracing::warn!("replying with an error: {e}");
    }
}

/// One relabelling query: decoded (refused when malformed), solved on the blocking pool, answered with the reply and
/// this server's residence time (what the client subtracts from its round trip to get the time on the wire).
async fn answer(
    query: Query,
    relabeller: &Arc<Relabeller>,
    metrics: &Mutex<Metrics>,
    rejects: &Rejects,
    max_batch: usize,
) {
    let received = Instant::now();
    let bytes = query
        .payload()
        .map(|p| p.to_bytes().to_vec())
        .unwrap_or_default();
    let request = match codec::decode_request(&bytes, max_batch) {
        Ok(request) => request,
        Err(e) => {
            let why = e.to_string();
            rejects.refuse(query.key_expr().as_str(), &why);
            metrics.lock().unwrap_or_else(|e| e.into_inner()).refused += 1;
            if let Err(e) = query.reply_err(format!("refused: {why}")).await {
                tracing::warn!("replying with an error: {e}");
            }
            return;
        }
    };
    let started = Instant::now();
    let solver = relabeller.clone();
    match tokio::task::spawn_blocking(move || solver.answer(&request)).await {
        Ok(Ok((mut reply, stats))) => {
            metrics
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .record(&stats);
            reply.batch_time_us = received.elapsed().as_micros() as u64;
            tracing::debug!(
                items = stats.items,
                ms = started.elapsed().as_secs_f64() * 1e3,
                "answered"
            );
            let key = query.key_expr().clone();
            if let Err(e) = query
                .reply(key, codec::encode(&reply))
                .encoding(encoding_of::<ExpertReply>())
                .await
            {
                tracing::warn!("replying: {e}");
            }
        }
        Ok(Err(refused)) => {
            metrics.lock().unwrap_or_else(|e| e.into_inner()).refused += 1;
            tracing::warn!("refused a request: {refused}");
            let _ = query.reply_err(format!("refused: {refused}")).await;
        }
        Err(e) => {
            tracing::error!("solver task failed: {e}");
            let _ = query.reply_err(format!("internal error: {e}")).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_more_than_the_maximum_requests_are_admitted() {
        let admission = Admission::new(3);
        let held: Vec<_> = (0..3).map(|_| admission.admit().unwrap()).collect();
        assert!(admission.admit().is_none());
        drop(held);
        assert!(admission.admit().is_some());
    }
}
