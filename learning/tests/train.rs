//! Training: the dynamics model learns a linear system, the critic separates two blobs, L_safety pushes the policy
//! away from what the critic marks unsafe, the critic trains on D+ and D- only, training is deterministic for a seed,
//! and the checkpoint round-trips (a resumed run continues bit for bit).

mod support;
use cabc_fixtures::training_config as config;
use cabc_learning::record::Record;
use cabc_learning::replay::Replay;
use cabc_learning::train::{critic_examples, CriticTrainer, Trainer};
use cabc_learning::{autolabel_replay, AutolabelOptions, Checkpoint, CheckpointWriter, Schedule};
use cabc_proto::config::{CriticNegatives, RunConfig, ScheduleKind};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::{train, Resumed};
use tch::{Device, Kind, Tensor};

fn segment(outcome: Outcome, steps: Vec<Step>) -> Segment {
    Segment::of("t", outcome, steps)
}

/// x' = A x + B u for a fixed A (near identity) and B.
fn linear(x: [f32; 6], u: [f32; 2]) -> [f32; 6] {
    let mut n = [0.0; 6];
    for k in 0..6 {
        n[k] = 0.9 * x[k] + 0.1 * x[(k + 1) % 6];
    }
    n[0] += 0.5 * u[0];
    n[2] += 0.3 * u[1];
    n[4] -= 0.2 * u[0];
    n
}

fn random_steps(
    n: usize,
    rng: &mut ChaCha8Rng,
    x0: std::ops::Range<f32>,
    expert: [f32; 2],
) -> Vec<Step> {
    cabc_fixtures::random_steps(n, rng, x0, expert, linear)
}

fn replay(seed: u64) -> Replay {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut r = Replay::new(10_000, seed);
    r.add_segment(&segment(
        Outcome::Lap,
        random_steps(2048, &mut rng, -1.0..0.0, [0.5, 0.2]),
    ))
    .unwrap();
    r.add_segment(&segment(
        Outcome::Failure(EndReason::OutOfTrack),
        random_steps(2048, &mut rng, 0.3..1.5, [0.5, 0.2]),
    ))
    .unwrap();
    // A labelling that removed nothing: D- is all of D?.
    r.apply_labels(&[]);
    r
}

#[test]
fn dynamics_learns_a_linear_system() {
    let mut c = config(1);
    c.training.passes = 4;
    c.training.critic_every = 1000; // not needed here
    let r = replay(1);
    let mut t = Trainer::with_device(&c, Device::Cpu);
    let mut last = f64::INFINITY;
    for epoch in 0..6 {
        last = train(&mut t, epoch, &r).dynamics.unwrap();
    }
    // Issue 29: 4.09e-4 on the training data and 4.78e-4 / 4.79e-4 held out, under this machine's AVX2 kernels and
    // the oldest; the bounds are 5 and 10 times that.
    eprintln!("dynamics MSE {last:.2e}");
    assert!(last < 2e-3, "dynamics MSE {last}");
    // Held-out states.
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let steps = random_steps(256, &mut rng, -1.0..1.0, [0.0; 2]);
    let x: Vec<f32> = steps.iter().flat_map(|s| s.state).collect();
    let u: Vec<f32> = steps.iter().flat_map(|s| s.applied_action).collect();
    let want: Vec<f32> = steps.iter().flat_map(|s| s.next_state).collect();
    let pred = tch::no_grad(|| {
        t.dynamics().forward(
            &Tensor::from_slice(&x).view([-1, 6]),
            &Tensor::from_slice(&u).view([-1, 2]),
        )
    });
    let err = (pred - Tensor::from_slice(&want).view([-1, 6]))
        .square()
        .mean(Kind::Float)
        .double_value(&[]);
    eprintln!("held-out MSE {err:.2e}");
    assert!(err < 5e-3, "held-out MSE {err}");
}

#[test]
fn critic_separates_two_blobs() {
    let c = config(2);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let n = 1024;
    let mut x = Vec::new();
    for i in 0..2 * n {
        let centre = if i < n { -1.0 } else { 1.0 };
        x.extend((0..6).map(|_| centre + rng.gen_range(-0.8f32..0.8)));
    }
    let x = Tensor::from_slice(&x).view([-1, 6]);
    let labels = Tensor::cat(
        &[
            Tensor::ones([n as i64], (Kind::Float, Device::Cpu)),
            Tensor::zeros([n as i64], (Kind::Float, Device::Cpu)),
        ],
        0,
    );
    let mut critic = CriticTrainer::new(6, &c, Device::Cpu, 2);
    let fit = critic.fit(&x, &labels, 5, &c);
    eprintln!("critic accuracy {}", fit.accuracy);
    assert!(fit.accuracy > 0.99, "{fit:?}");
    let p = tch::no_grad(|| {
        critic
            .critic
            .probability(&Tensor::from_slice(&[-1.0f32; 6]).view([1, 6]))
    });
    eprintln!("p at the safe centre {}", p.double_value(&[0]));
    assert!(p.double_value(&[0]) > 0.95);
    let q = tch::no_grad(|| {
        critic
            .critic
            .probability(&Tensor::from_slice(&[1.0f32; 6]).view([1, 6]))
    });
    eprintln!("p at the unsafe centre {}", q.double_value(&[0]));
    assert!(q.double_value(&[0]) < 0.05);
}

/// The published policy's mean action over the D+ states whose x0 lies in `x0`.
fn mean_action(t: &Trainer, r: &Replay, x0: std::ops::Range<f32>) -> [f64; 2] {
    let states: Vec<[f32; 6]> = r
        .plus
        .states
        .iter()
        .filter(|s| x0.contains(&s[0]))
        .copied()
        .collect();
    let a = t.deployed_policy().act_states(&states).unwrap();
    let n = a.len() as f64;
    assert!(n > 100.0, "{n} states in {x0:?}");
    [
        a.iter().map(|v| v[0] as f64).sum::<f64>() / n,
        a.iter().map(|v| v[1] as f64).sum::<f64>() / n,
    ]
}

#[test]
fn safety_term_pushes_the_policy_away_from_unsafe_states() {
    // D+ has x0 in [-1, 0], D- x0 in [0.3, 1.5]; the expert's u0 = 0.5 moves x0 towards D- (x0' = 0.9 x0 + 0.1 x1
    // + 0.5 u0), and u1 barely matters. L_safety must lower u0 where it matters, on the D+ states whose next state
    // under the expert's action reaches the critic's boundary (x0 > -0.25: x0' up to 0.35), by a clear margin
    // (size), and leave u1 alone. Far from D- (x0 < -0.75: x0' below -0.3) the critic is flat and the effect small.
    // Issue 29: the old measure, u0's mean over all of D+, moved by only 0.10 to 0.11 (the effect diluted by the far
    // states) and missed a fixed 0.1 on one machine. Near D- the effect is 0.299 under ATEN_CPU_CAPABILITY=avx2 and
    // avx512 (the same numbers) and 0.312 under default with MKL_ENABLE_INSTRUCTIONS=AVX; far from it -0.009 and
    // -0.007. The margins are a third of the near effect, and half of it for the far one.
    let r = replay(3);
    let train = |lambda: f64| {
        let mut c = config(3);
        c.algorithm.lambda = lambda;
        c.training.passes = 3;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let mut last = None;
        for epoch in 0..12 {
            last = Some(train(&mut t, epoch, &r));
        }
        (
            mean_action(&t, &r, -0.25..0.0),
            mean_action(&t, &r, -1.0..-0.75),
            last.unwrap(),
        )
    };
    let (bc, bc_far, bc_losses) = train(0.0);
    let (ca, ca_far, ca_losses) = train(10.0);
    let (near, far) = (bc[0] - ca[0], bc_far[0] - ca_far[0]);
    eprintln!("L_safety lowers u0 by {near:.3} near D- and by {far:.3} far from it (BC {bc:?}, CA {ca:?})");
    assert!(!bc_losses.safety_active && bc_losses.safety == 0.0);
    assert!(ca_losses.safety_active && ca_losses.safety > 0.0);
    assert!(ca_losses.critic_accuracy.unwrap() > 0.95, "{ca_losses:?}");
    assert!(
        (bc[0] - 0.5).abs() < 0.05 && (bc[1] - 0.2).abs() < 0.05,
        "baseline clones the expert: {bc:?}"
    );
    assert!(
        near > 0.1,
        "u0 must move away from the unsafe side near D-: CA {ca:?}, BC {bc:?}"
    );
    assert!(
        far.abs() < near / 2.0,
        "L_safety acts where the next state nears D-, not far from it: {far} against {near}"
    );
    assert!(ca[0] > -1.5, "and not without bound: {ca:?}");
    assert!(
        ca_losses.imitation > bc_losses.imitation,
        "the price is imitation: {ca_losses:?} {bc_losses:?}"
    );
}

#[test]
fn training_is_deterministic_for_a_seed() {
    let r = replay(4);
    let run = |seed: u64| {
        let mut c = config(seed);
        c.algorithm.lambda = 1.0;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let losses: Vec<_> = (0..2).map(|e| train(&mut t, e, &r)).collect();
        (
            t.policy_bytes(),
            losses
                .iter()
                .map(|l| (l.imitation, l.safety, l.dynamics, l.critic))
                .collect::<Vec<_>>(),
        )
    };
    let a = run(4);
    let b = run(4);
    assert_eq!(a.1, b.1);
    assert!(a.0 == b.0, "same seed, same weights");
    assert!(run(5).0 != a.0);
}

#[test]
fn trainer_save_and_load_round_trip() {
    let r = replay(6);
    let c = config(6);
    let mut t = Trainer::new(&c).unwrap();
    t.train_epoch(0, &r, &mut Record::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint");
    CheckpointWriter::new(&path)
        .files(t.to_checkpoint())
        .commit()
        .unwrap();
    let ck = Checkpoint::open(&path).unwrap();
    let back = Trainer::resume(&c, &ck).unwrap();
    assert!(back.policy_bytes() == t.policy_bytes());
    assert_eq!(back.epochs_trained, 1);
    assert_eq!(back.critic_trained(), t.critic_trained());
    assert_eq!(back.policy_architecture(), "policy-state-mlp-3x128");
    // Another architecture's checkpoint is refused.
    let mut other = c.clone();
    other.networks.policy.width = 64;
    assert!(Trainer::resume(&other, &ck).is_err());
    // Before any labelling D- is empty, and the critic does not train.
    let mut unlabelled = Replay::new(10_000, 6);
    for store in [&r.plus, &r.uncertain] {
        let outcome = if std::ptr::eq(store, &r.plus) {
            Outcome::Lap
        } else {
            Outcome::Failure(EndReason::Spin)
        };
        let steps = (0..store.len())
            .map(|i| {
                let (x, u) = (store.states[i], store.applied_actions[i]);
                cabc_fixtures::step(x, store.expert_actions[i], u, store.next_states[i])
            })
            .collect();
        unlabelled.add_segment(&segment(outcome, steps)).unwrap();
    }
    let mut fresh = Trainer::new(&c).unwrap();
    let l = train(&mut fresh, 0, &unlabelled);
    assert_eq!((unlabelled.len_minus(), l.critic), (0, None));
    assert!(!fresh.critic_trained());
}

/// Issue 13: k epochs, a checkpoint, a resume into a new trainer and one more epoch give, bit for bit, the losses and
/// the networks of k + 1 uninterrupted epochs: Adam's moments and step counts travel in the checkpoint. Without them
/// (an older checkpoint) the trainer still resumes, with fresh moments, and drifts from the uninterrupted run.
#[test]
fn resume_continues_bit_for_bit() {
    let r = replay(8);
    let mut c = config(8);
    c.algorithm.lambda = 1.0;
    let k = 2;
    let nets = |t: &Trainer| {
        use cabc_models::Network;
        [
            t.policy_bytes(),
            t.dynamics().to_bytes(),
            t.critic().to_bytes(),
        ]
    };
    let run = Resumed::run(&c, &r, k);
    assert_eq!(run.losses, run.straight_losses);
    assert!(
        nets(&run.resumed) == nets(&run.straight),
        "the resumed networks differ"
    );
    let (path, straight, straight_losses) = (run.checkpoint(), &run.straight, &run.straight_losses);

    // An older checkpoint, without the optimiser states: it loads, and the moments restart.
    for name in [
        "policy.adam.safetensors",
        "dynamics.adam.safetensors",
        "critic.adam.safetensors",
    ] {
        std::fs::remove_file(path.join(name)).unwrap();
    }
    let mut old = Trainer::resume(&c, &Checkpoint::open(&path).unwrap()).unwrap();
    let l = train(&mut old, k, &r);
    assert_ne!(l.imitation, straight_losses[k as usize].imitation);
    assert!(old.policy_bytes() != straight.policy_bytes());
}

/// Issue 10: with critic_every = 1 and autolabel_every = 3 the critic trains every epoch, and D? points that arrived
/// after the last labelling must never be among its negatives: its training set is D+ then the D- snapshot.
#[test]
fn the_critic_trains_on_d_plus_and_the_labelled_d_minus_only() {
    let mut c = config(7);
    c.training.schedule = ScheduleKind::Paper;
    c.training.critic_every = 1;
    c.training.dynamics_every = 1000;
    c.training.aux_passes = 1;
    c.training.initial_passes = 1;
    c.algorithm.autolabel_every = 3;
    let schedule = Schedule::from_config(&c);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut r = Replay::new(100_000, 7);
    r.add_segment(&segment(
        Outcome::Lap,
        random_steps(512, &mut rng, -1.0..0.0, [0.5, 0.2]),
    ))
    .unwrap();
    let mut t = Trainer::with_device(&c, Device::Cpu);
    let (mut snapshot, mut labelled_at) = (Vec::new(), 0);
    let mut trained = 0;
    for epoch in 0..7u64 {
        // Epoch e's new D? points sit at x0 in [10 + e, 10.5 + e): far from D+, so labelling keeps them.
        let e = epoch as f32;
        r.add_segment(&segment(
            Outcome::Failure(EndReason::OutOfTrack),
            random_steps(40, &mut rng, 10.0 + e..10.5 + e, [0.5, 0.2]),
        ))
        .unwrap();
        if schedule.autolabel_due(epoch) {
            let report = autolabel_replay(&r, &AutolabelOptions::from_config(&c));
            r.apply_labels(&report.removed);
            snapshot = r.uncertain.states.clone();
            labelled_at = epoch;
        }
        // More D? points after the labelling, before training.
        r.add_segment(&segment(
            Outcome::Failure(EndReason::OutOfTrack),
            random_steps(40, &mut rng, 20.0 + e..20.5 + e, [0.5, 0.2]),
        ))
        .unwrap();
        assert!(r.len_uncertain() > r.len_minus());
        let (x, labels) = critic_examples(
            &r,
            CriticNegatives::DMinus,
            c.algorithm.negative_label,
            Device::Cpu,
        );
        let rows: Vec<f32> = Vec::try_from(x.view(-1)).unwrap();
        let want: Vec<f32> = r
            .plus
            .states
            .iter()
            .chain(&snapshot)
            .flatten()
            .copied()
            .collect();
        assert!(
            rows == want,
            "epoch {epoch}: the critic's set is D+ and the D- snapshot"
        );
        let negatives: Vec<f32> = Vec::try_from(labels.view(-1)).unwrap();
        assert_eq!(negatives.len(), r.len_plus() + snapshot.len());
        assert!(negatives[r.len_plus()..]
            .iter()
            .all(|&l| l == c.algorithm.negative_label as f32));
        // No negative came in after the last labelling (at epoch L: bands 20 + e for e >= L, 10 + e for e > L).
        let l0 = labelled_at as f32;
        let late = rows
            .chunks_exact(6)
            .skip(r.len_plus())
            .filter(|s| s[0] >= 20.0 + l0 || (s[0] >= 10.0 + l0 + 0.75 && s[0] < 20.0));
        assert_eq!(late.count(), 0, "epoch {epoch}");
        let l = train(&mut t, epoch, &r);
        assert_eq!(r.len_minus(), snapshot.len());
        if l.critic.is_some() {
            trained += 1;
            let n = r.len_plus() + snapshot.len();
            assert_eq!(
                l.critic_samples,
                n / c.training.batch_size * c.training.batch_size
            );
        }
    }
    assert_eq!(trained, 7, "the critic trains every epoch");
}

/// Issue 12: `training.aux_max_batches` caps each fit of f_hat and p_hat at that many mini-batches, whatever
/// `aux_passes` asks; 0 leaves the paper's whole passes.
#[test]
fn aux_fits_stop_at_their_batch_cap() {
    let r = replay(8);
    let samples = |cap: usize| {
        let mut c = config(8);
        c.training.schedule = ScheduleKind::Paper;
        c.training.dynamics_every = 1;
        c.training.critic_every = 1;
        c.training.aux_passes = 3;
        c.training.aux_max_batches = cap;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let l = train(&mut t, 1, &r);
        assert!(l.critic.is_some() && l.dynamics.is_some());
        (l.dynamics_samples, l.critic_samples, l.policy_samples)
    };
    let batch = RunConfig::default().training.batch_size;
    let whole = |n: usize| 3 * (n / batch * batch);
    let (n_dynamics, n_critic) = (
        r.len_plus() + r.len_uncertain(),
        r.len_plus() + r.len_minus(),
    );
    let uncapped = samples(0);
    assert_eq!(uncapped.0, whole(n_dynamics));
    assert_eq!(uncapped.1, whole(n_critic));
    let capped = samples(7);
    assert_eq!((capped.0, capped.1), (7 * batch, 7 * batch));
    assert_eq!(capped.2, uncapped.2, "the policy's fit is not capped by it");
    assert_eq!(
        samples(10_000),
        uncapped,
        "a cap above the passes changes nothing"
    );
}

/// Issue 18 (1, 7): under the reference's full-state schedule all three networks fit every epoch, one pass each (5
/// in epoch 0), and the critic's negatives are all of D? as it is, the points added since the last labelling too.
#[test]
fn the_every_epoch_schedule_fits_all_three_every_epoch_on_all_of_d_uncertain() {
    let mut r = replay(11);
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    // Failures after the labelling: not in D-, but in D?.
    r.add_segment(&segment(
        Outcome::Failure(EndReason::Spin),
        random_steps(100, &mut rng, 2.0..3.0, [0.5, 0.2]),
    ))
    .unwrap();
    assert_eq!(r.len_uncertain(), r.len_minus() + 100);
    let mut c = RunConfig::load("v-b-ref").unwrap();
    c.run.seed = 11;
    c.training.device = "cpu".into();
    let mut t = Trainer::with_device(&c, Device::Cpu);
    let batch = c.training.batch_size;
    let whole = |n: usize| n / batch * batch;
    for epoch in 0..3 {
        let l = train(&mut t, epoch, &r);
        let passes = if epoch == 0 { 5 } else { 1 };
        assert!(
            l.dynamics.is_some() && l.critic.is_some(),
            "epoch {epoch}: {l:?}"
        );
        let n_dynamics = r.len_plus() + r.len_uncertain();
        assert_eq!(
            l.dynamics_samples,
            passes * whole(n_dynamics),
            "epoch {epoch}"
        );
        assert_eq!(l.critic_points, Some(r.len_plus() + r.len_uncertain()));
        assert_eq!(l.critic_positives, Some(r.len_plus()));
        assert_eq!(l.policy_samples, passes * whole(r.len_plus()));
        assert!(l.safety_active);
    }
    // Ours: the critic's negatives are D- alone.
    let mut ours = config(11);
    ours.algorithm.lambda = 10.0;
    let mut t = Trainer::with_device(&ours, Device::Cpu);
    let l = train(&mut t, 0, &r);
    assert_eq!(l.critic_points, Some(r.len_plus() + r.len_minus()));
}

/// Issue 18 (2): with the reference's clip scope the critic's and the dynamics model's gradients count in the policy's
/// clip (the policy trains differently, they do not change), and a resumed run still continues bit for bit: their
/// gradients travel in the checkpoint.
#[test]
fn the_reference_clip_scope_counts_the_auxiliary_gradients_and_resumes_exactly() {
    use cabc_models::Network;
    use cabc_proto::config::ClipScope;
    let r = replay(13);
    let run = |scope: ClipScope, epochs: u64| {
        let mut c = config(13);
        c.algorithm.lambda = 10.0;
        c.training.clip_scope = scope;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        for e in 0..epochs {
            t.train_epoch(e, &r, &mut Record::default()).unwrap();
        }
        (c, t)
    };
    let (_, ours) = run(ClipScope::Policy, 2);
    let (c, theirs) = run(ClipScope::PolicyCriticDynamics, 2);
    assert!(
        ours.policy_bytes() != theirs.policy_bytes(),
        "the clip changes the policy's steps"
    );
    assert!(
        ours.critic().to_bytes() == theirs.critic().to_bytes(),
        "the critic's own fit is the same"
    );
    assert!(ours.dynamics().to_bytes() == theirs.dynamics().to_bytes());
    // Checkpoint after 2 epochs, resume, one more: the same as 3 straight.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint");
    CheckpointWriter::new(&path)
        .files(theirs.to_checkpoint())
        .commit()
        .unwrap();
    let mut resumed = Trainer::resume(&c, &Checkpoint::open(&path).unwrap()).unwrap();
    let l = train(&mut resumed, 2, &r);
    let (_, mut straight) = run(ClipScope::PolicyCriticDynamics, 2);
    let m = train(&mut straight, 2, &r);
    assert_eq!(l, m);
    assert!(resumed.policy_bytes() == straight.policy_bytes());
}

/// Issue 18 (9): `training.policy_lr_gamma = 1` (the reference's vision trainer) keeps the policy's learning rate at
/// lr while the dynamics model's and the critic's decay by `lr_gamma` per fit; absent, the policy decays too.
#[test]
fn the_policys_own_gamma_holds_its_learning_rate() {
    let r = replay(14);
    let lrs = |gamma: Option<f64>| {
        let mut c = config(14);
        c.training.policy_lr_gamma = gamma;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        (0..3)
            .map(|e| {
                t.train_epoch(e, &r, &mut Record::default()).unwrap();
                t.lr_policy()
            })
            .collect::<Vec<f64>>()
    };
    let lr = RunConfig::default().training.lr;
    assert_eq!(lrs(Some(1.0)), vec![lr; 3]);
    let gamma = RunConfig::default().training.lr_gamma;
    let decayed = lrs(None);
    assert!(
        (decayed[2] - lr * gamma.powi(3)).abs() < 1e-12,
        "{decayed:?}"
    );
}

/// Issue 46: Adam over one flat buffer per network gives every epoch's losses and networks bit for bit as the step
/// parameter by parameter does, under both clip scopes (under the reference's, the critic's and the dynamics model's
/// gradients outlive their fits, take L_safety's gradient and count in the policy's clip).
#[test]
fn the_flat_step_keeps_every_bit_under_both_clip_scopes() {
    use cabc_models::Network;
    use cabc_proto::config::ClipScope;
    let r = replay(21);
    // The first epochs before any labelling: no D-, so the critic does not train and L_safety waits, while the
    // dynamics model's gradients already count in the policy's clip (the recipe's first ten epochs).
    let mut unlabelled = replay(21);
    unlabelled.apply_labels(&(0..2048).collect::<Vec<usize>>());
    for scope in [ClipScope::Policy, ClipScope::PolicyCriticDynamics] {
        let run = |per_variable: bool| {
            let mut c = RunConfig::load_variant("v-b", false).unwrap();
            c.run.seed = 21;
            c.training.device = "cpu".into();
            c.training.clip_scope = scope;
            let mut t = Trainer::with_device(&c, Device::Cpu);
            if per_variable {
                t.per_variable_steps();
            }
            let losses: Vec<String> = (0..5)
                .map(|e| {
                    let mut record = Record::default();
                    let data = if e < 2 { &unlabelled } else { &r };
                    t.train_epoch(e, data, &mut record).unwrap();
                    // What the learner does between epochs: the checkpoint and the published policy.
                    let _ = (t.to_checkpoint(), t.policy_bytes());
                    // Every column but the time.
                    format!("{record}")
                        .split(' ')
                        .filter(|cell| !cell.starts_with("train_s="))
                        .collect::<Vec<_>>()
                        .join(" ")
                })
                .collect();
            let nets = [
                t.policy_bytes(),
                t.dynamics().to_bytes(),
                t.critic().to_bytes(),
            ];
            (losses, nets)
        };
        let (flat, each) = (run(false), run(true));
        assert_eq!(flat.0, each.0, "{scope:?}: the records");
        assert!(flat.1 == each.1, "{scope:?}: the networks");
    }
}
