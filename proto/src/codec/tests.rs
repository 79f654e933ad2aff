use super::*;

/// An image's bytes encode as a `Vec<u8>`'s did (schema 6 unchanged), in bincode and in JSON, and decode back.
#[test]
fn image_bytes_keep_the_encoding_of_a_vec() {
    #[derive(serde::Serialize, serde::Deserialize, PartialEq, Debug)]
    struct Plain {
        width: u16,
        height: u16,
        rgb: Vec<u8>,
    }
    let rgb: Vec<u8> = (0..=255u8).cycle().take(image_bytes(64, 64)).collect();
    let image = Image {
        width: 64,
        height: 64,
        rgb: rgb.clone(),
    };
    let plain = Plain {
        width: 64,
        height: 64,
        rgb,
    };
    let c = config();
    let ours = bincode::serde::encode_to_vec(&image, c).unwrap();
    assert_eq!(ours, bincode::serde::encode_to_vec(&plain, c).unwrap());
    let (back, _): (Image, usize) = bincode::serde::decode_from_slice(&ours, c).unwrap();
    assert_eq!(back, image);
    let (plain_back, _): (Plain, usize) = bincode::serde::decode_from_slice(&ours, c).unwrap();
    assert_eq!(plain_back, plain);
    let json = serde_json::to_string(&image).unwrap();
    assert_eq!(json, serde_json::to_string(&plain).unwrap());
    assert_eq!(serde_json::from_str::<Image>(&json).unwrap(), image);
}

pub(crate) fn step(x: f32) -> Step {
    Step {
        state: [1.0, 0.1, 0.2, x, 0.3, -0.1],
        pose: [1.0, 2.0, 0.5],
        image: Some(Image {
            width: 2,
            height: 1,
            rgb: vec![1, 2, 3, 4, 5, 6],
        }),
        expert_action: [0.5, -0.1],
        applied_action: [0.4, -0.05],
        next_state: [1.1, 0.1, 0.2, x + 0.1, 0.3, -0.1],
        expert_ok: true,
    }
}

fn segment() -> TrajMessage {
    TrajMessage::Segment(Segment {
        actor: "actor-0".into(),
        incarnation: 3,
        env: 3,
        episode: 7,
        seq: 11,
        policy_version: 2,
        outcome: Outcome::Failure(EndReason::OutOfTrack),
        steps: vec![step(0.0), step(1.0)],
    })
}

fn round_trip<M: Message + PartialEq + std::fmt::Debug>(m: M) {
    let bytes = encode(&m);
    assert_eq!(&bytes[..4], b"CABC");
    assert_eq!(decode::<M>(&bytes).unwrap(), m);
}

#[test]
fn every_message_round_trips() {
    round_trip(segment());
    round_trip(TrajMessage::EpochDone(EpochDone {
        actor: "a".into(),
        version: 3,
        published_unix_ms: 5,
        segments: 4,
        steps: 1024,
        taken: 1030,
        staged: 17,
        shielded: 3,
    }));
    round_trip(PolicyUpdate {
        version: 9,
        beta: 0.95f64.powi(9),
        architecture: "mlp-6-3x128-2".into(),
        weights: vec![0, 1, 2, 255],
        steps_per_actor: 512,
        published_unix_ms: 1_790_000_000_000,
        shield: Some(ShieldNets {
            dynamics: vec![3, 4],
            critic: vec![5],
        }),
    });
    round_trip(ExpertRequest {
        request_id: 5,
        queries: vec![ExpertQuery {
            stream: StreamId {
                actor: "a".into(),
                env: 1,
                episode: 2,
            },
            start: true,
            vehicle: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
            frenet: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
        }],
    });
    round_trip(ExpertReply {
        request_id: 5,
        answers: vec![ExpertAnswer {
            action: [1.0, -0.2],
            success: true,
            status: "Solved".into(),
            iterations: 12,
            solve_time_us: 800,
        }],
        batch_time_us: 900,
    });
    round_trip(EvalReport {
        actor: "eval".into(),
        version: 4,
        laps: 2,
        lap_times: [4.9, 5.0].into(),
        end_reason: EndReason::MaxLaps,
        steps: 100,
        line: vec![[0.0, 0.0], [0.1, 0.0]],
        spawn_episodes: 5,
        spawn_crashes: 1,
    });
    round_trip(Stop {
        reason: "early stop".into(),
    });
}

#[test]
fn truncated_bytes_are_refused() {
    let bytes = encode(&segment());
    for len in [0, 3, HEADER_LEN - 1] {
        assert_eq!(
            decode::<TrajMessage>(&bytes[..len]),
            Err(DecodeError::Truncated { len })
        );
    }
    for len in [HEADER_LEN, HEADER_LEN + 5, bytes.len() - 1] {
        assert!(matches!(
            decode::<TrajMessage>(&bytes[..len]),
            Err(DecodeError::Malformed { .. })
        ));
    }
}

#[test]
fn foreign_bytes_are_refused() {
    let err = decode::<TrajMessage>(b"hello world, not cabc").unwrap_err();
    assert!(matches!(err, DecodeError::Foreign { .. }));
    assert!(err.to_string().contains("foreign"));
}

#[test]
fn another_schema_version_is_refused() {
    let mut bytes = encode(&segment());
    bytes[4..6].copy_from_slice(&(SCHEMA_VERSION + 1).to_le_bytes());
    assert_eq!(
        decode::<TrajMessage>(&bytes),
        Err(DecodeError::SchemaVersion {
            found: SCHEMA_VERSION + 1
        })
    );
}

#[test]
fn another_message_kind_is_refused() {
    let bytes = encode(&Stop { reason: "x".into() });
    assert!(matches!(
        decode::<TrajMessage>(&bytes),
        Err(DecodeError::WrongKind { found: 6, .. })
    ));
}

#[test]
fn trailing_bytes_are_refused() {
    let mut bytes = encode(&Stop { reason: "x".into() });
    bytes.push(0);
    assert!(matches!(
        decode::<Stop>(&bytes),
        Err(DecodeError::TrailingBytes { extra: 1, .. })
    ));
}

#[test]
fn non_finite_states_are_refused() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let TrajMessage::Segment(mut seg) = segment() else {
            unreachable!()
        };
        seg.steps[1].next_state[4] = bad;
        let err = decode::<TrajMessage>(&encode(&TrajMessage::Segment(seg))).unwrap_err();
        assert!(matches!(err, DecodeError::Invalid { .. }), "{err}");
        assert!(err.to_string().contains("step 1: next_state[4]"), "{err}");
    }
}

/// A batch round-trips; one of no segments, or mixing actors or incarnations, or with a bad step in any of its
/// segments, is refused with what was wrong.
#[test]
fn a_batch_of_one_incarnations_segments_round_trips_and_any_other_is_refused() {
    let TrajMessage::Segment(first) = segment() else {
        unreachable!()
    };
    let second = Segment {
        seq: 12,
        ..first.clone()
    };
    round_trip(TrajMessage::Segments(vec![first.clone(), second.clone()]));
    let refused = |batch: Vec<Segment>| {
        let err = decode::<TrajMessage>(&encode(&TrajMessage::Segments(batch))).unwrap_err();
        assert!(matches!(err, DecodeError::Invalid { .. }), "{err}");
        err.to_string()
    };
    assert!(refused(Vec::new()).contains("a batch of no segments"));
    let other_actor = Segment {
        actor: "actor-1".into(),
        ..second.clone()
    };
    let why = refused(vec![first.clone(), other_actor]);
    assert!(
        why.contains("segment 1 of a batch is of actor `actor-1`"),
        "{why}"
    );
    let other_incarnation = Segment {
        incarnation: 4,
        ..second.clone()
    };
    assert!(refused(vec![first.clone(), other_incarnation]).contains("incarnation 4"));
    let mut bad = second;
    bad.steps[0].state[2] = f32::NAN;
    let why = refused(vec![first, bad]);
    assert!(why.contains("segment 1: step 0: state[2]"), "{why}");
}

#[test]
fn an_evaluation_with_more_crashes_than_episodes_is_refused() {
    let report = EvalReport {
        actor: "eval".into(),
        version: 4,
        laps: 0,
        lap_times: vec![],
        end_reason: EndReason::Spin,
        steps: 10,
        line: vec![],
        spawn_episodes: 2,
        spawn_crashes: 3,
    };
    let err = decode::<EvalReport>(&encode(&report)).unwrap_err();
    assert!(err.to_string().contains("3 crashes of 2 episodes"), "{err}");
}

/// The codec does not judge an image's size: the learner's replay refuses one that is not the run's
/// (`learning/tests/replay.rs`, `outputs/tests/refused.rs`), in one place.
#[test]
fn an_image_is_carried_as_it_came() {
    let TrajMessage::Segment(mut seg) = segment() else {
        unreachable!()
    };
    seg.steps[0].image.as_mut().unwrap().rgb.pop();
    let message = TrajMessage::Segment(seg);
    assert_eq!(decode::<TrajMessage>(&encode(&message)).unwrap(), message);
}

#[test]
fn a_huge_length_prefix_does_not_allocate_or_panic() {
    // A Vec length of u64::MAX right after the header.
    let mut bytes = encode(&Stop { reason: "".into() });
    bytes.truncate(HEADER_LEN);
    bytes.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff]);
    assert!(decode::<Stop>(&bytes).is_err());
    assert!(decode::<TrajMessage>(&bytes).is_err());
}

#[test]
fn the_batch_size_is_checked_before_a_request_is_decoded() {
    let query = ExpertQuery {
        stream: StreamId {
            actor: "a".into(),
            env: 0,
            episode: 0,
        },
        start: true,
        vehicle: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
        frenet: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
    };
    let request = |n| ExpertRequest {
        request_id: 300,
        queries: vec![query.clone(); n],
    };
    assert_eq!(decode_request(&encode(&request(4)), 4), Ok(request(4)));
    assert!(matches!(
        decode_request(&encode(&request(5)), 4),
        Err(DecodeError::TooMany { len: 5, max: 4, .. })
    ));
    // A request claiming 10^9 queries in a few bytes: refused from its prefix, in no time.
    let mut bytes = encode(&request(0));
    bytes.truncate(bytes.len() - 1);
    bytes.push(252); // varint: a u32 follows
    bytes.extend_from_slice(&1_000_000_000u32.to_le_bytes());
    let started = std::time::Instant::now();
    assert_eq!(
        decode_request(&bytes, 1024),
        Err(DecodeError::TooMany {
            message: "ExpertRequest",
            len: 1_000_000_000,
            max: 1024
        })
    );
    assert!(started.elapsed() < std::time::Duration::from_millis(50));
    assert!(matches!(
        decode_request(&encode(&Stop { reason: "".into() }), 4),
        Err(DecodeError::WrongKind { .. })
    ));
    assert!(decode_request(&bytes[..HEADER_LEN + 2], 4).is_err());
}

#[test]
fn random_garbage_never_panics() {
    let mut x: u64 = 0x9e3779b97f4a7c15;
    let good = encode(&segment());
    for _ in 0..2000 {
        let mut bytes = good.clone();
        for _ in 0..4 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let i = HEADER_LEN + (x as usize) % (bytes.len() - HEADER_LEN);
            bytes[i] = (x >> 32) as u8;
        }
        let _ = decode::<TrajMessage>(&bytes);
    }
}
