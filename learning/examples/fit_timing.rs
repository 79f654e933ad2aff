//! `cargo run --release -p cabc-learning --example fit_timing -- RUN_DIR`: times each fit of one training epoch (one
//! pass each) on a run's checkpoint (its configuration, networks and replay), to find where an epoch's time goes.
//! It found the subnormal floats that `cabc_models::flush_denormals` now flushes: on `v-b-ref-s1`'s checkpoint at
//! epoch 136 (D+ 50,408, D? 48,322) the critic's pass took 45.5 s with them and 4.9 s without.

use cabc_learning::checkpoint::Checkpoint;
use cabc_learning::replay::Replay;
use cabc_learning::train::Trainer;
use cabc_proto::config::RunConfig;
use std::path::Path;
use std::time::Instant;

fn main() {
    let dir = std::env::args().nth(1).expect("a run folder");
    let dir = Path::new(&dir);
    let mut config = RunConfig::load(dir.join("config.toml").to_str().unwrap()).unwrap();
    config.training.device = "cpu".into();
    let ck = Checkpoint::open(&dir.join("checkpoint")).unwrap();
    let replay = Replay::from_checkpoint(&ck.read("replay.bin").unwrap(), dir)
        .unwrap()
        .0;
    println!(
        "D+ {} D? {} D- {}",
        replay.len_plus(),
        replay.len_uncertain(),
        replay.len_minus()
    );
    let mut t = Trainer::resume(&config, &ck).unwrap();
    let time = |f: &mut dyn FnMut()| {
        let s = Instant::now();
        f();
        s.elapsed().as_secs_f64()
    };
    let dynamics = time(&mut || {
        t.fit_dynamics(&replay, 1);
    });
    let critic = time(&mut || {
        t.fit_critic(&replay, 1);
    });
    let policy = time(&mut || {
        t.fit_policy(&replay, 1).unwrap();
    });
    println!(
        "one pass each: dynamics {dynamics:.2} s, critic {critic:.2} s, policy {policy:.2} s (subnormals flushed: {})",
        cabc_models::device::flushes_denormals()
    );
}
