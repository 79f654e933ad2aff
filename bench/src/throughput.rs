//! Throughput figures: auto-labelling queries per second and training samples per second per network
//! (`cabc bench`; the figures in learner/README.md come from here).
//!
//! The auto-labelling data is shaped like driving data on the 17.46 m track (simulator.md 2.1): D+ lies close to a
//! closed 1-d curve parameterised by the arc length s (speed, yaw rate and lateral offset vary with s), with noise;
//! D? is the same curve with more spread (failed laps wander) plus a few percent uniform in the state box.

use cabc_learning::autolabel::{autolabel, AutolabelOptions};
use cabc_learning::record::Record;
use cabc_learning::replay::Replay;
use cabc_learning::train::{CriticTrainer, Trainer};
use cabc_models::cuda_available;
use cabc_proto::config::{RunConfig, ScheduleKind};
use cabc_proto::messages::{Outcome, Segment, Step, STATE_DIM};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;
use tch::{Device, Kind, Tensor};

/// Track length (m), simulator.md 2.1.
const TRACK_LENGTH: f64 = 17.461_412_207_630_154;

/// What `cabc bench` measures (also its command-line arguments).
#[derive(Clone, Debug, Serialize, Deserialize, clap::Args)]
pub struct BenchOptions {
    /// D+ size for the auto-labelling figures.
    #[arg(long = "plus", default_value_t = 100_000)]
    pub n_plus: usize,
    /// D? size for the auto-labelling figures.
    #[arg(long = "uncertain", default_value_t = 20_000)]
    pub n_uncertain: usize,
    /// Training samples (D+ size) for the throughput figures.
    #[arg(long = "train", default_value_t = 100_000)]
    pub n_train: usize,
    /// Seed of the synthetic data.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// `--cpu-only`: skip the CUDA training figures even when a GPU is present (`cuda`: run them).
    #[arg(long = "cpu-only", action = clap::ArgAction::SetFalse)]
    pub cuda: bool,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            n_plus: 100_000,
            n_uncertain: 20_000,
            n_train: 100_000,
            seed: 1,
            cuda: true,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TrainFigures {
    pub device: String,
    /// Samples per second of one fit pass, per network.
    pub policy_bc: f64,
    pub policy_ca: f64,
    pub dynamics: f64,
    pub critic: f64,
    /// Seconds of one full-state epoch (all three networks, one pass each) over `n_train` D+ samples.
    pub epoch_seconds: f64,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct BenchReport {
    pub n_plus: usize,
    pub n_uncertain: usize,
    pub rho: f64,
    pub autolabel_seconds: f64,
    pub autolabel_queries_per_second: f64,
    pub removed: usize,
    pub mean_neighbours: f64,
    pub undecided: usize,
    pub threads: usize,
    pub train: Vec<TrainFigures>,
}

/// A driving-like state at arc length s, with noise of scale `spread`.
fn driving_state(s: f64, spread: f64, rng: &mut ChaCha8Rng) -> [f64; STATE_DIM] {
    let phase = 2.0 * std::f64::consts::PI * s / TRACK_LENGTH;
    let mut n = |scale: f64| spread * scale * (rng.gen::<f64>() * 2.0 - 1.0);
    [
        1.8 + 0.6 * (3.0 * phase).cos() + n(0.3),
        0.05 * (2.0 * phase).sin() + n(0.05),
        1.5 * (2.0 * phase).sin() + n(0.4),
        s,
        0.25 * (3.0 * phase).sin() + n(0.2),
        0.15 * (2.0 * phase).cos() + n(0.1),
    ]
}

/// D+ and D? of the benchmark (row-major, 6 values per state).
pub fn driving_like(n_plus: usize, n_uncertain: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut plus = Vec::with_capacity(n_plus * STATE_DIM);
    for _ in 0..n_plus {
        let s = rng.gen_range(0.0..TRACK_LENGTH);
        plus.extend(driving_state(s, 1.0, &mut rng));
    }
    let mut uncertain = Vec::with_capacity(n_uncertain * STATE_DIM);
    for i in 0..n_uncertain {
        if i % 20 == 0 {
            // Uniform in the state box.
            let lo = [0.25, -0.5, -4.0, 0.0, -0.85, -1.57];
            let hi = [3.5, 0.5, 4.0, TRACK_LENGTH, 0.85, 1.57];
            uncertain.extend((0..STATE_DIM).map(|k| rng.gen_range(lo[k]..hi[k])));
        } else {
            let s = rng.gen_range(0.0..TRACK_LENGTH);
            uncertain.extend(driving_state(s, 2.0, &mut rng));
        }
    }
    (plus, uncertain)
}

/// A replay whose D+ holds `n` driving-like steps (and D? a tenth of that, all of it D-: a labelling that removed
/// nothing), for the training figures.
pub fn synthetic_replay(n: usize, seed: u64) -> Replay {
    let (plus, uncertain) = driving_like(n, n / 10, seed);
    let mut replay = Replay::new(n.max(1), seed);
    let step = |x: &[f64]| {
        let state: [f32; STATE_DIM] = std::array::from_fn(|k| x[k] as f32);
        let mut next = state;
        next[3] += 0.1 * state[0];
        Step {
            state,
            pose: [0.0; 3],
            image: None,
            expert_action: [0.2 * (1.8 - state[0]), -0.5 * state[4] - 0.8 * state[5]],
            applied_action: [0.2 * (1.8 - state[0]), -0.5 * state[4] - 0.8 * state[5]],
            next_state: next,
            expert_ok: true,
        }
    };
    for (points, outcome) in [(&plus, Outcome::Lap), (&uncertain, Outcome::ExpertFailure)] {
        let steps = points.chunks_exact(STATE_DIM).map(step).collect();
        let segment = Segment::of("bench", outcome, steps);
        replay.add_segment(&segment).expect("state-only steps");
    }
    replay.apply_labels(&[]);
    replay
}

/// Samples per second of `f`, which trains on `samples` samples.
fn rate(samples: usize, f: impl FnOnce()) -> f64 {
    let t = Instant::now();
    f();
    samples as f64 / t.elapsed().as_secs_f64()
}

fn train_figures(device: Device, n_train: usize, seed: u64) -> TrainFigures {
    let mut config = RunConfig::default();
    config.run.seed = seed;
    config.training.schedule = ScheduleKind::EveryEpoch;
    let replay = synthetic_replay(n_train, seed);
    let mut trainer = Trainer::with_device(&config, device);
    let n = replay.len_plus();
    let mut fig = TrainFigures {
        device: format!("{device:?}"),
        ..Default::default()
    };
    fig.policy_bc = rate(n, || {
        trainer.fit_policy(&replay, 1).expect("state policy");
    });
    let n_dynamics = replay.len_plus() + replay.len_uncertain() + replay.len_dynamics_only();
    fig.dynamics = rate(n_dynamics, || {
        trainer.fit_dynamics(&replay, 1);
    });
    let x = Tensor::from_slice(replay.plus.states.as_flattened())
        .view([-1, 6])
        .to_device(device);
    let labels = Tensor::ones([n as i64], (Kind::Float, device));
    let mut critic = CriticTrainer::new(STATE_DIM, &config, device, seed);
    fig.critic = rate(n, || {
        critic.fit(&x, &labels, 1, &config);
    });
    trainer.set_critic_trained(true);
    fig.policy_ca = rate(n, || {
        trainer.fit_policy(&replay, 1).expect("state policy");
    });
    let mut fresh = Trainer::with_device(&config, device);
    let t = Instant::now();
    fresh
        .train_epoch(1, &replay, &mut Record::default())
        .expect("trains");
    fig.epoch_seconds = t.elapsed().as_secs_f64();
    fig
}

/// Runs the benchmark and prints one line per figure.
pub fn run_bench(options: &BenchOptions) -> BenchReport {
    let config = RunConfig::default();
    let (plus, uncertain) = driving_like(options.n_plus, options.n_uncertain, options.seed);
    let labels = autolabel(
        &plus,
        &uncertain,
        STATE_DIM,
        &AutolabelOptions::from_config(&config),
    );
    let mut report = BenchReport {
        n_plus: options.n_plus,
        n_uncertain: options.n_uncertain,
        rho: labels.rho,
        autolabel_seconds: labels.seconds,
        autolabel_queries_per_second: options.n_uncertain as f64 / labels.seconds,
        removed: labels.removed.len(),
        mean_neighbours: labels.mean_neighbours,
        undecided: labels.undecided,
        threads: rayon::current_num_threads(),
        train: Vec::new(),
    };
    println!(
        "autolabel: |D+| = {}, |D?| = {}, rho = {}, {} threads: {:.2} s, {:.0} queries/s, {:.0} neighbours/query, \
         {} removed, {} undecided",
        report.n_plus,
        report.n_uncertain,
        report.rho,
        report.threads,
        report.autolabel_seconds,
        report.autolabel_queries_per_second,
        report.mean_neighbours,
        report.removed,
        report.undecided
    );
    let mut devices = vec![Device::Cpu];
    if options.cuda && cuda_available() {
        devices.push(Device::Cuda(0));
    }
    for device in devices {
        let f = train_figures(device, options.n_train, options.seed);
        println!(
            "train on {}: policy (BC) {:.0} samples/s, policy (CA) {:.0} samples/s, dynamics {:.0} samples/s, \
             critic {:.0} samples/s; full-state epoch over {} samples: {:.2} s",
            f.device, f.policy_bc, f.policy_ca, f.dynamics, f.critic, options.n_train, f.epoch_seconds
        );
        report.train.push(f);
    }
    report
}
