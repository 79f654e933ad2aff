use super::*;
use tch::nn::{Module, OptimizerConfig};
use tch::{Device, Kind};

/// A small network: 5 -> 37 -> 3 (stretches of 185, 37, 111 and 3 values, none a multiple of a vector's width).
fn net(vs: &nn::VarStore) -> nn::Sequential {
    nn::seq()
        .add(nn::linear(vs.root() / "l1", 5, 37, Default::default()))
        .add_fn(|x| x.tanh())
        .add(nn::linear(vs.root() / "l2", 37, 3, Default::default()))
}

/// Two identical networks; one trained by tch's Adam, the other by ours.
fn pair() -> (nn::VarStore, nn::VarStore, nn::Sequential, nn::Sequential) {
    let a = nn::VarStore::new(Device::Cpu);
    let mut b = nn::VarStore::new(Device::Cpu);
    let (na, nb) = (net(&a), net(&b));
    b.copy(&a).unwrap();
    (a, b, na, nb)
}

/// A copy of the network `template` holds.
fn copy_of(template: &nn::VarStore) -> (nn::VarStore, nn::Sequential) {
    let mut vs = nn::VarStore::new(Device::Cpu);
    let n = net(&vs);
    vs.copy(template).unwrap();
    (vs, n)
}

/// Inputs from a seeded generator of this test's own (the tests run in parallel: libtorch's global generator is
/// shared).
fn inputs(rng: &mut rand_chacha::ChaCha8Rng) -> Tensor {
    use rand::Rng;
    let v: Vec<f32> = (0..80).map(|_| rng.gen_range(-2.0..2.0)).collect();
    Tensor::from_slice(&v).view([16, 5])
}

#[test]
fn matches_tch_adam_bit_for_bit() {
    tch::set_num_threads(1);
    for wd in [0.0, 1e-4] {
        let (a, b, na, nb) = pair();
        let mut theirs = nn::Adam::default().wd(wd).build(&a, 1e-2).unwrap();
        let mut ours = Adam::new(&b, 1e-2, wd);
        for i in 0..200 {
            let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
            let y = Tensor::randn([16, 3], (Kind::Float, Device::Cpu));
            let lr = 1e-2 * 0.97f64.powi(i / 10);
            theirs.set_lr(lr);
            ours.lr = lr;
            let la = na.forward(&x).mse_loss(&y, tch::Reduction::Mean);
            theirs.zero_grad();
            la.backward();
            theirs.clip_grad_norm(0.5);
            theirs.step();
            let lb = nb.forward(&x).mse_loss(&y, tch::Reduction::Mean);
            ours.zero_grad();
            lb.backward();
            ours.clip_grad_norm(0.5, &[]);
            ours.step();
            assert_eq!(
                la.double_value(&[]).to_bits(),
                lb.double_value(&[]).to_bits()
            );
        }
        let (va, vb) = (a.variables(), b.variables());
        for (name, t) in &va {
            assert!(t.equal(&vb[name]), "wd {wd}: {name} differs");
        }
        assert_eq!(ours.steps(), vec![200; 4]);
    }
}

#[test]
fn flat_and_per_variable_steps_agree() {
    tch::set_num_threads(1);
    let (a, b, na, nb) = pair();
    let mut each = Adam::new(&a, 1e-2, 1e-4);
    let mut flat = Adam::new(&b, 1e-2, 1e-4);
    for _ in 0..100 {
        let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
        for (adam, net) in [(&mut each, &na), (&mut flat, &nb)] {
            adam.zero_grad();
            net.forward(&x).square().sum(Kind::Float).backward();
            adam.clip_grad_norm(0.01, &[]);
        }
        each.step_each();
        flat.step();
    }
    let (va, vb) = (a.variables(), b.variables());
    for (name, t) in &va {
        assert!(t.equal(&vb[name]), "{name} differs");
    }
    assert_eq!(each.to_bytes(), flat.to_bytes());
}

#[test]
fn flat_steps_keep_the_bits_when_another_networks_gradients_count_in_the_clip() {
    tch::set_num_threads(1);
    // The reference's clip scope: the policy's loss reaches the critic's weights, whose gradients (left from the
    // critic's own fit and accumulated into) count in the policy's clip and are scaled by it.
    let (policy_template, critic_template, _, _) = pair();
    let run = |flat: bool| {
        let (policy_vs, policy) = copy_of(&policy_template);
        let (critic_vs, critic) = copy_of(&critic_template);
        let mut policy_adam = Adam::new(&policy_vs, 1e-2, 1e-4);
        let mut critic_adam = Adam::new(&critic_vs, 1e-2, 1e-4);
        let step = |adam: &mut Adam| match flat {
            true => adam.step(),
            false => adam.step_each(),
        };
        let mut rng = rand::SeedableRng::seed_from_u64(9);
        let mut losses = Vec::new();
        for _ in 0..30 {
            let x = inputs(&mut rng);
            for _ in 0..3 {
                critic_adam.zero_grad();
                critic.forward(&x).square().mean(Kind::Float).backward();
                critic_adam.clip_grad_norm(0.1, &[]);
                step(&mut critic_adam);
            }
            for _ in 0..3 {
                policy_adam.zero_grad();
                let u = policy.forward(&x);
                let inputs = Tensor::cat(&[&u, &x.narrow(1, 0, 2)], 1);
                let loss = u.square().mean(Kind::Float) + critic.forward(&inputs).mean(Kind::Float);
                loss.backward();
                losses.push(loss.double_value(&[]).to_bits());
                policy_adam.clip_grad_norm(0.1, &critic_vs.trainable_variables());
                step(&mut policy_adam);
            }
        }
        (losses, policy_adam.to_bytes(), critic_adam.to_bytes())
    };
    let (each, flat) = (run(false), run(true));
    assert_eq!(each.0, flat.0, "the losses");
    assert_eq!(each.1, flat.1, "the policy's moments");
    assert_eq!(each.2, flat.2, "the critic's moments");
}

#[test]
fn a_variable_without_a_gradient_is_not_stepped_as_in_libtorch() {
    tch::set_num_threads(1);
    let (a, b, na, nb) = pair();
    let mut theirs = nn::Adam::default().wd(1e-4).build(&a, 1e-2).unwrap();
    let mut ours = Adam::new(&b, 1e-2, 1e-4);
    for i in 0..40 {
        let x = Tensor::randn([16, 5], (Kind::Float, Device::Cpu));
        // The first 10 steps train the first layer alone: the second's gradients are undefined, then its step
        // counts trail the first's.
        let loss = |net: &nn::Sequential, vs: &nn::VarStore| match i < 10 {
            true => {
                let v = vs.variables();
                (x.matmul(&v["l1.weight"].tr()) + &v["l1.bias"]).sum(Kind::Float)
            }
            false => net.forward(&x).sum(Kind::Float),
        };
        theirs.zero_grad();
        loss(&na, &a).backward();
        theirs.step();
        ours.zero_grad();
        loss(&nb, &b).backward();
        ours.step();
    }
    let (va, vb) = (a.variables(), b.variables());
    for (name, t) in &va {
        assert!(t.equal(&vb[name]), "{name} differs");
    }
    assert_eq!(ours.steps(), vec![40, 40, 30, 30]);
}

#[test]
fn state_round_trips() {
    let (_, b, _, nb) = pair();
    let mut ours = Adam::new(&b, 1e-3, 1e-4);
    let x = Tensor::randn([8, 5], (Kind::Float, Device::Cpu));
    for _ in 0..3 {
        ours.zero_grad();
        nb.forward(&x).sum(Kind::Float).backward();
        ours.step();
    }
    let bytes = ours.to_bytes();
    let mut other = Adam::new(&b, 1e-3, 1e-4);
    assert_eq!(other.steps(), vec![0; 4]);
    other.load_bytes(&bytes).unwrap();
    assert_eq!(other.steps(), vec![3; 4]);
    assert_eq!(other.to_bytes(), bytes);
    let fresh = Adam::new(&b, 1e-3, 1e-4).to_bytes();
    other.load_bytes(&fresh).unwrap();
    assert_eq!(other.steps(), vec![0; 4]);
    assert!(other.load_bytes(&bytes[..bytes.len() - 4]).is_err());
    assert!(other.load_bytes(b"junk").is_err());
}

#[test]
fn the_clip_counts_other_gradients_and_gradients_survive_a_checkpoint() {
    let (a, b, na, nb) = pair();
    let x = Tensor::randn([8, 5], (Kind::Float, Device::Cpu));
    let mut own = Adam::new(&a, 1e-3, 0.0);
    own.zero_grad();
    na.forward(&x).sum(Kind::Float).backward();
    let other = Adam::new(&b, 1e-3, 0.0);
    nb.forward(&x).sum(Kind::Float).backward();
    let norm = |vs: &nn::VarStore| -> f64 {
        let sq: f64 = vs
            .trainable_variables()
            .iter()
            .map(|v| v.grad().square().sum(Kind::Double).double_value(&[]))
            .sum();
        sq.sqrt()
    };
    let (own_before, other_before) = (norm(&a), norm(&b));
    assert!(
        (own_before - other_before).abs() < 1e-9,
        "identical nets, identical gradients"
    );
    // Alone, the clip scales to 1; with the other network's gradients counted, each half gets 1 / sqrt(2).
    own.clip_grad_norm(1.0, &b.trainable_variables());
    let joint = (norm(&a).powi(2) + norm(&b).powi(2)).sqrt();
    assert!((joint - 1.0).abs() < 1e-4, "joint norm {joint}");
    assert!(
        (norm(&a) - 0.5f64.sqrt()).abs() < 1e-4,
        "own norm {}",
        norm(&a)
    );
    // The gradients travel with the state when asked to, and come back exactly.
    let mut keeper = other;
    keeper.keep_grads = true;
    let bytes = keeper.to_bytes();
    let saved: Vec<Tensor> = b
        .trainable_variables()
        .iter()
        .map(|v| v.grad().copy())
        .collect();
    for mut v in b.trainable_variables() {
        v.zero_grad();
    }
    keeper.load_bytes(&bytes).unwrap();
    for (v, g) in b.trainable_variables().iter().zip(&saved) {
        assert!(v.grad().equal(g));
    }
    keeper.keep_grads = false;
    assert!(
        keeper.to_bytes().len() < bytes.len(),
        "no gradients unless kept"
    );
}

/// The clip's coefficient computed where the gradients live (a GPU's path, forced here on the CPU) scales them by the
/// very bits the host's branch does, clipping or not, with another network's gradients in the norm too.
#[test]
fn the_clip_on_the_device_gives_the_hosts_bits() {
    tch::set_num_threads(1);
    let (a, b, na, nb) = pair();
    let (c, nc) = copy_of(&a);
    let (d, nd) = copy_of(&a);
    let mut host = Adam::new(&a, 1e-2, 1e-4);
    let mut device = Adam::new(&b, 1e-2, 1e-4);
    assert!(!host.device_clip, "on the CPU the host reads the norm");
    device.device_clip = true;
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
    let mut clipped = 0;
    for i in 0..120 {
        let x = inputs(&mut rng);
        // Alternately a bound that clips and one that does not.
        let max = if i % 2 == 0 { 0.05 } else { 50.0 };
        for (opt, n, other, no) in [(&mut host, &na, &c, &nc), (&mut device, &nb, &d, &nd)] {
            opt.zero_grad();
            for mut t in other.trainable_variables() {
                t.zero_grad();
            }
            (n.forward(&x).square().mean(Kind::Float) + no.forward(&x).abs().mean(Kind::Float))
                .backward();
            let before = other.trainable_variables()[0].grad().copy();
            opt.clip_grad_norm(max, &other.trainable_variables());
            if !before.equal(&other.trainable_variables()[0].grad()) {
                clipped += 1;
            }
            opt.step();
        }
    }
    assert!(clipped >= 2 * 60, "the bound 0.05 clips: {clipped}");
    for (name, t) in &a.variables() {
        assert!(t.equal(&b.variables()[name]), "{name} differs");
    }
    let dv = d.variables();
    for (name, t) in &c.variables() {
        assert!(
            t.grad().equal(&dv[name].grad()),
            "{name}'s clipped gradient differs"
        );
    }
}
