//! One epoch of a run's configuration, timed per phase against its floor (`cabc bench-epoch`, issue 46).
//!
//! Training: the three fits of an epoch (f_hat, eq. (15); p_hat, eq. (16); pi_theta, eq. (14) with L_safety active),
//! one pass each over a synthetic replay of the size asked ([`crate::throughput::synthetic_replay`]: D+ of `plus`
//! driving-like steps, D? a tenth of it), each split into its mini-batches' phases ([`FitProfile`]) and set against
//! its floor: the pass's multiply-adds over this core's measured GEMM rate. Collection: one step of the expert (MPCC),
//! of the policy's inference and of the simulator, whose sum times the epoch's steps is collection's floor; with
//! `--run`, a run's measured collection per step (its `metrics.csv`) beside it. Every figure is the median of
//! `repeats` timings.

use crate::throughput::synthetic_replay;
use cabc_learning::autolabel::{autolabel_replay, AutolabelOptions};
use cabc_learning::train::{profiled, FitProfile, Trainer};
use cabc_models::{Policy, PolicyArch};
use cabc_proto::config::{ClipScope, MlpSize, RunConfig, SafetyTerm};
use cabc_proto::messages::{ACTION_DIM, STATE_DIM};
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;
use tch::{Device, Kind, Tensor};

/// What `cabc bench-epoch` measures, besides the run configuration.
#[derive(Clone, Debug, clap::Args)]
pub struct EpochBenchOptions {
    /// D+ steps of the synthetic replay (D? holds a tenth of that); the recipe's D+ holds ~40,000 at epoch 50 and
    /// ~85,000 at epoch 130.
    #[arg(long, default_value_t = 40_000)]
    pub plus: usize,
    /// Timings of each figure; the median is reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// MPCC steps timed per repeat (a closed-loop drive from the fixed spawn).
    #[arg(long, default_value_t = 300)]
    pub mpcc_steps: usize,
    /// A run folder whose `metrics.csv` gives the measured collection per step, set beside its floor.
    #[arg(long)]
    pub run: Option<PathBuf>,
}

/// One phase: its median time and, where it has one, its floor.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Phase {
    pub name: String,
    /// Median wall time (s).
    pub seconds: f64,
    /// Samples (training) or steps (collection) the time covers.
    pub samples: usize,
    /// Multiply-add FLOPs of the phase (training), from the networks' sizes.
    pub flops: f64,
    /// What the phase reached: flops / seconds, in GFLOP/s.
    pub gflops: f64,
    /// The phase's floor (s): flops at this core's GEMM rate (training), the steps' parts alone (collection).
    pub floor_s: f64,
    /// seconds / floor_s.
    pub ratio: f64,
    /// The mini-batches' phases of the median repeat (training).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<FitProfile>,
}

/// The GEMM rates of this core (fp32, one thread, libtorch's kernels).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Gemm {
    /// [512, 512] x [512, 512]: the core's rate, the training floor's divisor.
    pub peak_gflops: f64,
    /// [64, 256] x [256, 256]: one of the critic's hidden layers on a mini-batch.
    pub batch_gflops: f64,
}

/// Collection's parts for one step, medians (ms).
#[derive(Clone, Debug, Default, Serialize)]
pub struct StepParts {
    pub mpcc_ms: f64,
    pub policy_ms: f64,
    pub sim_ms: f64,
    /// Their sum: a step's floor.
    pub floor_ms: f64,
    /// A run's collection per step (its epochs' median of collect_s / steps_taken), with `--run`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_ms: Option<f64>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct EpochBenchReport {
    pub run_name: String,
    pub plus: usize,
    pub uncertain: usize,
    pub repeats: usize,
    pub threads: i32,
    pub gemm: Gemm,
    /// Training's phases (one pass each), auto-labelling, and collection (an epoch's steps).
    pub phases: Vec<Phase>,
    /// The training phases together.
    pub training: Phase,
    pub step: StepParts,
}

fn median(v: Vec<f64>) -> f64 {
    cabc_proto::stats::median_of_middles(&v).unwrap_or(0.0)
}

/// The median of `repeats` timings of `f` (seconds), with the value `f` returned on the median repeat.
fn timed<R>(repeats: usize, mut f: impl FnMut() -> R) -> (f64, R) {
    let mut runs: Vec<(f64, R)> = (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            let r = f();
            (t.elapsed().as_secs_f64(), r)
        })
        .collect();
    runs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mid = runs.len() / 2;
    runs.swap_remove(mid)
}

/// Multiply-adds (x2: FLOPs) of one forward pass of an MLP from `inputs` to `outputs` through `size`'s hidden
/// layers, per sample.
pub fn mlp_flops(inputs: usize, size: MlpSize, outputs: usize) -> f64 {
    let mut dims = vec![inputs];
    dims.extend(std::iter::repeat_n(size.width, size.layers));
    dims.push(outputs);
    dims.windows(2).map(|w| 2.0 * (w[0] * w[1]) as f64).sum()
}

/// FLOPs per sample of one training step of each network: forward (F), backward to the weights (F) and to the
/// inputs (F), so 3F; the policy's under L_safety adds f_hat's and p_hat's forward and their backward to the inputs
/// (2F each), their weights' gradients too under the reference's clip scope (F each), and the hinged term's second
/// forward (F each).
pub fn fit_flops(config: &RunConfig) -> (f64, f64, f64) {
    let nets = &config.networks;
    let dynamics = mlp_flops(STATE_DIM + ACTION_DIM, nets.dynamics, STATE_DIM);
    let critic = mlp_flops(STATE_DIM, nets.critic, 1);
    let policy = mlp_flops(STATE_DIM, nets.policy, ACTION_DIM);
    let t = &config.training;
    let frozen = dynamics + critic;
    let mut safety = 2.0 * frozen;
    if t.clip_scope == ClipScope::PolicyCriticDynamics {
        safety += frozen;
    }
    if t.safety_term == SafetyTerm::Hinged {
        safety += frozen;
    }
    (3.0 * dynamics, 3.0 * critic, 3.0 * policy + safety)
}

/// GFLOP/s of `[m, k] x [k, n]` on this thread.
fn gemm_rate(m: i64, k: i64, n: i64, repeats: usize) -> f64 {
    let a = Tensor::randn([m, k], (Kind::Float, Device::Cpu));
    let b = Tensor::randn([k, n], (Kind::Float, Device::Cpu));
    let calls = ((2e8 / (2 * m * k * n) as f64) as usize).max(10);
    let (secs, _) = timed(repeats, || {
        for _ in 0..calls {
            let _ = a.matmul(&b);
        }
    });
    (2 * m * k * n) as f64 * calls as f64 / secs / 1e9
}

fn training_phase(
    name: &str,
    secs: f64,
    samples: usize,
    flops_per_sample: f64,
    gemm: f64,
) -> Phase {
    let flops = samples as f64 * flops_per_sample;
    let floor_s = flops / (gemm * 1e9);
    Phase {
        name: name.into(),
        seconds: secs,
        samples,
        flops,
        gflops: flops / secs / 1e9,
        floor_s,
        ratio: secs / floor_s,
        profile: None,
    }
}

/// The three fits of one epoch on `plus` D+ steps, medians of `repeats` (each on fresh networks).
fn training(config: &RunConfig, options: &EpochBenchOptions, gemm: f64) -> Vec<Phase> {
    let replay = synthetic_replay(options.plus, config.run.seed);
    let (dynamics_flops, critic_flops, policy_flops) = fit_flops(config);
    let mut times: [Vec<(f64, usize, FitProfile)>; 3] = Default::default();
    for _ in 0..options.repeats.max(1) {
        let mut trainer = Trainer::with_device(config, Device::Cpu);
        let mut fit = |i: usize, f: &mut dyn FnMut(&mut Trainer) -> usize| {
            let t = Instant::now();
            let (samples, profile) = profiled(|| f(&mut trainer));
            times[i].push((t.elapsed().as_secs_f64(), samples, profile));
        };
        fit(0, &mut |tr| {
            tr.fit_dynamics(&replay, 1).map_or(0, |f| f.samples)
        });
        fit(1, &mut |tr| {
            tr.fit_critic(&replay, 1).map_or(0, |f| f.samples)
        });
        fit(2, &mut |tr| {
            tr.set_critic_trained(true);
            tr.fit_policy(&replay, 1).map_or(0, |f| f.samples)
        });
    }
    let names = ["dynamics", "critic", "policy"];
    let flops = [dynamics_flops, critic_flops, policy_flops];
    times
        .into_iter()
        .enumerate()
        .map(|(i, mut runs)| {
            runs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (secs, samples, profile) = runs[runs.len() / 2];
            let mut phase = training_phase(names[i], secs, samples, flops[i], gemm);
            phase.profile = Some(profile);
            phase
        })
        .collect()
}

/// A step's parts: the MPCC expert's step, the policy's inference on one state, the simulator's step.
fn step_parts(config: &RunConfig, options: &EpochBenchOptions) -> anyhow::Result<StepParts> {
    let mpcc = cabc_expert::mpcc::Mpcc::from_config(config)?;
    let plant = cabc_sim::vehicle::VehicleParams::default();
    let mut p50s = Vec::new();
    for _ in 0..options.repeats.max(1) {
        let report = cabc_expert::bench::bench(&mpcc, &plant, options.mpcc_steps)?;
        p50s.push(report.p50.as_secs_f64() * 1e3);
    }
    let policy = Policy::new(
        PolicyArch::from_config(config),
        Device::Cpu,
        config.run.seed,
    );
    let state = [[1.5, 0.0, 0.0, 1.0, 0.0, 0.0]];
    const CALLS: usize = 2_000;
    let (policy_s, _) = timed(options.repeats, || {
        for _ in 0..CALLS {
            let _ = policy.act_states(&state);
        }
    });
    let sim_ms = 1e3 / cabc_sim::bench::run(1.0).env_steps_per_s;
    let mpcc_ms = median(p50s);
    let policy_ms = policy_s / CALLS as f64 * 1e3;
    let measured_ms = match &options.run {
        Some(run) => Some(measured_step_ms(run)?),
        None => None,
    };
    Ok(StepParts {
        mpcc_ms,
        policy_ms,
        sim_ms,
        floor_ms: mpcc_ms + policy_ms + sim_ms,
        measured_ms,
    })
}

/// A run's collection per step: the median over its epochs of collect_s / steps_taken (ms).
fn measured_step_ms(run: &std::path::Path) -> anyhow::Result<f64> {
    use anyhow::Context;
    let path = run.join(cabc_outputs::RunDir::METRICS);
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let (header, rows) = cabc_learning::record::csv_rows(&text)
        .with_context(|| format!("reading {}", path.display()))?;
    let column = |name: &str| header.iter().position(|h| *h == name);
    let (Some(collect), Some(taken)) = (column("collect_s"), column("steps_taken")) else {
        anyhow::bail!("{}: no collect_s or steps_taken column", path.display());
    };
    let cell = |row: &[&str], i: usize| row[i].parse::<f64>().ok();
    let per_step: Vec<f64> = rows
        .iter()
        .filter_map(|(_, r)| Some(cell(r, collect)? / cell(r, taken).filter(|&n| n > 0.0)?))
        .collect();
    anyhow::ensure!(
        !per_step.is_empty(),
        "{}: no epoch with collect_s and steps_taken",
        path.display()
    );
    Ok(median(per_step) * 1e3)
}

/// `cabc bench-epoch`: an epoch of `config` timed per phase against its floor.
pub fn run(config: &RunConfig, options: &EpochBenchOptions) -> anyhow::Result<EpochBenchReport> {
    cabc_models::flush_denormals();
    tch::set_num_threads(1);
    let gemm = Gemm {
        peak_gflops: gemm_rate(512, 512, 512, options.repeats),
        batch_gflops: gemm_rate(64, 256, 256, options.repeats),
    };
    let mut phases = training(config, options, gemm.peak_gflops);
    let sum = |f: fn(&Phase) -> f64| phases.iter().map(f).sum::<f64>();
    let training = Phase {
        name: "training".into(),
        seconds: sum(|p| p.seconds),
        samples: phases.iter().map(|p| p.samples).sum(),
        flops: sum(|p| p.flops),
        gflops: sum(|p| p.flops) / sum(|p| p.seconds) / 1e9,
        floor_s: sum(|p| p.floor_s),
        ratio: sum(|p| p.seconds) / sum(|p| p.floor_s),
        profile: None,
    };
    let replay = synthetic_replay(options.plus, config.run.seed);
    let labelling = AutolabelOptions::from_config(config);
    let (autolabel_s, _) = timed(options.repeats, || autolabel_replay(&replay, &labelling));
    phases.push(Phase {
        name: "autolabel".into(),
        seconds: autolabel_s,
        samples: replay.len_uncertain(),
        ..Default::default()
    });
    let step = step_parts(config, options)?;
    let steps = config.collection.steps_per_epoch as usize;
    let seconds = step.measured_ms.unwrap_or(f64::NAN) * 1e-3 * steps as f64;
    let floor_s = step.floor_ms * 1e-3 * steps as f64;
    phases.push(Phase {
        name: "collection".into(),
        seconds,
        samples: steps,
        floor_s,
        ratio: seconds / floor_s,
        ..Default::default()
    });
    Ok(EpochBenchReport {
        run_name: config.run.name.clone(),
        plus: replay.len_plus(),
        uncertain: replay.len_uncertain(),
        repeats: options.repeats.max(1),
        threads: tch::get_num_threads(),
        gemm,
        phases,
        training,
        step,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_mlps_flops_are_twice_its_multiply_adds() {
        let size = MlpSize {
            layers: 2,
            width: 4,
        };
        // 3x4 + 4x4 + 4x1 = 32 multiply-adds.
        assert_eq!(mlp_flops(3, size, 1), 64.0);
    }

    #[test]
    fn the_policys_flops_grow_with_the_safety_terms_networks() {
        let mut config = RunConfig::default();
        config.training.clip_scope = ClipScope::Policy;
        let (d, c, p) = fit_flops(&config);
        let nets = &config.networks;
        let policy = mlp_flops(STATE_DIM, nets.policy, ACTION_DIM);
        assert_eq!(p, 3.0 * policy + 2.0 * (d + c) / 3.0);
        config.training.clip_scope = ClipScope::PolicyCriticDynamics;
        assert_eq!(fit_flops(&config).2, 3.0 * policy + (d + c));
    }
}
