//! Shapes, weights round trips and the architecture check of the three networks.

use cabc_models::Network;
use cabc_models::{
    Critic, Dynamics, ModelError, Observation, Policy, PolicyArch, PolicyCheck, PolicyInput,
    VelocityMask,
};
use cabc_proto::config::{MlpSize, NetworksSection, RunConfig, VisionTrunk};
use cabc_proto::messages::Image;
use tch::{Device, Kind, Tensor};

fn sizes() -> NetworksSection {
    NetworksSection::default()
}

fn state_arch() -> PolicyArch {
    PolicyArch::State {
        mlp: sizes().policy,
    }
}

#[test]
fn architecture_names_round_trip() {
    let mlp = sizes().policy;
    for arch in [
        state_arch(),
        PolicyArch::Camera {
            trunk: VisionTrunk::Resnet18,
            mlp,
            sees: VelocityMask::ALL,
        },
        PolicyArch::Camera {
            trunk: VisionTrunk::SmallCnn,
            mlp,
            sees: VelocityMask::ALL,
        },
    ] {
        assert_eq!(arch.to_string().parse::<PolicyArch>().unwrap(), arch);
    }
    assert_eq!(state_arch().to_string(), "policy-state-mlp-3x128");
    assert!(matches!(
        "policy-state-cnn".parse::<PolicyArch>(),
        Err(ModelError::UnknownArchitecture(_))
    ));
}

#[test]
fn state_policy_acts_and_round_trips() {
    let policy = Policy::new(state_arch(), Device::Cpu, 1);
    let states = [
        [1.0f32, 0.0, 0.1, 2.0, 0.1, 0.0],
        [0.5, 0.1, -0.2, 5.0, -0.2, 0.1],
    ];
    let a = policy.act_states(&states).unwrap();
    assert_eq!(a.len(), 2);
    let bytes = policy.to_bytes();
    let same = Policy::from_bytes(&bytes, Device::Cpu).unwrap();
    assert_eq!(same.act_states(&states).unwrap(), a);
    let mut other = Policy::new(state_arch(), Device::Cpu, 2);
    assert_ne!(other.act_states(&states).unwrap(), a);
    other.load_bytes(&bytes).unwrap();
    assert_eq!(other.act_states(&states).unwrap(), a);
    // Same seed, same weights.
    assert_eq!(Policy::new(state_arch(), Device::Cpu, 1).to_bytes(), bytes);
}

#[test]
fn weights_of_another_architecture_are_refused() {
    let small = Policy::new(state_arch(), Device::Cpu, 1);
    let wide = PolicyArch::State {
        mlp: MlpSize {
            layers: 3,
            width: 64,
        },
    };
    let mut other = Policy::new(wide, Device::Cpu, 1);
    match other.load_bytes(&small.to_bytes()) {
        Err(ModelError::ArchitectureMismatch { expected, found }) => {
            assert_eq!(expected, "policy-state-mlp-3x64");
            assert_eq!(found, "policy-state-mlp-3x128");
        }
        r => panic!("expected an architecture mismatch, got {r:?}"),
    }
    let mut critic = Critic::new(6, sizes().critic, Device::Cpu, 0);
    assert!(matches!(
        critic.load_bytes(&small.to_bytes()),
        Err(ModelError::ArchitectureMismatch { .. })
    ));
    assert!(matches!(
        Policy::from_bytes(b"not safetensors", Device::Cpu),
        Err(ModelError::MalformedWeights(_))
    ));
    let mut truncated = small.to_bytes();
    truncated.truncate(truncated.len() - 4);
    assert!(Policy::from_bytes(&truncated, Device::Cpu).is_err());
}

fn image(w: u16, h: u16, seed: u8) -> Image {
    cabc_fixtures::image_of(w, h, |i| (i as u8).wrapping_mul(seed))
}

#[test]
fn camera_policies_take_images_and_velocities() {
    for trunk in [VisionTrunk::SmallCnn, VisionTrunk::Resnet18] {
        let arch = PolicyArch::Camera {
            trunk,
            mlp: sizes().policy,
            sees: VelocityMask::ALL,
        };
        let policy = Policy::new(arch, Device::Cpu, 3);
        let (a, b) = (image(32, 24, 3), image(32, 24, 7));
        let obs = [
            Observation::Camera {
                image: &a,
                velocity: [1.0, 0.0, 0.1],
            },
            Observation::Camera {
                image: &b,
                velocity: [0.5, 0.1, 0.0],
            },
        ];
        let actions = policy.act(&obs).unwrap();
        assert_eq!(actions.len(), 2);
        assert!(actions.iter().flatten().all(|v| v.is_finite()));
        // Images of another size in one batch, or a state, are refused.
        let c = image(16, 16, 1);
        let mixed = [
            obs[0],
            Observation::Camera {
                image: &c,
                velocity: [0.0; 3],
            },
        ];
        assert!(matches!(
            policy.act(&mixed),
            Err(ModelError::Observation(_))
        ));
        assert!(matches!(
            policy.act(&[Observation::State(&[0.0; 6])]),
            Err(ModelError::Observation(_))
        ));
        // Training-mode forward on tensors: u8 NHWC in.
        let images = Tensor::zeros([4, 24, 32, 3], (Kind::Uint8, Device::Cpu));
        let velocity = Tensor::zeros([4, 3], (Kind::Float, Device::Cpu));
        let out = policy.forward_t(&PolicyInput::Camera { images, velocity }, true);
        assert_eq!(out.size(), vec![4, 2]);
        let again = Policy::from_bytes(&policy.to_bytes(), Device::Cpu).unwrap();
        assert_eq!(again.act(&obs).unwrap(), policy.act(&obs).unwrap());
    }
}

#[test]
fn resnet18_has_the_torchvision_parameter_count() {
    let arch = PolicyArch::Camera {
        trunk: VisionTrunk::Resnet18,
        mlp: sizes().policy,
        sees: VelocityMask::ALL,
    };
    let policy = Policy::new(arch, Device::Cpu, 0);
    let trunk: i64 = policy
        .var_store()
        .trainable_variables()
        .iter()
        .map(|t| t.numel() as i64)
        .sum::<i64>()
        - (515 * 128 + 128 + 2 * (128 * 128 + 128) + 128 * 2 + 2);
    // torchvision resnet18: 11,689,512 parameters, of which the fc layer holds 513,000.
    assert_eq!(trunk, 11_689_512 - 513_000);
}

#[test]
fn dynamics_is_residual_and_critic_is_a_logit() {
    let dynamics = Dynamics::new(sizes().dynamics, Device::Cpu, 0);
    assert_eq!(dynamics.architecture(), "dynamics-residual-mlp-3x64");
    let x = Tensor::randn([5, 6], (Kind::Float, Device::Cpu));
    let u = Tensor::randn([5, 2], (Kind::Float, Device::Cpu));
    assert_eq!(dynamics.forward(&x, &u).size(), vec![5, 6]);
    let critic = Critic::new(6, sizes().critic, Device::Cpu, 0);
    assert_eq!(critic.architecture(), "critic-6-mlp-4x256");
    assert_eq!(critic.logits(&x).size(), vec![5]);
    let mut d2 = Dynamics::new(sizes().dynamics, Device::Cpu, 9);
    d2.load_bytes(&dynamics.to_bytes()).unwrap();
    assert!(d2
        .forward(&x, &u)
        .allclose(&dynamics.forward(&x, &u), 0.0, 0.0, false));
}

/// Issue 58 (`observation.velocity_inputs`): a masked velocity is zero in what the network sees, so the policy's
/// action does not move with it, while a velocity it sees does; the mask travels in the architecture's name, so the
/// actor's policy built from the learner's weights masks the same velocities.
#[test]
fn masked_velocities_are_zero_in_what_the_policy_sees() {
    let config = RunConfig::load("v-a-cpu")
        .unwrap()
        .with_overrides(&["observation.velocity_inputs=[\"v_long\"]".to_string()])
        .unwrap();
    let arch = PolicyArch::from_config(&config);
    assert_eq!(
        arch.to_string(),
        "policy-camera-small-cnn-mlp-3x128-sees-v_long"
    );
    assert_eq!(arch.to_string().parse::<PolicyArch>().unwrap(), arch);
    let policy = Policy::new(arch, Device::Cpu, 5);
    let frame = image(32, 32, 3);
    let act = |velocity: [f32; 3]| {
        policy
            .act(&[Observation::Camera {
                image: &frame,
                velocity,
            }])
            .unwrap()[0]
    };
    let base = act([1.0, 0.0, 0.0]);
    assert_eq!(act([1.0, 0.7, -2.0]), base, "v_tran and omega are masked");
    assert_ne!(act([2.0, 0.0, 0.0]), base, "v_long is seen");
    // The same with all three masked: the image alone.
    let none = PolicyArch::Camera {
        trunk: VisionTrunk::SmallCnn,
        mlp: sizes().policy,
        sees: VelocityMask([false; 3]),
    };
    assert_eq!(
        none.to_string(),
        "policy-camera-small-cnn-mlp-3x128-sees-none"
    );
    let blind = Policy::new(none, Device::Cpu, 5);
    let of = |velocity: [f32; 3]| {
        blind
            .act(&[Observation::Camera {
                image: &frame,
                velocity,
            }])
            .unwrap()[0]
    };
    assert_eq!(of([3.0, -1.0, 2.0]), of([0.0; 3]));
    // The actor's check holds weights to the run's mask: the paper's camera policy is another architecture.
    let bytes = policy.to_bytes();
    let check = PolicyCheck::new(arch);
    assert!(check.policy(&arch.to_string(), &bytes, Device::Cpu).is_ok());
    let all = PolicyArch::Camera {
        trunk: VisionTrunk::SmallCnn,
        mlp: sizes().policy,
        sees: VelocityMask::ALL,
    };
    assert!(matches!(
        PolicyCheck::new(all).check(&arch.to_string(), &bytes),
        Err(ModelError::ArchitectureMismatch { .. })
    ));
    for bad in [
        "-sees-omega+v_long",
        "-sees-v_long+v_tran+omega",
        "-sees-yaw",
    ] {
        let name = format!("policy-camera-small-cnn-mlp-3x128{bad}");
        assert!(name.parse::<PolicyArch>().is_err(), "{name}");
    }
}
