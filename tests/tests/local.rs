//! `learner run --local` (issue 22): Algorithm 1 in one process, no bus. For a seed it gives the distributed run's
//! numbers: the same data, losses and evaluations, epoch by epoch. It also completes the camera smoke preset.

use cabc_tests::Cluster;
use std::time::Duration;

fn csv_rows(path: &std::path::Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// The columns of a run's table that depend on its data and training alone (not on timing).
fn numbers(path: &std::path::Path, names: &[&str]) -> Vec<Vec<String>> {
    let rows = csv_rows(path);
    let idx: Vec<usize> = names
        .iter()
        .map(|n| {
            rows[0]
                .iter()
                .position(|h| h == n)
                .unwrap_or_else(|| panic!("no column {n}"))
        })
        .collect();
    rows[1..]
        .iter()
        .map(|r| idx.iter().map(|&i| r[i].clone()).collect())
        .collect()
}

/// Adds `line` to table `[table]` of the cluster's configuration file.
fn set_in(cluster: &Cluster, table: &str, line: &str) {
    let header = format!("[{table}]\n");
    let text = std::fs::read_to_string(&cluster.config).unwrap();
    let text = text.replacen(&header, &format!("{header}{line}\n"), 1);
    std::fs::write(&cluster.config, text).unwrap();
}

/// `learner run --local` of a cluster named `local` (configured by `configure`) to its summary of `epochs` epochs:
/// the cluster and the summary.
fn local_run(
    dir: &std::path::Path,
    epochs: u64,
    extra: &str,
    configure: impl Fn(&Cluster),
) -> (Cluster, serde_json::Value) {
    let mut local = Cluster::new(dir, "local", epochs, extra).unwrap();
    configure(&local);
    let (config, run_dir) = (
        local.config.display().to_string(),
        local.dir.display().to_string(),
    );
    local
        .start(
            "learner",
            "learner",
            &["run", "--local", "--config", &config, "--run-dir", &run_dir],
        )
        .unwrap();
    let summary = local.summary("learner");
    assert_eq!(summary["epochs"], epochs);
    (local, summary)
}

const METRICS: &[&str] = &[
    "epoch",
    "steps_collected",
    "segments",
    "d_plus",
    "d_uncertain",
    "d_minus",
    "dynamics_only",
    "imitation_loss",
    "safety_loss",
    "dynamics_loss",
    "critic_loss",
    "uncertain_truncating",
    "expert_failures",
];

/// Issue 56: a local run's `metrics.csv` says where each epoch's collection went. The phases are parts of
/// `collect_s` (the collectors' steps), and the evaluation, which runs beside them, is over before the epoch closes.
fn collection_times_lie_within_collect_s(metrics: &std::path::Path) {
    let phases = [
        "collect_observe_s",
        "collect_policy_s",
        "collect_expert_s",
        "collect_step_s",
        "collect_store_s",
    ];
    let names: Vec<&str> = ["collect_s", "evaluate_s"]
        .into_iter()
        .chain(phases)
        .collect();
    let rows = numbers(metrics, &names);
    for row in &rows {
        let v: Vec<f64> = row.iter().map(|c| c.parse().unwrap()).collect();
        let (collect, evaluate, parts) = (v[0], v[1], &v[2..]);
        assert!(parts.iter().all(|&s| s >= 0.0), "{names:?}: {v:?}");
        // Each figure is rounded to the millisecond.
        assert!(
            parts.iter().sum::<f64>() <= collect + 0.003,
            "{names:?}: {v:?}"
        );
        assert!(
            (0.0..=collect + 0.001).contains(&evaluate),
            "{names:?}: {v:?}"
        );
    }
    let total = |i: usize| {
        rows.iter()
            .map(|r| r[i].parse::<f64>().unwrap())
            .sum::<f64>()
    };
    assert!(
        total(3) > 0.0 && total(4) > 0.0,
        "the policy and the expert took time: {rows:?}"
    );
}

#[test]
fn a_local_run_gives_the_distributed_runs_numbers() {
    let tmp = cabc_tests::test_dir();
    let extra = "[actors]\ncount = 2\nenvs_per_actor = 2\n";
    let epochs = 6;
    let mut dist = Cluster::new(tmp.path(), "dist", epochs, extra).unwrap();
    dist.start_all(2, false).unwrap();
    let dist_summary = dist.summary("learner");
    assert_eq!(dist_summary["epochs"], epochs);

    let (local, local_summary) = local_run(tmp.path(), epochs, extra, |_| {});
    assert_eq!(
        local_summary["versions_not_evaluated"],
        serde_json::json!([])
    );

    let a = numbers(&dist.dir.join("metrics.csv"), METRICS);
    let b = numbers(&local.dir.join("metrics.csv"), METRICS);
    assert_eq!(a.len(), epochs as usize);
    assert_eq!(a, b, "metrics.csv: distributed (left) and local (right)");
    let evals = ["version", "laps", "end_reason", "lap_mean"];
    let a = numbers(&dist.dir.join("evals.csv"), &evals);
    let b = numbers(&local.dir.join("evals.csv"), &evals);
    assert_eq!(a, b, "evals.csv");
    collection_times_lie_within_collect_s(&local.dir.join("metrics.csv"));
    let dist_columns = &csv_rows(&dist.dir.join("metrics.csv"))[0];
    assert!(
        !dist_columns.iter().any(|c| c == "collect_policy_s"),
        "over the bus the learner cannot time the actors' phases: {dist_columns:?}"
    );
    assert!(
        std::fs::read(dist.dir.join("final-policy.safetensors")).unwrap()
            == std::fs::read(local.dir.join("final-policy.safetensors")).unwrap(),
        "the same final policy"
    );
    // Issue 19: TensorBoard events in tb/ hold every metrics.csv cell that holds a number, per epoch (with every
    // digit: the cell is rounded to its decimals).
    let tb = std::fs::read_dir(local.dir.join("tb"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let events = cabc_outputs::tensorboard::read_scalars(&std::fs::read(tb).unwrap()).unwrap();
    let rows = csv_rows(&local.dir.join("metrics.csv"));
    let mut cells = 0;
    for row in &rows[1..] {
        let epoch: i64 = row[0].parse().unwrap();
        for (name, cell) in rows[0].iter().zip(row) {
            let value = match cell.as_str() {
                "true" => 1.0,
                "false" => 0.0,
                cell => match cell.parse::<f32>() {
                    Ok(v) => v,
                    Err(_) => continue,
                },
            };
            cells += 1;
            let tag = format!("metrics/{name}");
            let decimals = cell.split_once('.').map_or(0, |(_, d)| d.len() as i32);
            let close =
                |v: f32| (v - value).abs() <= 0.5 * 10f32.powi(-decimals) + value.abs() * 1e-6;
            assert!(
                events
                    .iter()
                    .any(|(s, t, v)| *s == epoch && *t == tag && close(*v)),
                "{tag} = {value} at epoch {epoch} is not in the events"
            );
        }
    }
    assert!(cells > 25 * epochs as usize, "{cells} cells");
    assert!(events.iter().any(|(_, t, _)| t == "eval/laps"));
}

#[test]
fn a_local_run_completes_the_camera_smoke_preset() {
    let tmp = cabc_tests::test_dir();
    let mut local = Cluster::new(tmp.path(), "unused", 1, "").unwrap();
    let runs = tmp.path().display().to_string();
    let runs_dir = format!("run.runs_dir={runs:?}");
    local
        .start(
            "learner",
            "learner",
            &[
                "run",
                "--local",
                "--config",
                "smoke-camera",
                "--set",
                "run.max_epochs=2",
                "--set",
                &runs_dir,
                "--set",
                "training.device=\"cpu\"",
            ],
        )
        .unwrap();
    let (status, out) = local.wait("learner", Duration::from_secs(400)).unwrap();
    assert!(status.success(), "{}", local.log_tail("learner"));
    let summary: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(summary["epochs"], 2, "{summary:#}");
    assert!(summary["d_plus"].as_u64().unwrap() > 0, "{summary:#}");
    let metrics = tmp.path().join("smoke-camera").join("metrics.csv");
    assert_eq!(csv_rows(&metrics).len(), 3);
}

/// Issue 19: an evaluation that completes its laps leaves a video (plots/eval-v<version>.gif), and the best one is
/// best-policy.gif.
#[test]
fn an_evaluation_that_completes_its_laps_leaves_a_video() {
    let tmp = cabc_tests::test_dir();
    let mut local = Cluster::new(tmp.path(), "unused", 1, "").unwrap();
    let runs_dir = format!("run.runs_dir={:?}", tmp.path().display().to_string());
    let args = [
        "run",
        "--local",
        "--config",
        "smoke",
        "--set",
        "run.max_epochs=60",
        "--set",
        &runs_dir,
        "--set",
        "training.device=\"cpu\"",
    ];
    local.start("learner", "learner", &args).unwrap();
    let (status, out) = local.wait("learner", Duration::from_secs(400)).unwrap();
    assert!(status.success(), "{}", local.log_tail("learner"));
    let summary: serde_json::Value = serde_json::from_str(&out).unwrap();
    let first = summary["first_version_with_eval_laps"]
        .as_u64()
        .expect("the smoke run completes its laps");
    let run = tmp.path().join("smoke");
    for gif in [
        run.join("plots").join(format!("eval-v{first}.gif")),
        run.join("best-policy.gif"),
    ] {
        let bytes = std::fs::read(&gif).unwrap_or_else(|e| panic!("{}: {e}", gif.display()));
        assert!(bytes.starts_with(b"GIF89a"), "{}", gif.display());
        assert!(bytes.len() < 3 << 20, "{} bytes", bytes.len());
    }
    // `cabc video RUN` evaluates the final policy anew and writes its video.
    let out = tmp.path().join("final.gif");
    let (run_s, out_s) = (run.display().to_string(), out.display().to_string());
    local
        .start(
            "video",
            "cabc",
            &["video", &run_s, "--final", "--out", &out_s],
        )
        .unwrap();
    let (status, said) = local.wait("video", Duration::from_secs(120)).unwrap();
    assert!(status.success(), "{}", local.log_tail("video"));
    assert!(said.contains("laps, ended by"), "{said}");
    assert!(std::fs::read(&out).unwrap().starts_with(b"GIF89a"));
    // `cabc show RUN --gif VERSION` names the evaluation's video; `cabc show --config X key` prints a configuration
    // value.
    let version = first.to_string();
    local
        .start("show", "cabc", &["show", &run_s, "--gif", &version])
        .unwrap();
    let (status, said) = local.wait("show", Duration::from_secs(60)).unwrap();
    assert!(status.success(), "{}", local.log_tail("show"));
    assert!(
        said.trim().ends_with(&format!("eval-v{first}.gif")),
        "{said}"
    );
    local
        .start(
            "key",
            "cabc",
            &["show", "--config", "smoke", "actors.count"],
        )
        .unwrap();
    let (status, said) = local.wait("key", Duration::from_secs(60)).unwrap();
    assert!(
        status.success() && said.trim().parse::<u32>().is_ok(),
        "{said}"
    );
}

/// Collection overlapping training (`collection.overlap`, issue 46) over the bus: the segments that arrive while the
/// learner trains wait in the subscription's queue, and the run has the in-process run's numbers.
#[test]
fn an_overlapped_distributed_run_gives_the_local_runs_numbers() {
    let tmp = cabc_tests::test_dir();
    let extra = "[actors]\ncount = 2\nenvs_per_actor = 2\n";
    let epochs = 4;
    let overlap = |cluster: &Cluster| set_in(cluster, "collection", "overlap = true");
    let mut dist = Cluster::new(tmp.path(), "dist", epochs, extra).unwrap();
    overlap(&dist);
    dist.start_all(2, false).unwrap();
    assert_eq!(dist.summary("learner")["epochs"], epochs);
    let (local, _) = local_run(tmp.path(), epochs, extra, overlap);
    let a = numbers(&dist.dir.join("metrics.csv"), METRICS);
    let b = numbers(&local.dir.join("metrics.csv"), METRICS);
    assert_eq!(a.len(), epochs as usize);
    assert_eq!(a, b, "metrics.csv: distributed (left) and local (right)");
    let config = std::fs::read_to_string(dist.dir.join("config.toml")).unwrap();
    assert!(config.contains("overlap = true"), "{config}");
}

/// The actors solving their own relabellings (`expert.placement = "in-actor"`, issue 46): no expert server runs, and
/// the run has the numbers of the in-process run, whose actors ask the same relabelling code.
#[test]
fn actors_that_solve_their_own_relabellings_give_the_local_runs_numbers() {
    let tmp = cabc_tests::test_dir();
    let extra = "[actors]\ncount = 2\nenvs_per_actor = 2\n";
    let epochs = 4;
    let mut dist = Cluster::new(tmp.path(), "dist", epochs, extra).unwrap();
    set_in(&dist, "expert", "placement = \"in-actor\"");
    dist.start_learner("learner", false).unwrap();
    let config = dist.config.display().to_string();
    for id in ["actor-0", "actor-1"] {
        dist.start(id, "actor", &["--config", &config, "--id", id])
            .unwrap();
    }
    dist.start(
        "eval",
        "actor",
        &["--config", &config, "--id", "eval", "--eval"],
    )
    .unwrap();
    assert_eq!(dist.summary("learner")["epochs"], epochs);
    let (local, _) = local_run(tmp.path(), epochs, extra, |_| {});
    let a = numbers(&dist.dir.join("metrics.csv"), METRICS);
    let b = numbers(&local.dir.join("metrics.csv"), METRICS);
    assert_eq!(a.len(), epochs as usize);
    assert_eq!(
        a, b,
        "metrics.csv: in-actor experts (left) and local (right)"
    );
}
