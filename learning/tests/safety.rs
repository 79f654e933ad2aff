//! Issue 45: the keys of the safety term and the critic's held-out measure, each shown on a small problem.
//! * `training.clip_scope = "policy"` (Fig. 4): the policy's fit leaves f_hat's and p_hat's weights and gradients as
//!   they were; the reference's scope accumulates L_safety's gradient into them.
//! * `training.safety_states = "clone"` (eq. (14)): L_safety reaches the D? states L_clone fits.
//! * `training.safety_term = "hinged"`: no cost for an action as safe as the expert's, a smaller push than eq. (14).
//! * the critic's held-out rows (this epoch's D+ and D? rows) and its accuracy, Brier score and calibration error.
//! * `training.safety_gate`: L_safety waits for the critic's held-out balanced accuracy.

mod support;
use cabc_learning::record::Record;
use cabc_learning::replay::Replay;
use cabc_learning::train::{heldout, l_safety_hinged, Trainer};
use cabc_models::{Critic, Network};
use cabc_proto::config::{ClipScope, RunConfig, SafetyStates, SafetyTerm};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use support::{train, Resumed};
use tch::{Device, Kind, Tensor};

fn config(seed: u64) -> RunConfig {
    let mut c = cabc_fixtures::training_config(seed);
    c.algorithm.lambda = 10.0;
    c
}

/// x' = 0.9 x + 0.1 x (shifted) + B u: u0 moves x0 (towards D- when positive), u1 moves x2.
fn next(x: [f32; 6], u: [f32; 2]) -> [f32; 6] {
    let mut n: [f32; 6] = std::array::from_fn(|k| 0.9 * x[k] + 0.1 * x[(k + 1) % 6]);
    n[0] += 0.5 * u[0];
    n[2] += 0.3 * u[1];
    n
}

/// `n` steps with x0 in `x0`, the other dimensions in [-1, 1], the expert's action [0.5, 0.2], random applied actions.
fn steps(n: usize, rng: &mut ChaCha8Rng, x0: std::ops::Range<f32>) -> Vec<Step> {
    cabc_fixtures::random_steps(n, rng, x0, [0.5, 0.2], next)
}

fn lap(steps: Vec<Step>) -> Segment {
    Segment::of("t", Outcome::Lap, steps)
}

fn failure(steps: Vec<Step>) -> Segment {
    Segment::of("t", Outcome::Failure(EndReason::OutOfTrack), steps)
}

/// D+ with x0 in [-1, 0], D? = D- with x0 in [0.3, 1.5].
fn replay(seed: u64) -> Replay {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut r = Replay::new(10_000, seed);
    r.add_segment(&lap(steps(2048, &mut rng, -1.0..0.0)))
        .unwrap();
    r.add_segment(&failure(steps(1024, &mut rng, 0.3..1.5)))
        .unwrap();
    r.apply_labels(&[]);
    r
}

/// The published policy's mean u0 over `states`.
fn mean_u0(t: &Trainer, states: &[[f32; 6]]) -> f64 {
    let a = t.deployed_policy().act_states(states).unwrap();
    a.iter().map(|v| f64::from(v[0])).sum::<f64>() / a.len() as f64
}

fn near_d_minus(r: &Replay) -> Vec<[f32; 6]> {
    let near = |s: &&[f32; 6]| (-0.25..0.0).contains(&s[0]);
    r.plus.states.iter().filter(near).copied().collect()
}

/// Each variable's gradient (None where it has none).
fn grads(vars: Vec<Tensor>) -> Vec<Option<Vec<f32>>> {
    vars.iter()
        .map(|v| {
            let g = v.grad();
            g.defined()
                .then(|| Vec::<f32>::try_from(g.reshape([-1])).unwrap())
        })
        .collect()
}

/// Fig. 4: under `clip_scope = "policy"` the policy's fit with L_safety active leaves f_hat's and p_hat's weights and
/// gradients exactly as their own fits left them; under the reference's scope the weights stay too (their optimisers
/// do not step) but L_safety's gradient accumulates into theirs.
#[test]
fn the_policys_fit_leaves_the_frozen_networks_and_their_gradients_untouched() {
    let r = replay(1);
    let run = |scope: ClipScope| {
        let mut c = config(1);
        c.training.clip_scope = scope;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        t.fit_dynamics(&r, 1).unwrap();
        t.fit_critic(&r, 1).unwrap();
        let before = (
            t.dynamics().to_bytes(),
            t.critic().to_bytes(),
            grads(t.dynamics().var_store().trainable_variables()),
            grads(t.critic().var_store().trainable_variables()),
        );
        let fit = t.fit_policy(&r, 1).unwrap();
        assert!(fit.safety_active && fit.safety > 0.0, "{fit:?}");
        let after = (
            t.dynamics().to_bytes(),
            t.critic().to_bytes(),
            grads(t.dynamics().var_store().trainable_variables()),
            grads(t.critic().var_store().trainable_variables()),
        );
        (before, after)
    };
    let (before, after) = run(ClipScope::Policy);
    assert!(before.0 == after.0 && before.1 == after.1, "weights");
    assert!(before.2 == after.2, "f_hat's gradients");
    assert!(before.3 == after.3, "p_hat's gradients");
    let (before, after) = run(ClipScope::PolicyCriticDynamics);
    assert!(before.0 == after.0 && before.1 == after.1, "weights");
    assert!(
        before.2 != after.2 && before.3 != after.3,
        "the reference's scope accumulates L_safety into their gradients"
    );
}

/// `safety_states = "clone"`: with DAgger's aggregate, L_safety also acts at D?'s states, where the next state of
/// the expert's action is deep in D-, and lowers u0 there; over D+'s rows alone it acts there only through the
/// shared weights. The effect at D? is several times the far side's (measured: see the eprintln).
#[test]
fn l_safety_over_the_clone_set_reaches_the_states_near_a_failure() {
    let r = replay(2);
    let u0_at_uncertain = |states: SafetyStates| {
        let mut c = config(2);
        c.training.clone_uncertain = true;
        c.training.safety_states = states;
        c.training.passes = 3;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let mut losses = None;
        for epoch in 0..8 {
            losses = Some(train(&mut t, epoch, &r));
        }
        (mean_u0(&t, &r.uncertain.states), losses.unwrap())
    };
    let (plus, plus_losses) = u0_at_uncertain(SafetyStates::DPlus);
    let (clone, clone_losses) = u0_at_uncertain(SafetyStates::Clone);
    eprintln!("u0 at D?: {plus:.3} over D+'s rows, {clone:.3} over the clone set");
    assert!(plus_losses.safety_active && clone_losses.safety_active);
    assert!(
        clone_losses.safety > plus_losses.safety,
        "D?'s rows are the unsafe ones: {clone_losses:?} {plus_losses:?}"
    );
    assert!(
        plus - clone > 0.1,
        "u0 lower at D? when L_safety sees it: {clone} against {plus}"
    );
}

/// `safety_term = "hinged"`: zero where the action is the expert's; in training it moves u0 near D- less than eq.
/// (14)'s term (which pushes every action towards higher predicted safety, the expert's too).
#[test]
fn the_hinged_term_costs_nothing_at_the_experts_action_and_pushes_less() {
    let r = replay(3);
    let shift = |term: SafetyTerm| {
        let mut c = config(3);
        c.training.safety_term = term;
        c.training.passes = 3;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        for epoch in 0..12 {
            train(&mut t, epoch, &r);
        }
        let x = Tensor::from_slice(r.plus.states.as_flattened()).view([-1, 6]);
        let expert = Tensor::from_slice(&[0.5f32, 0.2])
            .view([1, 2])
            .repeat([x.size()[0], 1]);
        let at_expert = l_safety_hinged(t.dynamics(), t.critic(), &x, &expert, &expert, 10.0);
        assert_eq!(at_expert.double_value(&[]), 0.0, "the expert's own action");
        0.5 - mean_u0(&t, &near_d_minus(&r))
    };
    let absolute = shift(SafetyTerm::Absolute);
    let hinged = shift(SafetyTerm::Hinged);
    eprintln!("u0 below the expert's near D-: {absolute:.3} (eq. (14)), {hinged:.3} (hinged)");
    assert!(absolute > 0.1, "eq. (14) pushes: {absolute}");
    assert!(
        hinged.abs() < absolute / 2.0,
        "the hinge stops near the expert: {hinged} against {absolute}"
    );
}

/// This epoch's rows: D+'s appended ones, and D?'s, less what the epoch's labelling removed (D?'s tail, and D-'s).
#[test]
fn the_fresh_rows_are_this_epochs_d_plus_and_d_uncertain() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut r = replay(4);
    assert_eq!((r.len_plus(), r.len_minus()), (2048, 1024));
    r.begin_epoch();
    assert!(r.fresh_plus().is_empty() && r.fresh_uncertain().is_empty());
    let new_fail = steps(40, &mut rng, 0.3..1.5);
    r.add_segment(&lap(steps(100, &mut rng, -1.0..0.0)))
        .unwrap();
    r.add_segment(&failure(new_fail.clone())).unwrap();
    assert_eq!(r.fresh_plus(), 2048..2148);
    assert_eq!(
        r.fresh_uncertain(),
        1024..1064,
        "before the epoch's labelling"
    );
    // Remove 3 old D? rows and 2 new ones (D?'s rows 1024.. are the new ones).
    r.apply_labels(&[0, 5, 1000, 1024, 1030]);
    assert_eq!(r.fresh_uncertain(), 1021..1059);
    let kept: Vec<[f32; 6]> = (0..40)
        .filter(|&i| i != 0 && i != 6)
        .map(|i| new_fail[i].state)
        .collect();
    assert_eq!(&r.minus()[r.fresh_uncertain()], kept.as_slice());
    assert_eq!(&r.uncertain.states[r.fresh_uncertain()], kept.as_slice());
    r.begin_epoch();
    assert!(r.fresh_plus().is_empty() && r.fresh_uncertain().is_empty());
}

/// With every weight zero the critic says p = 0.5 everywhere: accuracy = the negatives' share (p > 0.5 is "safe"),
/// Brier 0.25, ECE |0.5 - positives' share|.
#[test]
fn the_held_out_measure_of_a_critic_that_knows_nothing() {
    let mut critic = Critic::new(6, RunConfig::default().networks.critic, Device::Cpu, 0);
    tch::no_grad(|| {
        for mut v in critic.var_store_mut().trainable_variables() {
            let _ = v.zero_();
        }
    });
    let safe = Tensor::ones([30, 6], (Kind::Float, Device::Cpu));
    let unsafe_ = Tensor::zeros([10, 6], (Kind::Float, Device::Cpu));
    let h = heldout(&critic, &safe, &unsafe_).unwrap();
    assert_eq!((h.points, h.positives), (40, 30));
    assert!((h.accuracy - 0.25).abs() < 1e-9, "{h:?}");
    assert!((h.brier - 0.25).abs() < 1e-9, "{h:?}");
    assert!((h.ece - 0.25).abs() < 1e-9, "{h:?}");
    let empty = Tensor::zeros([0, 6], (Kind::Float, Device::Cpu));
    assert!(heldout(&critic, &empty, &empty).is_none());
}

/// The trainer measures the critic, before its fit, on the epoch's new rows: after an epoch on the two blobs it
/// tells the next epoch's new D+ and D? rows apart (an epoch without labelling: its D? rows are all failures').
#[test]
fn an_epoch_records_the_critics_held_out_accuracy_on_its_new_rows() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut r = replay(5);
    let mut t = Trainer::with_device(&config(5), Device::Cpu);
    let mut first = Record::new(0);
    t.train_epoch(0, &r, &mut first).unwrap();
    assert_eq!(first.u64("critic_heldout_points"), None, "no critic yet");
    r.begin_epoch();
    r.add_segment(&lap(steps(96, &mut rng, -1.0..0.0))).unwrap();
    r.add_segment(&failure(steps(32, &mut rng, 0.3..1.5)))
        .unwrap();
    let mut second = Record::new(1);
    t.train_epoch(1, &r, &mut second).unwrap();
    assert_eq!(second.u64("critic_heldout_points"), Some(128));
    assert_eq!(second.u64("critic_heldout_positives"), Some(96));
    let accuracy = second.f64("critic_heldout_accuracy").unwrap();
    let brier = second.f64("critic_heldout_brier").unwrap();
    eprintln!("held out: accuracy {accuracy}, Brier {brier}");
    assert!(accuracy > 0.9 && brier < 0.1, "{second:?}");
}

/// `training.safety_gate`: L_safety waits for the critic's held-out balanced accuracy. The first epoch trains the
/// critic with nothing held out yet: no L_safety under the gate. The second measures it on new rows: failures where
/// D- lies (the critic tells them apart: L_safety acts), or failures inside D+'s region (the critic calls them safe:
/// balanced accuracy about 0.5, L_safety stays off). Without a gate L_safety acts from the first fit; the measure
/// survives a checkpoint.
#[test]
fn the_gate_holds_l_safety_until_the_critic_passes_on_held_out_rows() {
    let run = |gate: f64, failures_at: std::ops::Range<f32>| {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let mut r = replay(6);
        let mut c = config(6);
        c.training.safety_gate = gate;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let first = train(&mut t, 0, &r);
        r.begin_epoch();
        r.add_segment(&lap(steps(96, &mut rng, -1.0..0.0))).unwrap();
        r.add_segment(&failure(steps(32, &mut rng, failures_at)))
            .unwrap();
        r.apply_labels(&[]);
        let mut second = Record::new(1);
        t.train_epoch(1, &r, &mut second).unwrap();
        (first, second, t, c, r)
    };
    let (first, second, t, c, r) = run(0.9, 0.3..1.5);
    assert!(!first.safety_active, "no measure yet: {first:?}");
    let balanced = second.f64("critic_heldout_balanced").unwrap();
    assert!(balanced >= 0.9, "the blobs are apart: {balanced}");
    assert_eq!(second.f64("safety_active"), Some(1.0), "{second:?}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint");
    cabc_learning::CheckpointWriter::new(&path)
        .files(t.to_checkpoint())
        .commit()
        .unwrap();
    let mut resumed =
        Trainer::resume(&c, &cabc_learning::Checkpoint::open(&path).unwrap()).unwrap();
    assert!(
        resumed.fit_policy(&r, 1).unwrap().safety_active,
        "a resumed trainer keeps the measure"
    );

    let (_, second, ..) = run(0.9, -1.0..0.0);
    let balanced = second.f64("critic_heldout_balanced").unwrap();
    assert!(balanced < 0.7, "failures where D+ lies: {balanced}");
    assert_eq!(second.f64("safety_active"), Some(0.0), "{second:?}");

    let (first, ..) = run(0.0, 0.3..1.5);
    assert!(first.safety_active, "no gate: from the first fit");
}

/// Issue 57: lambda_j's warm-up (`algorithm.lambda_start = 1`, `lambda_growth = 1.007`, the campaigns' `warmup`) has
/// one derivation ([`Trainer::lambda`]): a trainer resumed mid-warm-up trains the epoch after its checkpoint at the
/// lambda_j an unbroken one does (the record's `lambda`, and the same losses bit for bit), and then both read the
/// next epoch's, through a bare policy fit too.
#[test]
fn a_trainer_resumed_mid_warm_up_goes_on_with_the_unbroken_runs_lambda() {
    let r = replay(9);
    let mut c = config(9);
    (c.algorithm.lambda_start, c.algorithm.lambda_growth) = (Some(1.0), 1.007);
    assert!(
        c.lambda(0) < c.lambda(3) && c.lambda(3) < c.algorithm.lambda,
        "mid-warm-up"
    );
    let run = Resumed::run(&c, &r, 2);
    let lambdas = |losses: &[support::Losses]| losses.iter().map(|l| l.lambda).collect::<Vec<_>>();
    let warm_up: Vec<_> = (0..3).map(|j| Some(c.lambda(j))).collect();
    assert_eq!(lambdas(&run.straight_losses), warm_up);
    assert_eq!(lambdas(&run.losses), warm_up);
    assert!(
        run.losses[2].safety_active,
        "L_safety at lambda_2: {:?}",
        run.losses[2]
    );
    assert_eq!(run.losses, run.straight_losses);
    let (mut resumed, mut straight) = (run.resumed, run.straight);
    assert_eq!(
        (resumed.lambda(), straight.lambda()),
        (c.lambda(3), c.lambda(3))
    );
    assert_eq!(
        resumed.fit_policy(&r, 1).unwrap(),
        straight.fit_policy(&r, 1).unwrap()
    );
}
