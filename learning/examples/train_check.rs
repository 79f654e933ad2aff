//! `cargo run --release --example train_check`: trains a few epochs of `Trainer::train_epoch` on a
//! synthetic replay from fixed seeds (state and camera policies, both schedules, auto-labelling in between) and prints
//! every metric of each epoch's record with its floats' bits, so that two builds can be compared with `diff`
//! (refactors that must not change behaviour).

use cabc_learning::record::Record;
use cabc_learning::{autolabel_replay, AutolabelOptions, Replay, Trainer};
use cabc_proto::config::{ObservationKind, RunConfig, ScheduleKind, VisionTrunk};
use cabc_proto::messages::{EndReason, Image, Outcome, Segment, Step};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::Device;

fn steps(n: usize, rng: &mut ChaCha8Rng, x0: f32, camera: bool) -> Vec<Step> {
    (0..n)
        .map(|_| {
            let mut state: [f32; 6] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
            state[0] += x0;
            let applied = [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)];
            let mut next = state;
            for (k, v) in next.iter_mut().enumerate() {
                *v = 0.9 * *v + 0.1 * applied[k % 2];
            }
            Step {
                state,
                pose: [0.0; 3],
                image: camera.then(|| Image {
                    width: 32,
                    height: 32,
                    rgb: (0..32 * 32 * 3).map(|_| rng.gen()).collect(),
                }),
                expert_action: [0.5 - 0.2 * state[0], 0.1 * state[4]],
                applied_action: applied,
                next_state: next,
                expert_ok: true,
            }
        })
        .collect()
}

fn segment(outcome: Outcome, steps: Vec<Step>) -> Segment {
    Segment::of("c", outcome, steps)
}

fn show(name: &str, record: &Record) {
    let values: Vec<String> = record
        .iter()
        .filter(|(metric, _)| *metric != "train_s")
        .map(|(metric, v)| format!("{metric} {:e}/{:016x}", v.as_f64(), v.as_f64().to_bits()))
        .collect();
    println!("{name} {}", values.join(" "));
}

fn run(name: &str, config: &RunConfig, epochs: u64, per_epoch: usize, camera: bool) {
    let mut rng = ChaCha8Rng::seed_from_u64(config.run.seed);
    let mut replay = Replay::new(3 * per_epoch, config.run.seed);
    let mut trainer = Trainer::with_device(config, Device::Cpu);
    let options = AutolabelOptions::from_config(config);
    for epoch in 0..epochs {
        for (outcome, x0) in [
            (Outcome::Lap, -0.5),
            (Outcome::Failure(EndReason::OutOfTrack), 0.3),
            (Outcome::Incomplete, 0.0),
        ] {
            replay
                .add_segment(&segment(outcome, steps(per_epoch, &mut rng, x0, camera)))
                .unwrap();
        }
        if trainer.schedule().autolabel_due(epoch) && replay.len_uncertain() > 0 {
            let report = autolabel_replay(&replay, &options);
            println!(
                "{name} epoch {epoch} labelled: removed {}",
                report.removed.len()
            );
            replay.apply_labels(&report.removed);
        }
        let mut record = Record::new(epoch);
        trainer.train_epoch(epoch, &replay, &mut record).unwrap();
        show(name, &record);
    }
    let w = trainer.policy_bytes();
    let sum: u64 = w.iter().map(|&b| b as u64).sum();
    println!("{name} policy bytes {} sum {sum}", w.len());
}

fn main() {
    let mut c = RunConfig::default();
    c.run.seed = 11;
    c.training.device = "cpu".into();
    c.algorithm.lambda = 1.0;
    c.algorithm.rho = 1.5;
    c.training.initial_passes = 2;
    c.training.aux_passes = 2;
    c.training.dynamics_every = 2;
    c.training.critic_every = 3;
    c.algorithm.autolabel_every = 3;
    run("paper", &c, 8, 200, false);

    let mut e = c.clone();
    e.run.seed = 12;
    e.training.schedule = ScheduleKind::EveryEpoch;
    e.algorithm.autolabel_every = 1;
    run("every-epoch", &e, 4, 200, false);

    let mut v = c.clone();
    v.run.seed = 13;
    v.observation.kind = ObservationKind::Camera;
    v.observation.trunk = VisionTrunk::SmallCnn;
    v.training.critic_every = 2;
    v.algorithm.autolabel_every = 2;
    run("camera", &v, 4, 100, true);
}
