//! The relabelling service: answers [`ExpertRequest`] batches with either expert, keeping the MPCC warm starts per
//! stream. Zenoh-free, so tests and benchmarks drive it in-process; the `expert-server` binary is a queryable over it.
//!
//! * Warm starts are kept per stream (actor, environment, episode), at most `max_streams` of them, with
//!   least-recently-used eviction.
//! * A query that starts a stream, or names a stream this server does not hold (evicted, or answered so far by
//!   another replica), is cold-started exactly like a new stream, so any replica can answer and a given sequence of
//!   states always gets the same actions.
//! * A batch is solved in parallel on the server's cores (rayon).
//! * A bad item (NaN, outside the Frenet band, a solver error) is a per-item failure; an oversized batch is refused
//!   whole with [`RelabelError`]. Nothing here panics on input.

use crate::mpcc::{Mpcc, MpccError, MpccStream};
use cabc_proto::config::{ExpertKind, RunConfig};
use cabc_proto::messages::{ExpertAnswer, ExpertQuery, ExpertReply, ExpertRequest, StreamId};
use cabc_proto::ports::{ExpertClient, Pending, PortError};
use cabc_sim::pid::PidLaneFollower;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The expert behind the service.
#[derive(Clone)]
pub enum Expert {
    Mpcc(Arc<Mpcc>),
    /// The PID lane follower at this target speed (m/s).
    Pid(f64),
}

impl Expert {
    /// The expert a run's configuration names (`expert.kind`): [`Mpcc::from_config`], or the PID lane follower at
    /// `expert.pid_target_speed`.
    pub fn from_config(config: &RunConfig) -> Result<Expert, MpccError> {
        Ok(match config.expert.kind {
            ExpertKind::Mpcc => Expert::Mpcc(Arc::new(Mpcc::from_config(config)?)),
            ExpertKind::Pid => Expert::Pid(config.expert.pid_target_speed),
        })
    }

    pub fn kind(&self) -> ExpertKind {
        match self {
            Expert::Mpcc(_) => ExpertKind::Mpcc,
            Expert::Pid(_) => ExpertKind::Pid,
        }
    }
}

/// A whole request refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RelabelError {
    #[error("batch of {len} queries exceeds this server's limit of {max}")]
    Oversized { len: usize, max: usize },
}

enum StreamState {
    Mpcc(Box<MpccStream>),
    Pid(Box<PidLaneFollower>),
}

struct Cache {
    streams: HashMap<StreamId, (StreamState, u64)>,
    tick: u64,
    capacity: usize,
    evicted: u64,
}

impl Cache {
    fn take(&mut self, id: &StreamId) -> Option<StreamState> {
        self.streams.remove(id).map(|(s, _)| s)
    }

    fn put(&mut self, id: StreamId, state: StreamState) {
        if self.capacity == 0 {
            return;
        }
        while self.streams.len() >= self.capacity {
            let oldest = self
                .streams
                .iter()
                .min_by_key(|(_, (_, t))| *t)
                .map(|(k, _)| k.clone());
            match oldest {
                Some(k) => {
                    self.streams.remove(&k);
                    self.evicted += 1;
                }
                None => break,
            }
        }
        self.tick += 1;
        self.streams.insert(id, (state, self.tick));
    }
}

/// What one answered batch cost, for the server's metrics.
#[derive(Clone, Debug, Default)]
pub struct BatchStats {
    pub items: usize,
    pub failures: usize,
    pub cold_starts: usize,
    /// Per-item solve times (microseconds).
    pub solve_us: Vec<u32>,
}

/// The service.
pub struct Relabeller {
    expert: Expert,
    cache: Mutex<Cache>,
    max_batch: usize,
}

impl Relabeller {
    pub fn new(expert: Expert, max_streams: usize, max_batch: usize) -> Self {
        Relabeller {
            expert,
            cache: Mutex::new(Cache {
                streams: HashMap::new(),
                tick: 0,
                capacity: max_streams,
                evicted: 0,
            }),
            max_batch,
        }
    }

    pub fn expert(&self) -> &Expert {
        &self.expert
    }

    /// Streams held and streams evicted so far.
    pub fn cache_stats(&self) -> (usize, u64) {
        let cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        (cache.streams.len(), cache.evicted)
    }

    /// Answers a batch, item by item.
    pub fn answer(
        &self,
        request: &ExpertRequest,
    ) -> Result<(ExpertReply, BatchStats), RelabelError> {
        let started = Instant::now();
        let n = request.queries.len();
        if n > self.max_batch {
            return Err(RelabelError::Oversized {
                len: n,
                max: self.max_batch,
            });
        }
        // Take each stream's warm start out of the cache (a stream appearing twice in one batch gets it once).
        let states: Vec<Option<StreamState>> = {
            let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            request
                .queries
                .iter()
                .map(|q| if q.start { None } else { cache.take(&q.stream) })
                .collect()
        };
        let results: Vec<(ExpertAnswer, Option<StreamState>, bool)> = request
            .queries
            .par_iter()
            .zip(states.into_par_iter())
            .map(|(query, state)| self.answer_one(query, state))
            .collect();
        let mut stats = BatchStats {
            items: n,
            ..BatchStats::default()
        };
        let mut answers = Vec::with_capacity(n);
        {
            let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            for (query, (answer, state, cold)) in request.queries.iter().zip(results) {
                if let Some(state) = state {
                    cache.put(query.stream.clone(), state);
                }
                stats.failures += usize::from(!answer.success);
                stats.cold_starts += usize::from(cold);
                stats.solve_us.push(answer.solve_time_us);
                answers.push(answer);
            }
        }
        Ok((
            ExpertReply {
                request_id: request.request_id,
                answers,
                batch_time_us: started.elapsed().as_micros() as u64,
            },
            stats,
        ))
    }

    /// One item: (answer, the stream's state to keep, whether it was cold-started).
    fn answer_one(
        &self,
        query: &ExpertQuery,
        state: Option<StreamState>,
    ) -> (ExpertAnswer, Option<StreamState>, bool) {
        let failed = |status: String| ExpertAnswer {
            action: [0.0, 0.0],
            success: false,
            status,
            iterations: 0,
            solve_time_us: 0,
        };
        if let Some(i) = query
            .vehicle
            .iter()
            .chain(query.frenet.iter())
            .position(|v| !v.is_finite())
        {
            return (failed(format!("non-finite state entry {i}")), None, false);
        }
        let started = Instant::now();
        match &self.expert {
            Expert::Pid(target_speed) => {
                let cold = !matches!(state, Some(StreamState::Pid(_)));
                let mut pid = match state {
                    Some(StreamState::Pid(p)) => p,
                    _ => Box::new(PidLaneFollower::new(*target_speed)),
                };
                let [v_long, _, _, _, x_tran, e_psi] = query.frenet;
                let u = pid.action(v_long, x_tran, e_psi);
                let answer = ExpertAnswer {
                    action: u,
                    success: true,
                    status: "Solved".into(),
                    iterations: 0,
                    solve_time_us: micros(started),
                };
                (answer, Some(StreamState::Pid(pid)), cold)
            }
            Expert::Mpcc(mpcc) => {
                let (stream, cold) = match state {
                    Some(StreamState::Mpcc(s)) => (Ok(*s), false),
                    _ => (mpcc.start(&query.vehicle), true),
                };
                let mut stream = match stream {
                    Ok(s) => s,
                    Err(e) => return (failed(e.to_string()), None, cold),
                };
                match mpcc.step(&mut stream, &query.vehicle) {
                    Ok(step) => {
                        let answer = ExpertAnswer {
                            action: step.action,
                            success: step.success,
                            status: step.status.to_string(),
                            iterations: step.qp_iterations,
                            solve_time_us: micros(started),
                        };
                        (answer, Some(StreamState::Mpcc(Box::new(stream))), cold)
                    }
                    Err(e) => (failed(e.to_string()), None, cold),
                }
            }
        }
    }
}

fn micros(since: Instant) -> u32 {
    since.elapsed().as_micros().min(u32::MAX as u128) as u32
}

impl Relabeller {
    /// The answers of one batch, as a client sees them.
    fn relabel_batch(&self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        let request = ExpertRequest {
            request_id: 0,
            queries,
        };
        self.answer(&request)
            .map(|(reply, _)| reply.answers)
            .map_err(|e| PortError::Transport(e.to_string()))
    }
}

/// The in-process expert client: the relabelling of Algorithm 1 answered directly, without a bus (tests, one-process
/// runs), each batch when it is sent. The `expert-server` binary puts the same service behind a zenoh queryable.
impl ExpertClient for Relabeller {
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        self.relabel_batch(queries)
    }
}

/// The in-process expert answering in the background, as an expert server over the bus does: [`ExpertClient::send`]
/// starts the batch on a thread of its own and returns at once, so that an actor observes, runs the policy and steps
/// one half of its environments while the other half's relabelling is solved (the collector's pipeline). The answers
/// are the [`Relabeller`]'s asked in turn: a stream's warm start is taken when its batch starts and put back when it
/// ends, the collector sends a half's next batch only after that half's answers came, and a cancelled batch is
/// waited for (its warm starts stored, as when it is answered at once).
pub struct Background {
    relabeller: Arc<Relabeller>,
    next: u64,
    in_flight: HashMap<u64, std::thread::JoinHandle<Result<Vec<ExpertAnswer>, PortError>>>,
}

impl Background {
    pub fn new(relabeller: Relabeller) -> Self {
        Background {
            relabeller: Arc::new(relabeller),
            next: 0,
            in_flight: HashMap::new(),
        }
    }

    /// The answers of batch `id`, waiting for its thread.
    fn wait(&mut self, id: u64) -> Result<Vec<ExpertAnswer>, PortError> {
        let thread = self
            .in_flight
            .remove(&id)
            .ok_or_else(|| PortError::Transport(format!("request {id} is not in flight")))?;
        thread.join().map_err(|_| {
            PortError::Transport(format!("the expert's thread of request {id} panicked"))
        })?
    }
}

impl ExpertClient for Background {
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        self.relabeller.relabel_batch(queries)
    }

    fn send(&mut self, queries: Vec<ExpertQuery>) -> Result<Pending, PortError> {
        let relabeller = Arc::clone(&self.relabeller);
        let thread = std::thread::Builder::new()
            .name("expert".into())
            .spawn(move || relabeller.relabel_batch(queries))
            .map_err(|e| PortError::Transport(format!("starting the expert's thread: {e}")))?;
        self.next += 1;
        self.in_flight.insert(self.next, thread);
        Ok(Pending::InFlight(self.next))
    }

    fn cancel(&mut self, pending: Pending) {
        if let Pending::InFlight(id) = pending {
            let _ = self.wait(id);
        }
    }

    fn receive(&mut self, pending: Pending) -> Result<Vec<ExpertAnswer>, PortError> {
        match pending {
            Pending::Answered(answers) => Ok(answers),
            Pending::InFlight(id) => self.wait(id),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_sim::track::Track;

    fn query(episode: u64, start: bool, vehicle: [f64; 6], frenet: [f64; 6]) -> ExpertQuery {
        ExpertQuery {
            stream: StreamId {
                actor: "a".into(),
                env: 0,
                episode,
            },
            start,
            vehicle,
            frenet,
        }
    }

    fn spawn() -> ([f64; 6], [f64; 6]) {
        let q = cabc_sim::env::fixed_spawn_state(&Track::l_track_barc());
        let (at, v) = (cabc_sim::FIXED_SPAWN, cabc_sim::FIXED_SPAWN_SPEED);
        (q, [v, 0.0, 0.0, at.s, at.x_tran, at.e_psi])
    }

    #[test]
    fn pid_answers_the_closed_form() {
        let r = Relabeller::new(Expert::Pid(1.0), 8, 16);
        let (v, _) = spawn();
        let req = ExpertRequest {
            request_id: 3,
            queries: vec![query(0, true, v, [0.5, 0.0, 0.0, 1.0, 0.1, 0.2])],
        };
        let (reply, stats) = r.answer(&req).unwrap();
        assert_eq!(reply.request_id, 3);
        let a = reply.answers[0].action;
        assert!((a[0] - 0.75).abs() < 1e-12, "{a:?}");
        assert!((a[1] - (-0.5 * (5.0 * 0.1 + 0.2))).abs() < 1e-12, "{a:?}");
        assert_eq!(stats.failures, 0);
    }

    #[test]
    fn oversized_batches_are_refused() {
        let r = Relabeller::new(Expert::Pid(1.0), 8, 2);
        let (v, f) = spawn();
        let req = ExpertRequest {
            request_id: 1,
            queries: vec![query(0, true, v, f); 3],
        };
        assert_eq!(
            r.answer(&req).unwrap_err(),
            RelabelError::Oversized { len: 3, max: 2 }
        );
    }

    #[test]
    fn bad_items_fail_alone() {
        let r = Relabeller::new(Expert::Mpcc(Arc::new(Mpcc::reference())), 8, 16);
        let (v, f) = spawn();
        let mut nan = v;
        nan[0] = f64::NAN;
        let far = [1.0, 0.0, 0.0, 50.0, 50.0, 0.0];
        let req = ExpertRequest {
            request_id: 2,
            queries: vec![
                query(0, true, nan, f),
                query(1, true, far, f),
                query(2, true, v, f),
            ],
        };
        let (reply, stats) = r.answer(&req).unwrap();
        assert!(!reply.answers[0].success && reply.answers[0].status.contains("non-finite"));
        assert!(!reply.answers[1].success);
        assert!(reply.answers[2].success, "{:?}", reply.answers[2]);
        assert_eq!(stats.failures, 2);
    }

    #[test]
    fn unknown_streams_cold_start_like_new_ones() {
        // Replica A sees the stream from its start; replica B is asked mid-stream after A's eviction: a cold start
        // on B gives the same answer as a start on a fresh A.
        let mpcc = Arc::new(Mpcc::reference());
        let (v, f) = spawn();
        let a = Relabeller::new(Expert::Mpcc(mpcc.clone()), 8, 16);
        let b = Relabeller::new(Expert::Mpcc(mpcc), 8, 16);
        let started = a
            .answer(&ExpertRequest {
                request_id: 1,
                queries: vec![query(0, true, v, f)],
            })
            .unwrap()
            .0;
        let (unknown, stats) = b
            .answer(&ExpertRequest {
                request_id: 1,
                queries: vec![query(0, false, v, f)],
            })
            .unwrap();
        assert_eq!(stats.cold_starts, 1);
        assert_eq!(started.answers[0].action, unknown.answers[0].action);
        // A now holds the stream: the next query continues it warm.
        let (_, stats) = a
            .answer(&ExpertRequest {
                request_id: 2,
                queries: vec![query(0, false, v, f)],
            })
            .unwrap();
        assert_eq!(stats.cold_starts, 0);
    }

    /// Issue 56: the in-process expert answering in the background gives the answers of the relabeller asked in
    /// turn, with two halves' batches in flight at once, and a cancelled batch leaves the warm starts where
    /// answering it does.
    #[test]
    fn answers_in_the_background_are_the_relabellers_in_turn() {
        let mpcc = Arc::new(Mpcc::reference());
        let (v, f) = spawn();
        // Two halves of one environment each, at different speeds, over five steps a little apart each.
        let half = |h: u64, k: usize| {
            let scale = 1.0 - 0.1 * h as f64 - 0.01 * k as f64;
            let (mut v, mut f) = (v, f);
            v[0] *= scale;
            f[0] *= scale;
            vec![query(h, k == 0, v, f)]
        };
        let mut turn = Relabeller::new(Expert::Mpcc(mpcc.clone()), 8, 16);
        let mut background = Background::new(Relabeller::new(Expert::Mpcc(mpcc), 8, 16));
        let actions = |a: Vec<ExpertAnswer>| a.iter().map(|a| a.action).collect::<Vec<_>>();
        let mut pending = [0, 1].map(|h| background.send(half(h, 0)).unwrap());
        assert_eq!(background.in_flight.len(), 2);
        for k in 0..5 {
            for (h, in_flight) in pending.iter_mut().enumerate() {
                let expected = actions(turn.relabel(half(h as u64, k)).unwrap());
                let this = std::mem::replace(in_flight, Pending::Answered(Vec::new()));
                let answers = background.receive(this).unwrap();
                assert_eq!(actions(answers), expected, "step {k}, half {h}");
                // As the collector does: a half's next batch goes once its answers came, while the other's travels.
                *in_flight = background.send(half(h as u64, k + 1)).unwrap();
                assert_eq!(background.in_flight.len(), 2);
            }
        }
        // Half 0's sixth batch is cancelled, half 1's answered: then half 0's seventh is the one after the sixth.
        let [cancelled, answered] = pending;
        background.cancel(cancelled);
        turn.relabel(half(0, 5)).unwrap();
        assert_eq!(
            actions(background.receive(answered).unwrap()),
            actions(turn.relabel(half(1, 5)).unwrap())
        );
        assert!(background.in_flight.is_empty());
        let next = background.send(half(0, 6)).unwrap();
        assert_eq!(
            actions(background.receive(next).unwrap()),
            actions(turn.relabel(half(0, 6)).unwrap())
        );
        assert!(background.receive(Pending::InFlight(99)).is_err());
    }

    #[test]
    fn least_recently_used_streams_are_evicted() {
        let r = Relabeller::new(Expert::Pid(1.0), 2, 16);
        let (v, f) = spawn();
        for e in 0..3 {
            r.answer(&ExpertRequest {
                request_id: e,
                queries: vec![query(e, true, v, f)],
            })
            .unwrap();
        }
        assert_eq!(r.cache_stats(), (2, 1));
    }
}
