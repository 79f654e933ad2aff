//! The keys of the V-B recipe (issue 30), each checked for what it promises: the state's standardisation
//! (`training.standardise`) trains on standardised states and publishes a policy that takes raw ones; the moving
//! average of the weights (`training.policy_ema`) is what is published; lambda's warm-up (`algorithm.lambda_start`,
//! `lambda_growth`) and the learning rate's floor (`training.lr_min`) follow their formulas; and a run with all of
//! them resumes bit for bit.

mod support;
use cabc_learning::record::Record;
use cabc_learning::replay::Replay;
use cabc_learning::train::Trainer;
use cabc_models::Network;
use cabc_proto::config::{RunConfig, ScheduleKind};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::{train, Resumed};
use tch::{Device, Tensor};

fn config(seed: u64) -> RunConfig {
    let mut c = cabc_fixtures::training_config(seed);
    c.algorithm.lambda = 1.0;
    c
}

/// States on the scale of the plant's: s (index 3) over a 20 m track, the rest near 1; the expert's action depends
/// on s, so a policy must read it.
fn steps(n: usize, rng: &mut ChaCha8Rng, s0: f32) -> Vec<Step> {
    (0..n)
        .map(|_| {
            let mut state: [f32; 6] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
            state[3] = s0 + rng.gen_range(0.0..20.0);
            let mut next = state;
            next[3] += 0.1;
            let expert = [(state[3] / 10.0).sin(), 0.1 * state[0]];
            cabc_fixtures::step(state, expert, [0.0, 0.0], next)
        })
        .collect()
}

fn replay(seed: u64) -> Replay {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut r = Replay::new(10_000, seed);
    r.add_segment(&Segment::of("t", Outcome::Lap, steps(1024, &mut rng, 0.0)))
        .unwrap();
    r.add_segment(&Segment::of(
        "t",
        Outcome::Failure(EndReason::OutOfTrack),
        steps(256, &mut rng, 5.0),
    ))
    .unwrap();
    r.apply_labels(&[]);
    r
}

fn weights(t: &Tensor) -> Vec<f32> {
    Vec::<f32>::try_from(t.flatten(0, -1)).unwrap()
}

#[test]
fn a_standardised_policy_trains_on_standardised_states_and_drives_on_raw_ones() {
    let r = replay(1);
    let mut c = config(1);
    c.training.standardise = true;
    let mut t = Trainer::with_device(&c, Device::Cpu);
    assert!(t.standardiser().is_none(), "taken at the first fit");
    t.train_epoch(0, &r, &mut Record::default()).unwrap();
    let s = t.standardiser().expect("taken from D+").clone();
    assert!(
        (s.mean[3] - 10.0).abs() < 1.0 && (s.std[3] - 5.77).abs() < 0.5,
        "{s:?}"
    );
    // The published policy on raw states is the trained one on standardised states, up to f32 rounding.
    let raw: Vec<f32> = r.plus.states[..64].iter().flatten().copied().collect();
    let raw = Tensor::from_slice(&raw).view([-1, 6]);
    let trained = tch::no_grad(|| {
        t.policy()
            .forward_t(&cabc_models::PolicyInput::State(s.apply(&raw)), false)
    });
    let deployed = t.deployed_policy();
    let published = tch::no_grad(|| {
        deployed.forward_t(&cabc_models::PolicyInput::State(raw.shallow_clone()), false)
    });
    let gap = (trained - &published).abs().max().double_value(&[]);
    assert!(gap < 1e-4, "the fold changes the policy by {gap}");
    assert_eq!(
        deployed.architecture(),
        "policy-state-mlp-3x128",
        "a plain MLP"
    );
    // The standardisation stays: a second epoch does not take it again.
    t.train_epoch(1, &r, &mut Record::default()).unwrap();
    assert_eq!(t.standardiser(), Some(&s));
    // Without the key nothing is standardised and the published weights are the trained ones.
    let mut plain = Trainer::with_device(&config(1), Device::Cpu);
    plain.train_epoch(0, &r, &mut Record::default()).unwrap();
    assert!(plain.standardiser().is_none());
    assert!(plain.policy_bytes() == plain.policy().to_bytes());
}

#[test]
fn the_published_policy_is_the_moving_average_of_the_trained_weights() {
    let r = replay(2);
    let mut c = config(2);
    c.training.policy_ema = 0.75;
    let mut t = Trainer::with_device(&c, Device::Cpu);
    let first_layer = |p: &cabc_models::Policy| weights(&p.var_store().variables()["mlp.0.weight"]);
    t.train_epoch(0, &r, &mut Record::default()).unwrap();
    let theta0 = first_layer(t.policy());
    assert_eq!(
        first_layer(&t.deployed_policy()),
        theta0,
        "the average starts at theta"
    );
    t.train_epoch(1, &r, &mut Record::default()).unwrap();
    let theta1 = first_layer(t.policy());
    let published = first_layer(&t.deployed_policy());
    assert_ne!(theta1, theta0);
    for ((p, a), b) in published.iter().zip(&theta0).zip(&theta1) {
        let want = 0.75 * a + 0.25 * b;
        assert!(
            (p - want).abs() <= 1e-6 * (1.0 + want.abs()),
            "{p} != {want}"
        );
    }
}

#[test]
fn lambda_warms_up_and_the_learning_rate_keeps_its_floor() {
    let mut c = config(3);
    c.algorithm.lambda = 10.0;
    c.algorithm.lambda_start = Some(1.0);
    c.algorithm.lambda_growth = 1.007;
    assert_eq!(c.lambda(0), 1.0);
    assert!((c.lambda(100) - 1.007f64.powi(100)).abs() < 1e-12);
    assert_eq!(c.lambda(400), 10.0, "capped at lambda");
    c.make_baseline();
    assert_eq!(c.lambda(0), 0.0, "the baseline has none");

    let r = replay(3);
    let mut c = config(3);
    c.training.lr_gamma = 0.5;
    c.training.lr_min = 3e-4;
    let mut t = Trainer::with_device(&c, Device::Cpu);
    let mut lrs = Vec::new();
    for epoch in 0..4 {
        lrs.push(t.lr_policy());
        t.train_epoch(epoch, &r, &mut Record::default()).unwrap();
    }
    assert_eq!(
        lrs,
        vec![1e-3, 5e-4, 3e-4, 3e-4],
        "decays, then holds at its floor"
    );
}

/// Standardisation, moving average and warm-up together: k epochs, a checkpoint, a resume and one more epoch give the
/// uninterrupted run's losses and networks bit for bit; the checkpoint holds the standardisation and the average.
#[test]
fn the_recipe_resumes_bit_for_bit() {
    let r = replay(4);
    let mut c = config(4);
    c.training.standardise = true;
    c.training.policy_ema = 0.5;
    c.training.lr_min = 5e-4;
    c.algorithm.lambda_start = Some(0.5);
    c.algorithm.lambda_growth = 1.5;
    let nets = |t: &Trainer| {
        [
            t.policy_bytes(),
            t.policy().to_bytes(),
            t.dynamics().to_bytes(),
            t.critic().to_bytes(),
        ]
    };
    let run = Resumed::run(&c, &r, 2);
    assert!(run.checkpoint().join("policy.ema.safetensors").exists());
    assert_eq!(run.resumed.standardiser(), run.straight.standardiser());
    assert_eq!(run.losses, run.straight_losses);
    assert!(
        nets(&run.resumed) == nets(&run.straight),
        "the resumed networks differ"
    );
    // The safety term's weight grew with the epochs.
    let mut record = Record::default();
    Trainer::with_device(&c, Device::Cpu)
        .train_epoch(0, &r, &mut record)
        .unwrap();
    assert_eq!(record.f64("lambda"), Some(0.5));
}

/// `training.clone_uncertain`: L_clone fits D+ and D?'s states with the expert's labels; a step whose expert failed
/// (labelled [0, 0] by the actor) stays out.
#[test]
fn cloning_on_d_uncertain_takes_its_labelled_steps() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut r = Replay::new(10_000, 5);
    r.add_segment(&Segment::of("t", Outcome::Lap, steps(1024, &mut rng, 0.0)))
        .unwrap();
    let mut failed = steps(320, &mut rng, 5.0);
    for s in failed.iter_mut().take(64) {
        s.expert_ok = false;
        s.expert_action = [0.0, 0.0];
    }
    r.add_segment(&Segment::of(
        "t",
        Outcome::Failure(EndReason::OutOfTrack),
        failed,
    ))
    .unwrap();
    r.apply_labels(&[]);
    assert_eq!(r.len_uncertain(), 320);
    let samples = |clone_uncertain: bool| {
        let mut c = config(5);
        c.training.clone_uncertain = clone_uncertain;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        train(&mut t, 0, &r).policy_samples
    };
    let passes = RunConfig::default().training.initial_passes;
    assert_eq!(samples(false), passes * 1024);
    assert_eq!(
        samples(true),
        passes * (1024 + 256),
        "D?'s 256 labelled steps"
    );
}

/// `training.clone_uncertain` on a camera policy (V-A, V-C): D? keeps its images, and L_clone fits D?'s labelled
/// steps each through its own image (a change to D?'s images changes the fit; without the key it changes nothing).
#[test]
fn a_camera_policy_clones_d_uncertain_through_its_images() {
    let mut c = RunConfig::load("v-c-ref").unwrap();
    c.training.device = "cpu".into();
    c.training.schedule = ScheduleKind::EveryEpoch;
    c.training.initial_passes = 1;
    c.training.clone_uncertain = true;
    c.validate("t").unwrap();
    assert!(c.uncertain_images());
    let side = c.observation.width as usize;
    assert_eq!(c.observation.height as usize, side);
    let replay = |uncertain_fill: u8| {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let with_image = |mut steps: Vec<Step>, fill: &dyn Fn(usize) -> u8| {
            for (i, s) in steps.iter_mut().enumerate() {
                let side = side as u16;
                s.image = Some(cabc_fixtures::image_of(side, side, |k| {
                    fill(i).wrapping_add(k as u8)
                }));
            }
            steps
        };
        let mut r = Replay::from_config(&c);
        let lap = with_image(steps(256, &mut rng, 0.0), &|i| i as u8);
        r.add_segment(&Segment::of("t", Outcome::Lap, lap)).unwrap();
        let mut failed = with_image(steps(96, &mut rng, 5.0), &|i| uncertain_fill ^ i as u8);
        for s in failed.iter_mut().take(32) {
            s.expert_ok = false;
            s.expert_action = [0.0, 0.0];
        }
        let failure = Outcome::Failure(EndReason::OutOfTrack);
        r.add_segment(&Segment::of("t", failure, failed)).unwrap();
        r.apply_labels(&[]);
        r
    };
    let (r, other) = (replay(0), replay(77));
    let images = r.uncertain.images.as_ref().expect("D? keeps its images");
    assert_eq!(images.bytes.len(), 96 * side * side * 3);
    assert_eq!(images.get(40)[0], 40, "step 40's own image");
    let fit = |clone_uncertain: bool, r: &Replay| {
        let mut c = c.clone();
        c.training.clone_uncertain = clone_uncertain;
        let mut t = Trainer::with_device(&c, Device::Cpu);
        let l = train(&mut t, 0, r);
        (l.policy_samples, l.imitation)
    };
    let (samples, imitation) = fit(true, &r);
    assert_eq!(samples, 256 + 64, "D?'s 64 labelled steps");
    assert_ne!(fit(true, &other).1, imitation, "D?'s images are read");
    let (samples, imitation) = fit(false, &r);
    assert_eq!(samples, 256);
    assert_eq!(fit(false, &other), (256, imitation), "D?'s images unread");
}
