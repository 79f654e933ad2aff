//! Policy updates from the bus are checked against the run's architecture before anything is built from them: a
//! bad one is a typed error, counted, and the actor goes on with the policy it has (issue 13, item 2).

use cabc_actor::collect::Collector;
use cabc_actor::run::run_actor;
use cabc_fixtures::policy_update as update;
use cabc_models::{Network, Policy, PolicyArch, PolicyCheck};
use cabc_proto::config::{MlpSize, RunConfig};
use cabc_proto::messages::{ExpertAnswer, ExpertQuery, PolicyUpdate, TrajMessage};
use cabc_proto::ports::{ExpertClient, Next, PolicySource, PortError, SegmentSink};
use cabc_sim::pid::PidLaneFollower;
use std::collections::VecDeque;
use tch::Device;

/// safetensors bytes with no tensor and `architecture` in the metadata: ~100 bytes.
fn bare_weights(architecture: &str) -> Vec<u8> {
    let header = format!(r#"{{"__metadata__":{{"architecture":"{architecture}"}}}}"#);
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out
}

#[test]
fn a_five_layer_update_is_an_error_not_a_panic() {
    // The issue's reproduction: before the check, this hit `assert!(layers < 5)` in mlp.rs and killed the actor.
    let bytes = bare_weights("policy-state-mlp-5x8");
    assert!(bytes.len() < 100, "{}", bytes.len());
    let built = std::panic::catch_unwind(|| Policy::from_bytes(&bytes, Device::Cpu).map(|_| ()));
    let result = built.expect("Policy::from_bytes panicked on a 5-layer architecture");
    assert!(result.is_err());
    // A huge width is refused before anything is built, too.
    assert!(
        Policy::from_bytes(&bare_weights("policy-state-mlp-3x4000000000"), Device::Cpu).is_err()
    );
    assert!(Policy::from_bytes(&bare_weights("policy-state-mlp-4x4096"), Device::Cpu).is_err());
    let check = PolicyCheck::new(PolicyArch::from_config(&RunConfig::load("smoke").unwrap()));
    assert!(check.check("policy-state-mlp-5x8", &bytes).is_err());
    assert!(check.check(&check.arch().to_string(), &bytes).is_err());
}

/// Hands out scripted updates; `interrupted` offers one update in the middle of the first epoch.
struct Script {
    next: VecDeque<Next>,
    interrupt: Option<Next>,
    polls: u32,
}

impl PolicySource for Script {
    fn next(&mut self) -> Result<Next, PortError> {
        Ok(self
            .next
            .pop_front()
            .unwrap_or(Next::Stop("script done".into())))
    }

    fn interrupted(&mut self) -> Option<Next> {
        self.polls += 1;
        if self.polls == 3 {
            self.interrupt.take()
        } else {
            None
        }
    }
}

struct Pid;

impl ExpertClient for Pid {
    fn relabel(&mut self, queries: Vec<ExpertQuery>) -> Result<Vec<ExpertAnswer>, PortError> {
        Ok(queries
            .iter()
            .map(|q| ExpertAnswer {
                action: PidLaneFollower::new(1.0).action(q.frenet[0], q.frenet[4], q.frenet[5]),
                success: true,
                status: String::new(),
                iterations: 0,
                solve_time_us: 0,
            })
            .collect())
    }
}

#[derive(Default)]
struct Count {
    steps: u64,
    staged: u64,
    markers: Vec<(u64, u64)>,
}

impl SegmentSink for Count {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        match message {
            TrajMessage::EpochDone(d) => {
                self.staged = d.staged;
                self.markers.push((d.version, d.steps))
            }
            message => {
                self.steps += message
                    .segments()
                    .iter()
                    .map(|s| s.steps.len() as u64)
                    .sum::<u64>()
            }
        }
        Ok(())
    }
}

#[test]
fn bad_updates_are_refused_counted_and_the_epoch_goes_on() {
    let config = RunConfig::load("smoke").unwrap();
    let arch = PolicyArch::from_config(&config);
    let name = arch.to_string();
    let good = Policy::new(arch, Device::Cpu, 3).to_bytes();
    let other = PolicyArch::State {
        mlp: MlpSize {
            layers: 1,
            width: 4,
        },
    };
    let foreign = Policy::new(other, Device::Cpu, 3).to_bytes();
    let mut truncated = good.clone();
    truncated.truncate(good.len() - 5);
    let policy = |u: PolicyUpdate| Next::Policy(Box::new(u));
    let mut source = Script {
        next: VecDeque::from([
            policy(update(
                1,
                "policy-state-mlp-5x8",
                bare_weights("policy-state-mlp-5x8"),
            )),
            policy(update(1, &name, bare_weights("policy-state-mlp-5x8"))),
            policy(update(1, &other.to_string(), foreign.clone())),
            policy(update(1, &name, foreign)),
            policy(update(1, &name, truncated)),
            policy(update(1, &name, good.clone())),
        ]),
        // A bad update in the middle of the epoch must not cut it short.
        interrupt: Some(policy(update(2, &name, bare_weights(&name)))),
        polls: 0,
    };
    let check = PolicyCheck::new(arch);
    let mut collector = Collector::new("actor-0", 0, &config).unwrap();
    let mut sink = Count::default();
    let stats = run_actor(
        &mut collector,
        &check,
        &mut source,
        &mut Pid,
        &mut sink,
        |_, _| {},
    )
    .expect("the actor survives bad updates");
    assert_eq!(stats.refused_policies, 6);
    assert_eq!(stats.versions, 1);
    assert_eq!(sink.markers, vec![(1, sink.steps)]);
    // The whole budget was taken: published, or staged for the next epoch (episodes go on across epochs).
    assert!(
        sink.steps + sink.staged >= 120,
        "{} steps, {} staged",
        sink.steps,
        sink.staged
    );
}
