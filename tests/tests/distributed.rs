//! The distributed run end to end: the real binaries on loopback, smoke-sized (PID expert, full state).

use cabc_tests::Cluster;
use std::time::Duration;

fn csv_rows(path: &std::path::Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

fn column(rows: &[Vec<String>], name: &str) -> Vec<String> {
    let i = rows[0]
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    rows[1..].iter().map(|r| r[i].clone()).collect()
}

async fn publish_garbage(endpoint: &str, key: &str) {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"client\"").unwrap();
    config
        .insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let session = zenoh::open(config).await.unwrap();
    for payload in [&b"definitely not cabc"[..], b"CABC\x01\x00\x01garbage", b""] {
        session.put(key, payload.to_vec()).await.unwrap();
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    session.close().await.unwrap();
}

fn endpoint_of(config: &std::path::Path) -> String {
    let text = std::fs::read_to_string(config).unwrap();
    let start = text.find("listen = [\"").unwrap() + "listen = [\"".len();
    let end = start + text[start..].find('"').unwrap();
    text[start..end].to_string()
}

/// Two actors, an eval actor, one expert server and the learner complete the run: every published step reaches
/// the replay exactly once, policy versions advance, evaluations arrive, and the run folder holds the checkpoint,
/// metrics and plots. A third actor killed mid-run does not stall it, and garbage on a cabc key is counted.
/// Then the learner resumes the same run for more epochs, continuing its epoch count and buffers.
#[test]
fn a_smoke_run_completes_survives_faults_and_resumes() {
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "e2e", 10, "").unwrap();
    cluster.start_all(3, false).unwrap();
    let endpoint = endpoint_of(&cluster.config);

    // Once two epochs are done, crash actor-2 and throw garbage at the learner.
    let metrics_path = cluster.dir.join("metrics.csv");
    let started = std::time::Instant::now();
    while std::fs::read_to_string(&metrics_path).map_or(0, |t| t.lines().count()) < 3 {
        assert!(
            started.elapsed() < Duration::from_secs(240),
            "no epoch completed:\n{}",
            cluster.log_tail("learner")
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    cluster.kill("actor-2").unwrap();
    let runtime = cabc_fixtures::runtime();
    runtime.block_on(publish_garbage(&endpoint, "cabc/e2e/traj/x"));

    let summary = cluster.summary("learner");
    assert_eq!(summary["epochs"], 10, "{summary:#}");
    // Issue 21: started directly (as deploy/SCALE-OUT.md does), each process logs into the run folder itself.
    let logs = cluster.dir.join("logs");
    for (file, line) in [
        ("learner.log", "epoch done"),
        ("actor-0.log", "actor started"),
        ("eval.log", "actor started"),
        ("expert-server-0.log", "logging to this file"),
    ] {
        let text = std::fs::read_to_string(logs.join(file))
            .unwrap_or_else(|e| panic!("{}: {e}", logs.join(file).display()));
        assert!(text.contains(line), "{file} lacks {line:?}");
        assert!(
            !text.contains('\u{1b}'),
            "{file}: no terminal colours in a file"
        );
    }
    assert_eq!(summary["duplicate_segments"], 0, "{summary:#}");
    assert_eq!(summary["segments_not_stored"], 0, "{summary:#}");
    assert!(
        summary["rejected_messages"].as_u64().unwrap() >= 2,
        "garbage not counted: {summary:#}"
    );

    let dir = cluster.dir.clone();
    for f in [
        "summary.json",
        "metrics.csv",
        "evals.csv",
        "config.toml",
        "checkpoint/state.json",
        "checkpoint/replay.bin",
        "plots/laps.png",
        "plots/losses.png",
        "plots/lap_times.png",
        "final-policy.safetensors",
    ] {
        assert!(dir.join(f).exists(), "{f} missing in {}", dir.display());
    }
    let metrics = csv_rows(&dir.join("metrics.csv"));
    let epochs: Vec<String> = (0..10).map(|e| e.to_string()).collect();
    assert_eq!(column(&metrics, "epoch"), epochs);
    // Exactly once: what the actors said they published for an epoch is what was stored; only in the epoch in
    // which actor-2 was killed the learner holds more (its partial segments, without its marker).
    let stored: Vec<u64> = column(&metrics, "steps_collected")
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let published: Vec<u64> = column(&metrics, "steps_published")
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    assert!(
        stored.iter().zip(&published).all(|(s, p)| s >= p),
        "lost steps: {stored:?} vs {published:?}"
    );
    let unequal = stored
        .iter()
        .zip(&published)
        .filter(|(s, p)| s != p)
        .count();
    assert!(unequal <= 1, "stored {stored:?} vs published {published:?}");
    // Each epoch takes its budget (published, or staged for the next epoch), but the one in which actor-2 died
    // without its marker.
    let taken: Vec<u64> = column(&metrics, "steps_taken")
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    assert!(
        taken.iter().filter(|&&t| t < 256).count() <= 1,
        "each epoch collects its budget: {taken:?}"
    );
    let evals = csv_rows(&dir.join("evals.csv"));
    assert!(evals.len() > 1, "no evaluation arrived");

    // Resume the same run for two more epochs.
    let text = std::fs::read_to_string(&cluster.config)
        .unwrap()
        .replace("max_epochs = 10", "max_epochs = 12");
    std::fs::write(&cluster.config, text).unwrap();
    let d_plus_before: u64 = column(&metrics, "d_plus").last().unwrap().parse().unwrap();
    let config = cluster.config.display().to_string();
    // The surviving actors and the expert server were stopped with the run; start fresh ones.
    cluster.start_learner("learner-resumed", true).unwrap();
    cluster
        .start(
            "expert-server-2",
            "expert-server",
            &["--config", &config, "serve", "--id", "1"],
        )
        .unwrap();
    for id in ["actor-0", "actor-1"] {
        cluster
            .start(
                &format!("{id}-2"),
                "actor",
                &["--config", &config, "--id", id],
            )
            .unwrap();
    }
    let (status, _) = cluster
        .wait("learner-resumed", Duration::from_secs(300))
        .unwrap_or_else(|e| panic!("{e}\n{}", cluster.log_tail("learner-resumed")));
    assert!(
        status.success(),
        "resumed learner failed:\n{}",
        cluster.log_tail("learner-resumed")
    );
    let metrics = csv_rows(&dir.join("metrics.csv"));
    let epochs: Vec<String> = (0..12).map(|e| e.to_string()).collect();
    assert_eq!(column(&metrics, "epoch"), epochs);
    let d_plus_after: u64 = column(&metrics, "d_plus").last().unwrap().parse().unwrap();
    assert!(
        d_plus_after >= d_plus_before,
        "D+ shrank across the resume: {d_plus_before} -> {d_plus_after}"
    );
}

/// A malformed request to the expert server gets an error reply, and the next good request is answered.
#[test]
fn the_expert_server_refuses_bad_requests_and_keeps_serving() {
    use cabc_proto::codec::{decode, encode};
    use cabc_proto::messages::{ExpertQuery, ExpertReply, ExpertRequest, StreamId};
    let tmp = cabc_tests::test_dir();
    let mut cluster = Cluster::new(tmp.path(), "expert", 1, "").unwrap();
    let config = cluster.config.display().to_string();
    let endpoint = endpoint_of(&cluster.config);
    // The server is a client of a router: the learner is the router of a run, so start one.
    let run_dir = cluster.dir.display().to_string();
    cluster
        .start(
            "learner",
            "learner",
            &["run", "--config", &config, "--run-dir", &run_dir],
        )
        .unwrap();
    cluster
        .start(
            "expert-server",
            "expert-server",
            &["--config", &config, "serve"],
        )
        .unwrap();
    let runtime = cabc_fixtures::runtime();
    runtime.block_on(async {
        let mut zc = zenoh::Config::default();
        zc.insert_json5("mode", "\"client\"").unwrap();
        zc.insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
            .unwrap();
        zc.insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        zc.insert_json5("connect/timeout_ms", "-1").unwrap();
        let session = zenoh::open(zc).await.unwrap();
        let key = "cabc/expert/expert/pid";
        let ask = |payload: Vec<u8>| {
            let session = session.clone();
            async move {
                for _ in 0..100 {
                    let replies = session
                        .get(key)
                        .payload(payload.clone())
                        .timeout(Duration::from_secs(2))
                        .await
                        .unwrap();
                    if let Ok(reply) = replies.recv_async().await {
                        return reply
                            .into_result()
                            .map(|s| s.payload().to_bytes().to_vec())
                            .map_err(|e| {
                                String::from_utf8_lossy(&e.payload().to_bytes()).to_string()
                            });
                    }
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
                panic!("no expert server answered");
            }
        };
        let err = ask(b"garbage".to_vec()).await.unwrap_err();
        assert!(err.contains("refused") && err.contains("foreign"), "{err}");
        let request = ExpertRequest {
            request_id: 9,
            queries: vec![ExpertQuery {
                stream: StreamId {
                    actor: "t".into(),
                    env: 0,
                    episode: 0,
                },
                start: true,
                vehicle: [0.5, 0.0, 0.0, 0.1, 0.0, 0.0],
                frenet: [0.5, 0.0, 0.0, 0.1, 0.1, 0.0],
            }],
        };
        let reply: ExpertReply = decode(&ask(encode(&request)).await.unwrap()).unwrap();
        assert_eq!(reply.request_id, 9);
        assert!(reply.answers[0].success);
        // The PID's closed form: a = 1.5 (1 - v), delta = -0.5 (5 x_tran + e_psi).
        assert!((reply.answers[0].action[0] - 0.75).abs() < 1e-12);
        assert!((reply.answers[0].action[1] + 0.25).abs() < 1e-12);
        session.close().await.unwrap();
    });
}

/// The camera end to end (the `smoke-camera` settings: 32x32 images, the small CNN): the actors render, their
/// segments carry images, the replay stores them, the vision policy trains with L_clone and L_safety, and the eval
/// actor drives from images. It asserts what the state smoke run asserts.
#[test]
fn a_camera_smoke_run_completes() {
    let tmp = cabc_tests::test_dir();
    let camera =
        "[observation]\nkind = \"camera\"\nwidth = 32\nheight = 32\ntrunk = \"small-cnn\"\n";
    let epochs = 6;
    let mut cluster = Cluster::new(tmp.path(), "camera", epochs, camera).unwrap();
    // The policy takes over fast (beta halves each epoch), so it fails, D? grows and the critic trains: L_safety
    // is in play.
    let text = std::fs::read_to_string(&cluster.config).unwrap().replace(
        "autolabel_every = 2",
        "autolabel_every = 2\nbeta_decay = 0.5",
    );
    std::fs::write(&cluster.config, text).unwrap();
    cluster.start_all(2, false).unwrap();
    let summary = cluster.summary("learner");
    assert_eq!(summary["epochs"], epochs, "{summary:#}");
    assert_eq!(summary["duplicate_segments"], 0, "{summary:#}");
    // A segment whose images are not 32x32 would be refused here.
    assert_eq!(summary["segments_not_stored"], 0, "{summary:#}");
    assert_eq!(summary["rejected_messages"], 0, "{summary:#}");

    let dir = cluster.dir.clone();
    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    assert!(config.contains("kind = \"camera\""), "{config}");
    let metrics = csv_rows(&dir.join("metrics.csv"));
    let epoch_names: Vec<String> = (0..epochs).map(|e| e.to_string()).collect();
    assert_eq!(column(&metrics, "epoch"), epoch_names);
    assert_eq!(
        column(&metrics, "steps_collected"),
        column(&metrics, "steps_published"),
        "every published step stored once"
    );
    assert!(column(&metrics, "steps_taken")
        .iter()
        .all(|t| t.parse::<u64>().unwrap() >= 256));
    let d_plus: u64 = column(&metrics, "d_plus").last().unwrap().parse().unwrap();
    assert!(d_plus > 0, "the PID expert's laps fill D+");
    // D+'s images are in the run's image log (32 x 32 x 3 bytes each, at least one record per D+ step), not in the
    // checkpoint's replay.bin, which holds the arrays and one record number per image.
    let log: u64 = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with("replay-images-")
        })
        .map(|e| e.metadata().unwrap().len())
        .sum();
    assert!(
        log >= d_plus * 32 * 32 * 3,
        "{log} bytes of images for {d_plus} steps of D+"
    );
    let replay = std::fs::metadata(dir.join("checkpoint/replay.bin"))
        .unwrap()
        .len();
    assert!(
        replay < d_plus * 32 * 32 * 3,
        "replay.bin holds images: {replay} bytes"
    );
    // The vision policy trains once D+ holds enough of a lap: a positive imitation loss, and once the critic has
    // trained on D+ against D-, a positive safety term (lambda 1).
    let d_plus_by_epoch = column(&metrics, "d_plus");
    let imitation = column(&metrics, "imitation_loss");
    let safety = column(&metrics, "safety_loss");
    let (mut trained, mut with_safety) = (0, 0);
    for (imitation, safety) in imitation.iter().zip(&safety) {
        let (imitation, safety): (f64, f64) = (imitation.parse().unwrap(), safety.parse().unwrap());
        assert!(safety.is_finite() && safety >= 0.0, "safety loss {safety}");
        assert!(
            imitation.is_finite() && imitation >= 0.0,
            "imitation loss {imitation}"
        );
        trained += (imitation > 0.0) as u32;
        with_safety += (safety > 0.0) as u32;
    }
    assert!(
        trained >= 3,
        "the policy trained in {trained} epochs: {d_plus_by_epoch:?}"
    );
    assert!(with_safety >= 1, "L_safety never in play: {safety:?}");
    // The eval actor drove every version it reported from images.
    let evals = csv_rows(&dir.join("evals.csv"));
    assert!(evals.len() > 1, "no evaluation arrived");
    assert!(column(&evals, "steps")
        .iter()
        .all(|s| s.parse::<u64>().unwrap() > 0));
    for label in ["actor-0", "actor-1", "eval", "expert-server"] {
        cluster.wait_success(label, Duration::from_secs(60));
    }
    let actor = std::fs::read_to_string(dir.join("actor-0.log")).unwrap_or_default();
    assert!(!actor.contains("ERROR"), "{actor}");
}

/// Two evaluators share the versions (`actors.evaluators = 2`: `eval` takes the even ones, `eval-1` the odd ones):
/// every version is evaluated once, but those whose reports had not arrived when the run ended, which the summary
/// lists.
#[test]
fn two_evaluators_share_every_version() {
    let tmp = cabc_tests::test_dir();
    let epochs = 10;
    let extra = "[actors]\ncount = 2\nenvs_per_actor = 2\nevaluators = 2\n";
    let mut cluster = Cluster::new(tmp.path(), "shards", epochs, extra).unwrap();
    cluster.start_all(2, false).unwrap();
    let config = cluster.config.display().to_string();
    cluster
        .start(
            "eval-1",
            "actor",
            &["--config", &config, "--id", "eval-1", "--eval"],
        )
        .unwrap();
    let summary = cluster.summary("learner");
    assert_eq!(summary["duplicate_evals"], 0, "{summary:#}");
    let evals = csv_rows(&cluster.dir.join("evals.csv"));
    let mut versions: Vec<u64> = column(&evals, "version")
        .iter()
        .map(|v| v.parse().unwrap())
        .collect();
    let reported = versions.len();
    versions.sort();
    versions.dedup();
    assert_eq!(versions.len(), reported, "a version evaluated twice");
    let missing: Vec<u64> = summary["versions_not_evaluated"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    let mut all = versions.clone();
    all.extend(&missing);
    all.sort();
    assert_eq!(all, (0..epochs).collect::<Vec<_>>(), "{summary:#}");
    // Only the last versions can be missing: their evaluations were still under way at the end.
    assert!(missing.iter().all(|&v| v + 3 >= epochs), "{missing:?}");
    assert!(versions.iter().any(|v| v % 2 == 0) && versions.iter().any(|v| v % 2 == 1));
    for label in ["eval", "eval-1"] {
        cluster.wait_success(label, Duration::from_secs(60));
    }
    // eval-1's log: "evaluated version=<v> ..." for odd versions only (ANSI colours stripped).
    let odd = std::fs::read_to_string(cluster.dir.join("eval-1.log")).unwrap();
    let plain: String = odd
        .split('\x1b')
        .enumerate()
        .map(|(i, part)| match i {
            0 => part,
            _ => part.split_once('m').map_or("", |(_, rest)| rest),
        })
        .collect();
    let evaluated: Vec<u64> = plain
        .lines()
        .filter(|l| l.contains(" evaluated "))
        .filter_map(|l| l.split("version=").nth(1)?.split(' ').next()?.parse().ok())
        .collect();
    assert!(!evaluated.is_empty(), "{plain}");
    assert!(
        evaluated.iter().all(|v| v % 2 == 1),
        "eval-1 evaluated {evaluated:?}"
    );
}
