//! Training on CUDA (issue 22): skipped, with the reason printed, where libtorch sees no CUDA device (every CI run and
//! this project's machines); run on the lent GPU machine. The camera policy with a ResNet-18 trunk, the dynamics
//! model and the critic train there in fp32 and in bf16, their variables live on the GPU, and the losses are finite
//! and fall.

mod support;
use cabc_learning::replay::Replay;
use cabc_learning::train::Trainer;
use cabc_models::Network;
use cabc_proto::config::{ObservationKind, Precision, RunConfig, VisionTrunk};
use cabc_proto::messages::{EndReason, Outcome, Segment, Step};
use std::io::Write;
use support::train;
use tch::Device;

fn replay(side: u16) -> Replay {
    let mut r = Replay::new(10_000, 1);
    let step = |i: usize, safe: bool| {
        let x = i as f32 / 100.0;
        let (x_tran, next_x_tran) = if safe { (0.0, 0.0) } else { (0.6, 0.7) };
        let state = [1.0, 0.0, 0.0, x, x_tran, 0.0];
        let next = [1.0, 0.0, 0.0, x + 0.1, next_x_tran, 0.0];
        Step {
            image: Some(cabc_fixtures::image_of(side, side, |k| {
                ((k + i) % 251) as u8
            })),
            ..cabc_fixtures::step(state, [0.5, -0.1], [0.5, -0.1], next)
        }
    };
    let segment = |outcome, steps| Segment::of("t", outcome, steps);
    r.add_segment(&segment(
        Outcome::Lap,
        (0..512).map(|i| step(i, true)).collect(),
    ))
    .unwrap();
    let failed = (0..128).map(|i| step(i, false)).collect();
    r.add_segment(&segment(Outcome::Failure(EndReason::OutOfTrack), failed))
        .unwrap();
    r.apply_labels(&[]);
    r
}

#[test]
fn the_three_networks_train_on_cuda_in_fp32_and_bf16() {
    if !tch::Cuda::is_available() {
        // Written past libtest's capture, so that the skip shows in the test run's output.
        let _ = writeln!(
            std::io::stderr(),
            "skipped: no CUDA device (libtorch sees none); it runs on the lent GPU machine"
        );
        return;
    }
    let r = replay(64);
    for precision in [Precision::Fp32, Precision::Bf16] {
        let mut c = RunConfig::load("v-c").unwrap();
        assert_eq!(c.observation.kind, ObservationKind::Camera);
        (c.observation.width, c.observation.height) = (64, 64);
        c.observation.trunk = VisionTrunk::Resnet18;
        c.training.device = "cuda:0".into();
        c.training.precision = precision;
        c.training.critic_min_uncertain = 1;
        c.training.dynamics_every = 1;
        c.training.critic_every = 1;
        c.training.aux_passes = 2;
        c.algorithm.lambda = 1.0;
        let mut t = Trainer::new(&c).unwrap();
        assert_eq!(t.device(), Device::Cuda(0));
        let losses: Vec<_> = (0..4).map(|e| train(&mut t, e, &r)).collect();
        for l in &losses {
            assert!(
                l.imitation.is_finite() && l.safety.is_finite(),
                "{precision:?}: {l:?}"
            );
            assert!(l.dynamics.unwrap().is_finite() && l.critic.unwrap().is_finite());
        }
        assert!(
            losses[3].imitation < losses[0].imitation,
            "{precision:?}: {losses:?}"
        );
        for vs in [
            t.policy().var_store(),
            t.dynamics().var_store(),
            t.critic().var_store(),
        ] {
            assert!(vs
                .variables()
                .values()
                .all(|v| v.device() == Device::Cuda(0)));
        }
        // The policy acts on the GPU for in-process actors (`learner run --local`).
        let bytes = t.policy_bytes();
        let on_gpu = cabc_models::Policy::from_bytes(&bytes, Device::Cuda(0)).unwrap();
        assert!(on_gpu
            .var_store()
            .variables()
            .values()
            .all(|v| v.device().is_cuda()));
        eprintln!(
            "{precision:?}: imitation {:.4} -> {:.4}",
            losses[0].imitation, losses[3].imitation
        );
    }
}
