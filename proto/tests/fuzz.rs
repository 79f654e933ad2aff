//! Fuzzing in the normal test run (issue 13, item 4): random bytes and mutations of valid encodings of every message
//! type (flipped, truncated, extended, spliced bytes; corrupted header and length prefixes) through `codec::decode`
//! of every type and `codec::decode_request`. Every case must return (Ok or a `DecodeError`) without a panic, in
//! bounded time. The number of cases per target goes to stderr, past the test harness's capture.

use cabc_proto::codec::{self, Message, HEADER_LEN};
use cabc_proto::messages::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};

/// Bytes that bincode reads as a length or an integer: small, at each varint marker, and huge.
fn length_prefix(rng: &mut StdRng) -> Vec<u8> {
    match rng.gen_range(0..6) {
        0 => vec![rng.gen::<u8>() % 251],
        1 => [vec![251], rng.gen::<u16>().to_le_bytes().to_vec()].concat(),
        2 => [vec![252], rng.gen::<u32>().to_le_bytes().to_vec()].concat(),
        3 => [vec![253], rng.gen::<u64>().to_le_bytes().to_vec()].concat(),
        4 => [
            vec![254],
            rng.gen::<u64>().to_le_bytes().to_vec(),
            rng.gen::<u64>().to_le_bytes().to_vec(),
        ]
        .concat(),
        _ => vec![255],
    }
}

/// One mutation of a valid encoding.
fn mutate(good: &[u8], rng: &mut StdRng) -> Vec<u8> {
    let mut b = good.to_vec();
    let rounds = 1 + rng.gen_range(0..4);
    for _ in 0..rounds {
        let len = b.len();
        match rng.gen_range(0..9) {
            // Flip bits of a byte.
            0 if len > 0 => {
                let i = rng.gen_range(0..len);
                b[i] ^= 1 << rng.gen_range(0..8);
            }
            // Overwrite a byte.
            1 if len > 0 => {
                let i = rng.gen_range(0..len);
                b[i] = rng.gen::<u8>();
            }
            // Truncate.
            2 => b.truncate(rng.gen_range(0..len + 1)),
            // Extend with random bytes.
            3 => (0..1 + rng.gen_range(0..16)).for_each(|_| b.push(rng.gen::<u8>())),
            // Corrupt the header: magic, schema version or kind.
            4 if len >= HEADER_LEN => {
                let i = rng.gen_range(0..HEADER_LEN);
                b[i] = rng.gen::<u8>();
            }
            // Replace what follows the header (or a later byte) by a length prefix of any size.
            5 if len > HEADER_LEN => {
                let at = HEADER_LEN + rng.gen_range(0..len - HEADER_LEN);
                let prefix = length_prefix(rng);
                let end = (at + prefix.len()).min(len);
                b.splice(at..end, prefix);
            }
            // Insert a length prefix.
            6 if len > HEADER_LEN => {
                let at = HEADER_LEN + rng.gen_range(0..len - HEADER_LEN + 1);
                let prefix = length_prefix(rng);
                b.splice(at..at, prefix);
            }
            // Duplicate or drop a run of bytes.
            7 if len > 1 => {
                let a = rng.gen_range(0..len);
                let e = (a + 1 + rng.gen_range(0..32)).min(len);
                if rng.gen_range(0..2) == 0 {
                    let run = b[a..e].to_vec();
                    b.splice(e..e, run);
                } else {
                    b.drain(a..e);
                }
            }
            // NaN / inf bit patterns where floats sit.
            _ if len >= HEADER_LEN + 4 => {
                let i = HEADER_LEN + rng.gen_range(0..len - HEADER_LEN - 3);
                let bits =
                    [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][rng.gen_range(0..3)].to_le_bytes();
                b[i..i + 4].copy_from_slice(&bits);
            }
            _ => b.push(rng.gen::<u8>()),
        }
    }
    b
}

fn step(i: usize, image: bool) -> Step {
    let x = i as f32 * 0.1;
    Step {
        state: [1.0, 0.1, 0.2, x, 0.3, -0.1],
        pose: [1.0, 2.0, 0.5],
        image: image.then(|| Image {
            width: 4,
            height: 2,
            rgb: (0..24).collect(),
        }),
        expert_action: [0.5, -0.1],
        applied_action: [0.4, -0.05],
        next_state: [1.1, 0.1, 0.2, x + 0.1, 0.3, -0.1],
        expert_ok: !i.is_multiple_of(3),
    }
}

/// A valid encoding of every message type (both kinds of TrajMessage, with and without images).
fn corpus() -> Vec<(&'static str, Vec<u8>)> {
    let segment = |image, outcome| {
        TrajMessage::Segment(Segment {
            actor: "actor-0".into(),
            incarnation: 0,
            env: 3,
            episode: 7,
            seq: 11,
            policy_version: 2,
            outcome,
            steps: (0..3).map(|i| step(i, image)).collect(),
        })
    };
    let query = |i: u32| ExpertQuery {
        stream: StreamId {
            actor: "actor-1".into(),
            env: i,
            episode: 2,
        },
        start: i == 0,
        vehicle: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
        frenet: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
    };
    vec![
        (
            "TrajMessage::Segment",
            codec::encode(&segment(false, Outcome::Lap)),
        ),
        (
            "TrajMessage::Segment+image",
            codec::encode(&segment(true, Outcome::Failure(EndReason::OutOfTrack))),
        ),
        (
            "TrajMessage::EpochDone",
            codec::encode(&TrajMessage::EpochDone(EpochDone {
                actor: "actor-0".into(),
                version: 3,
                published_unix_ms: 0,
                segments: 4,
                steps: 1024,
                taken: 1024,
                staged: 0,
                shielded: 0,
            })),
        ),
        (
            "PolicyUpdate",
            codec::encode(&PolicyUpdate {
                version: 9,
                beta: 0.63,
                architecture: "policy-state-mlp-2x32".into(),
                weights: (0..64).collect(),
                steps_per_actor: 512,
                published_unix_ms: 1_790_000_000_000,
                shield: None,
            }),
        ),
        (
            "ExpertRequest",
            codec::encode(&ExpertRequest {
                request_id: 5,
                queries: (0..3).map(query).collect(),
            }),
        ),
        (
            "ExpertReply",
            codec::encode(&ExpertReply {
                request_id: 5,
                answers: (0..3)
                    .map(|i| ExpertAnswer {
                        action: [1.0, -0.2],
                        success: i != 1,
                        status: "Solved".into(),
                        iterations: 12,
                        solve_time_us: 800,
                    })
                    .collect(),
                batch_time_us: 900,
            }),
        ),
        (
            "EvalReport",
            codec::encode(&EvalReport {
                actor: "eval-0".into(),
                version: 4,
                laps: 2,
                lap_times: vec![4.9, 5.0],
                end_reason: EndReason::MaxLaps,
                steps: 100,
                line: vec![[0.0, 0.0], [0.1, 0.0]],
                spawn_episodes: 0,
                spawn_crashes: 0,
            }),
        ),
        (
            "Stop",
            codec::encode(&Stop {
                reason: "early stop".into(),
            }),
        ),
        (
            "Ack",
            codec::encode(&Ack {
                incarnation: 7,
                seqs: vec![0, 1, 5],
                learner: 9,
                committed: true,
            }),
        ),
    ]
}

/// Decodes `bytes` as every message type (a payload may arrive on any key); true when nothing panicked.
fn decode_all(bytes: &[u8]) -> bool {
    fn one<M: Message>(bytes: &[u8]) -> bool {
        catch_unwind(AssertUnwindSafe(|| {
            let _ = codec::decode::<M>(bytes);
        }))
        .is_ok()
    }
    let request = catch_unwind(|| {
        let _ = codec::decode_request(bytes, 1024);
    })
    .is_ok();
    one::<TrajMessage>(bytes)
        && one::<PolicyUpdate>(bytes)
        && one::<ExpertRequest>(bytes)
        && one::<ExpertReply>(bytes)
        && one::<EvalReport>(bytes)
        && one::<Stop>(bytes)
        && one::<Ack>(bytes)
        && request
}

/// 0: header refused, 1: body refused by bincode, 2: values refused, 3: decoded.
fn own_depth(name: &str, bytes: &[u8]) -> usize {
    fn depth<M: Message>(bytes: &[u8]) -> usize {
        use codec::DecodeError::*;
        match codec::decode::<M>(bytes) {
            Err(Truncated { .. } | Foreign { .. } | SchemaVersion { .. } | WrongKind { .. }) => 0,
            Err(Malformed { .. } | TrailingBytes { .. } | TooMany { .. }) => 1,
            Err(Invalid { .. }) => 2,
            Ok(_) => 3,
        }
    }
    match name.split(':').next().unwrap_or(name) {
        "TrajMessage" => depth::<TrajMessage>(bytes),
        "PolicyUpdate" => depth::<PolicyUpdate>(bytes),
        "ExpertRequest" => depth::<ExpertRequest>(bytes),
        "ExpertReply" => depth::<ExpertReply>(bytes),
        "EvalReport" => depth::<EvalReport>(bytes),
        "Ack" => depth::<Ack>(bytes),
        _ => depth::<Stop>(bytes),
    }
}

fn report(target: &str, cases: usize, panics: usize, took: Duration) {
    // Straight to stderr: the harness captures print!/eprintln!, the lead wants the counts in every run.
    let _ = writeln!(
        std::io::stderr(),
        "fuzz {target}: {cases} cases, {panics} panics, {:.2} s",
        took.as_secs_f64()
    );
}

const MUTATIONS_PER_MESSAGE: usize = 25_000;
const RANDOM_CASES: usize = 25_000;

#[test]
fn mutated_encodings_of_every_message_decode_without_panic() {
    let mut rng = StdRng::seed_from_u64(0x00c0_ffee_cabc_0013);
    let (mut total, mut total_panics) = (0, 0);
    let started = Instant::now();
    for (name, good) in corpus() {
        let t = Instant::now();
        let mut panics = 0;
        // How far the mutations got in their own type's decoder: refused by the header, by bincode, by the checks
        // of values (NaN, sizes), or decoded.
        let mut depth = [0usize; 4];
        for _ in 0..MUTATIONS_PER_MESSAGE {
            let bytes = mutate(&good, &mut rng);
            if !decode_all(&bytes) {
                panics += 1;
            }
            depth[own_depth(name, &bytes)] += 1;
        }
        assert!(
            depth[1] > 0 && depth[3] > 0,
            "{name}: the mutations reach no decoder: {depth:?}"
        );
        report(
            &format!("codec::decode mutations of {name} (header/body/values refused, decoded: {depth:?})"),
            MUTATIONS_PER_MESSAGE,
            panics,
            t.elapsed(),
        );
        total += MUTATIONS_PER_MESSAGE;
        total_panics += panics;
    }
    report(
        "codec::decode mutations, all messages",
        total,
        total_panics,
        started.elapsed(),
    );
    assert_eq!(total_panics, 0);
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn random_bytes_decode_without_panic() {
    let mut rng = StdRng::seed_from_u64(0x5eed_0013);
    let started = Instant::now();
    let mut panics = 0;
    for i in 0..RANDOM_CASES {
        let len = rng.gen_range(0..if i % 4 == 0 { 16 } else { 512 });
        let mut bytes: Vec<u8> = (0..len).map(|_| rng.gen::<u8>()).collect();
        // Half of them behind a valid header of a random kind, so the bodies are reached.
        if i % 2 == 0 {
            let mut header = codec::MAGIC.to_vec();
            header.extend_from_slice(&codec::SCHEMA_VERSION.to_le_bytes());
            header.push(1 + rng.gen_range(0..6) as u8);
            bytes.splice(0..0, header);
        }
        if !decode_all(&bytes) {
            panics += 1;
        }
    }
    report(
        "codec::decode random bytes",
        RANDOM_CASES,
        panics,
        started.elapsed(),
    );
    assert_eq!(panics, 0);
}
