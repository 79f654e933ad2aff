//! The actor's expert port over zenoh: [`ZenohExpert`] sends a relabelling request on `expert/<kind>` and returns;
//! the actor simulates while it travels and then waits for what is left of the round trip, asking again every
//! 500 ms while no server answers, until a stop.

use crate::ports::{with_stats, SharedStats, Stops};
use crate::{encoding_of, interrupt::Interrupt, Bus};
use cabc_proto::codec;
use cabc_proto::messages::{ExpertAnswer, ExpertQuery, ExpertReply, ExpertRequest};
use cabc_proto::ports::{ExpertClient, Pending, PortError};
use std::time::{Duration, Instant};
use zenoh::handlers::FifoChannelHandler;
use zenoh::Wait;

/// Relabellings one client may have in flight at once (a collecting actor keeps two: its halves of environments).
const MAX_IN_FLIGHT: usize = 8;

/// A request on its way: what a retry sends again, and where its replies arrive.
struct InFlight {
    id: u64,
    payload: Vec<u8>,
    queries: usize,
    sent: Instant,
    replies: Result<FifoChannelHandler<zenoh::query::Reply>, String>,
}

/// The expert servers, over zenoh. [`ExpertClient::send`] puts a request on its way and returns; the actor simulates
/// while it travels, and [`ExpertClient::receive`] waits for what is left of the round trip.
pub struct ZenohExpert<'a> {
    bus: &'a Bus,
    key: String,
    timeout: Duration,
    request_id: u64,
    in_flight: Vec<InFlight>,
    stops: Stops,
    stats: SharedStats,
}

impl<'a> ZenohExpert<'a> {
    /// Queries `expert/<kind>` with `timeout` per attempt.
    pub fn new(
        bus: &'a Bus,
        kind: &str,
        timeout: Duration,
        interrupt: &Interrupt,
        stats: SharedStats,
    ) -> Result<Self, PortError> {
        Ok(ZenohExpert {
            bus,
            key: bus.keys.expert(kind),
            timeout,
            request_id: 0,
            in_flight: Vec::new(),
            stops: Stops::new(bus, interrupt)?,
            stats,
        })
    }

    /// Sends `payload` and returns the channel its replies arrive on, without waiting for them.
    fn get(&self, payload: &[u8]) -> Result<FifoChannelHandler<zenoh::query::Reply>, String> {
        self.bus
            .session
            .get(&self.key)
            .payload(payload.to_vec())
            .encoding(encoding_of::<ExpertRequest>())
            .timeout(self.timeout)
            .wait()
            .map_err(|e| e.to_string())
    }

    /// The first reply on `replies`, decoded.
    fn reply(replies: FifoChannelHandler<zenoh::query::Reply>) -> Result<ExpertReply, String> {
        match replies.recv() {
            Ok(reply) => match reply.result() {
                Ok(sample) => codec::decode::<ExpertReply>(&sample.payload().to_bytes())
                    .map_err(|e| e.to_string()),
                Err(err) => Err(format!(
                    "the server refused the request: {}",
                    String::from_utf8_lossy(&err.payload().to_bytes())
                )),
            },
            Err(_) => Err("no expert server answered".into()),
        }
    }

    /// Waits for `request`'s answers, asking again every 500 ms while no server answers, until a stop.
    ///
    /// The figures: the time blocked here is expert wait; of it, what can have been the wire is counted as transport:
    /// the round trip less the server's residence time, but no more than the time blocked (the rest of the wire
    /// time passed while the actor simulated).
    fn finish(&mut self, request: InFlight) -> Result<Vec<ExpertAnswer>, PortError> {
        let blocked = Instant::now();
        let InFlight {
            id,
            payload,
            queries: n,
            mut sent,
            mut replies,
        } = request;
        let mut attempt = 1u32;
        loop {
            match replies.and_then(Self::reply) {
                Ok(reply) if reply.request_id == id && reply.answers.len() == n => {
                    let waited = blocked.elapsed();
                    let on_wire = sent
                        .elapsed()
                        .saturating_sub(Duration::from_micros(reply.batch_time_us));
                    with_stats(&self.stats, |s| {
                        s.expert_wait += waited;
                        s.transport += on_wire.min(waited);
                    });
                    if attempt > 1 {
                        tracing::info!(key = self.key, attempt, "expert answered again");
                    }
                    return Ok(reply.answers);
                }
                Ok(reply) => tracing::warn!(
                    key = self.key,
                    "expert reply does not match the request ({} answers for {n} queries, id {} for {id})",
                    reply.answers.len(),
                    reply.request_id,
                ),
                Err(why) => {
                    if attempt == 1 || attempt.is_multiple_of(10) {
                        tracing::warn!(key = self.key, attempt, "waiting for an expert server: {why}");
                    }
                }
            }
            if let Some(reason) = self.stops.requested(self.bus) {
                return Err(PortError::Stopped(reason));
            }
            std::thread::sleep(Duration::from_millis(500));
            attempt += 1;
            sent = Instant::now();
            replies = self.get(&payload);
        }
    }
}

impl ExpertClient for ZenohExpert<'_> {
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        let pending = self.send(queries)?;
        self.receive(pending)
    }

    fn send(&mut self, queries: Vec<ExpertQuery>) -> Result<Pending, PortError> {
        if self.in_flight.len() >= MAX_IN_FLIGHT {
            return Err(PortError::Transport(format!(
                "{MAX_IN_FLIGHT} relabellings already in flight"
            )));
        }
        self.request_id += 1;
        let queries_len = queries.len();
        let payload = codec::encode(&ExpertRequest {
            request_id: self.request_id,
            queries,
        });
        let sent = Instant::now();
        let replies = self.get(&payload);
        self.in_flight.push(InFlight {
            id: self.request_id,
            payload,
            queries: queries_len,
            sent,
            replies,
        });
        Ok(Pending::InFlight(self.request_id))
    }

    fn cancel(&mut self, pending: Pending) {
        if let Pending::InFlight(id) = pending {
            self.in_flight.retain(|r| r.id != id);
        }
    }

    fn receive(&mut self, pending: Pending) -> Result<Vec<ExpertAnswer>, PortError> {
        let id = match pending {
            Pending::Answered(answers) => return Ok(answers),
            Pending::InFlight(id) => id,
        };
        let Some(at) = self.in_flight.iter().position(|r| r.id == id) else {
            return Err(PortError::Transport(format!(
                "request {id} is not in flight with this client"
            )));
        };
        let request = self.in_flight.swap_remove(at);
        self.finish(request)
    }
}
