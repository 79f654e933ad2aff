//! The synthetic actors of `cabc bench-bus`, run in a child process of the same binary (`cabc bench-bus-actors`), so
//! that the learner's process CPU time is the learner's alone. Each actor is a real actor's bus side without its
//! simulator: its own zenoh session (a client of the learner's or the standalone router), the learner's versions
//! from [`ZenohPolicySource`], its segments through [`ZenohSegments`] (the outbox, held until the learner's receipt),
//! its marker after its share; it publishes real-shaped segments of [`template`] steps as fast as the bus takes them.
//! On the learner's Stop the process prints an [`ActorsReport`] (JSON) on stdout.

use super::{CapacityError, Kind};
use cabc_bus::interrupt::Interrupt;
use cabc_bus::outbox::{Batching, ZenohSegments};
use cabc_bus::ports::{SharedStats, ZenohPolicySource};
use cabc_bus::{Bus, Role};
use cabc_proto::codec;
use cabc_proto::config::BusSection;
use cabc_proto::keys::Keys;
use cabc_proto::messages::{
    image_bytes, Ack, EpochDone, Image, Outcome, Segment, Step, TrajMessage, STATE_DIM,
};
use cabc_proto::ports::{Next, PolicySource, SegmentSink};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::Wait;

/// `cabc bench-bus-actors`: the child process of `cabc bench-bus` (not for people).
#[derive(Clone, Debug, clap::Args)]
pub struct ActorsArgs {
    /// The router every actor connects to.
    #[arg(long)]
    pub connect: String,
    /// The run's name (its keys).
    #[arg(long)]
    pub run: String,
    #[arg(long, value_enum)]
    pub kind: Kind,
    /// Actors, each with its own session.
    #[arg(long)]
    pub count: usize,
    #[arg(long)]
    pub steps_per_segment: usize,
    /// The run's `bus.segment_batch_ms` and `bus.segment_batch_kib`.
    #[arg(long)]
    pub segment_batch_ms: f64,
    #[arg(long)]
    pub segment_batch_kib: u64,
    /// The camera's image side (64: `v-a-cpu`).
    #[arg(long, default_value_t = 64)]
    pub side: u16,
}

/// A version as an actor received it (decoded, handed out by its policy source).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Receipt {
    pub version: u64,
    /// When, in microseconds since the Unix epoch (this machine's clock, as the learner's).
    pub unix_us: u64,
    pub weights_bytes: usize,
}

/// What one actor did.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ActorBook {
    pub id: String,
    pub incarnation: u64,
    /// Segments and steps published (their seqs are 0 .. segments).
    pub segments: u64,
    pub steps: u64,
    pub markers: u64,
    pub receipts: Vec<Receipt>,
    /// Segments the outbox dropped unacknowledged, and those it published again (`cabc_bus::outbox`).
    pub outbox_lost: u64,
    pub resent: u64,
    /// Segments still unacknowledged when the actor stopped.
    pub unacknowledged: usize,
}

/// The child's report: every actor's book and the receipts' round trips (publish -> acknowledgement at the actor)
/// of versions after the warm-up.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ActorsReport {
    pub actors: Vec<ActorBook>,
    pub receipt_rtt_ms_p50: Option<f64>,
    pub receipt_rtt_ms_p99: Option<f64>,
    pub receipt_rtt_samples: usize,
}

fn unix_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// `steps` real-shaped steps of `kind` (finite states, poses, actions; a camera step's `side` x `side` RGB image of
/// random bytes, which compress as badly as a camera's), seeded by `seed`.
pub fn template(kind: Kind, steps: usize, side: u16, seed: u64) -> Vec<Step> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..steps)
        .map(|_| {
            let mut state = [0f32; STATE_DIM];
            state.iter_mut().for_each(|x| *x = rng.gen_range(-1.0..1.0));
            let mut next_state = state;
            next_state[3] += 0.1;
            let image = (kind == Kind::Camera).then(|| {
                let mut rgb = vec![0u8; image_bytes(side.into(), side.into())];
                rng.fill(&mut rgb[..]);
                Image {
                    width: side,
                    height: side,
                    rgb,
                }
            });
            Step {
                state,
                pose: [rng.gen(), rng.gen(), rng.gen()],
                image,
                expert_action: [rng.gen_range(-1.0..1.0), rng.gen_range(-0.4..0.4)],
                applied_action: [rng.gen_range(-1.0..1.0), rng.gen_range(-0.4..0.4)],
                next_state,
                expert_ok: true,
            }
        })
        .collect()
}

/// The round trips of one actor's receipts: when each seq was published, and how long its receipt took.
#[derive(Default)]
struct RoundTrips {
    sent: HashMap<u64, (Instant, bool)>,
    /// Milliseconds, of segments of versions after the warm-up (version 0).
    rtt_ms: Vec<f64>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// One actor until the learner's Stop.
fn actor(
    bus: &Bus,
    id: &str,
    incarnation: u64,
    steps: &[Step],
    batching: Batching,
    trips: &Arc<Mutex<RoundTrips>>,
) -> Result<ActorBook, CapacityError> {
    let interrupt = Interrupt::default();
    let stats = SharedStats::default();
    let mut sink = ZenohSegments::new(bus, id, &interrupt, stats.clone())?.batching(batching);
    let mut source = ZenohPolicySource::new(bus, &interrupt, stats.clone())?.echoing(sink.echo());
    let mut book = ActorBook {
        id: id.to_string(),
        incarnation,
        ..ActorBook::default()
    };
    while let Next::Policy(update) = source.next()? {
        book.receipts.push(Receipt {
            version: update.version,
            unix_us: unix_us(),
            weights_bytes: update.weights.len(),
        });
        let (mut segments, mut sent) = (0, 0u64);
        while sent < update.steps_per_actor {
            let n = (update.steps_per_actor - sent).min(steps.len() as u64) as usize;
            let seq = book.segments;
            let segment = Segment {
                actor: id.to_string(),
                env: 0,
                episode: seq,
                incarnation,
                seq,
                policy_version: update.version,
                outcome: Outcome::Lap,
                steps: steps[..n].to_vec(),
            };
            lock(trips)
                .sent
                .insert(seq, (Instant::now(), update.version > 0));
            sink.put(TrajMessage::Segment(segment))?;
            book.segments += 1;
            book.steps += n as u64;
            segments += 1;
            sent += n as u64;
        }
        sink.put(TrajMessage::EpochDone(EpochDone {
            actor: id.to_string(),
            version: update.version,
            published_unix_ms: update.published_unix_ms,
            segments,
            steps: sent,
            taken: sent,
            staged: 0,
            shielded: 0,
        }))?;
        book.markers += 1;
    }
    // The receipts of the last segments may still be on their way.
    let until = Instant::now() + Duration::from_secs(2);
    while sink.unacknowledged() > 0 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(10));
    }
    book.unacknowledged = sink.unacknowledged();
    let wire = lock(&stats);
    (book.outbox_lost, book.resent) = (wire.segments_lost, wire.segments_resent);
    Ok(book)
}

/// `cabc bench-bus-actors`: `count` actors until the learner's Stop; their report.
pub fn serve(args: &ActorsArgs) -> Result<ActorsReport, CapacityError> {
    let bus_section = BusSection {
        listen: Vec::new(),
        connect: vec![args.connect.clone()],
        segment_batch_ms: args.segment_batch_ms,
        segment_batch_kib: args.segment_batch_kib,
        ..BusSection::default()
    };
    let batching = Batching::of(&bus_section);
    let steps = template(args.kind, args.steps_per_segment.max(1), args.side, 0x5eed);
    let incarnation = unix_us();
    let mut trips = Vec::new();
    let books = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..args.count)
            .map(|i| {
                let id = format!("bench-{i}");
                let trips_i: Arc<Mutex<RoundTrips>> = Arc::default();
                trips.push(trips_i.clone());
                let (bus_section, steps, run) = (&bus_section, &steps, &args.run);
                std::thread::Builder::new()
                    .name(format!("actor-{i}"))
                    .spawn_scoped(scope, move || {
                        let keys = Keys::new(run)
                            .map_err(|e| CapacityError::Setup(format!("run name: {e}")))?;
                        let bus =
                            Bus::join(bus_section, Role::Connect, keys, &format!("actor/{id}"))?;
                        let on_ack = trips_i.clone();
                        let _acks = bus
                            .session
                            .declare_subscriber(bus.keys.ack(&id))
                            .callback(move |sample| {
                                let bytes = sample.payload().to_bytes();
                                let Ok(ack) = codec::decode::<Ack>(&bytes) else {
                                    return;
                                };
                                let now = Instant::now();
                                let mut trips = lock(&on_ack);
                                for seq in &ack.seqs {
                                    if let Some((sent, counted)) = trips.sent.remove(seq) {
                                        if counted {
                                            trips.rtt_ms.push((now - sent).as_secs_f64() * 1e3);
                                        }
                                    }
                                }
                            })
                            .wait()
                            .map_err(|e| CapacityError::Setup(format!("ack subscriber: {e}")))?;
                        let book =
                            actor(&bus, &id, incarnation + i as u64, steps, batching, &trips_i);
                        drop(_acks);
                        bus.close_blocking()?;
                        book
                    })
                    .map_err(|e| CapacityError::Setup(format!("an actor's thread: {e}")))
            })
            .collect::<Result<_, _>>()?;
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .map_err(|_| CapacityError::Setup("an actor's thread panicked".into()))?
            })
            .collect::<Result<Vec<ActorBook>, CapacityError>>()
    })?;
    let mut rtt: Vec<f64> = trips
        .iter()
        .flat_map(|t| std::mem::take(&mut lock(t).rtt_ms))
        .collect();
    Ok(ActorsReport {
        actors: books,
        receipt_rtt_ms_p50: super::cpu::quantile(&mut rtt, 0.5),
        receipt_rtt_ms_p99: super::cpu::quantile(&mut rtt, 0.99),
        receipt_rtt_samples: rtt.len(),
    })
}
