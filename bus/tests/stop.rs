//! The learner's Stop reaches an evaluator that subscribed to `control` only after the first Stop went out (issue 64:
//! an evaluator joining late over TLS from another namespace waited for a learner that was gone), and the learner stops
//! saying so as soon as nobody is alive.

mod common;

use cabc_bus::interrupt::Interrupt;
use cabc_bus::rollouts::{Waits, ZenohActors};
use cabc_bus::{Bus, Role};
use cabc_proto::codec;
use cabc_proto::config::RunConfig;
use cabc_proto::keys::Keys;
use cabc_proto::messages::Stop;
use cabc_proto::ports::Rollouts;
use std::time::{Duration, Instant};
use zenoh::Wait;

#[test]
fn a_late_evaluator_hears_the_stop_and_the_learner_ends_when_it_left() {
    let section = common::loopback();
    let keys = Keys::new("late").unwrap();
    let learner_bus = Bus::join(&section, Role::Listen, keys.clone(), "learner").unwrap();
    let waits = Waits {
        epoch_timeout: Duration::from_secs(5),
        no_actor_timeout: Duration::from_secs(5),
    };
    let mut learner = ZenohActors::new(
        learner_bus,
        &RunConfig::default(),
        waits,
        Interrupt::default(),
    )
    .unwrap();
    let evaluator = Bus::join(&section, Role::Connect, keys.clone(), "eval/eval-0").unwrap();
    // The learner learns of the evaluator's liveliness token before it stops the run.
    std::thread::sleep(Duration::from_millis(500));

    let began = Instant::now();
    let stopping = std::thread::spawn(move || {
        learner.stop("max_epochs reached").unwrap();
        began.elapsed()
    });
    // The first Stop has gone out (the learner waits 500 ms before it says it again) when the evaluator subscribes.
    std::thread::sleep(Duration::from_millis(200));
    let control = evaluator
        .session
        .declare_subscriber(keys.control())
        .wait()
        .unwrap();
    let sample = control
        .recv_timeout(Duration::from_secs(5))
        .unwrap()
        .expect("the late evaluator heard no Stop");
    let stop: Stop = codec::decode(&sample.payload().to_bytes()).unwrap();
    assert_eq!(stop.reason, "max_epochs reached");
    evaluator.close_blocking().unwrap();
    let took = stopping.join().unwrap();
    assert!(
        took < Duration::from_secs(9),
        "the learner said Stop for {took:?} after the evaluator left"
    );
}
