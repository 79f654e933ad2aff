//! An epoch's losses as the tests read them: from the record `Trainer::train_epoch` writes, the one place an epoch's
//! losses and samples are kept (what `metrics.csv`, TensorBoard and the bus get).
#![allow(dead_code)]

use cabc_learning::record::Record;
use cabc_learning::{Replay, Trainer};

/// The training metrics of one epoch's record (its wall clock, `train_s`, left out: two runs compare equal).
#[derive(Clone, Debug, PartialEq)]
pub struct Losses {
    pub imitation: f64,
    pub safety: f64,
    pub safety_active: bool,
    pub dynamics: Option<f64>,
    pub critic: Option<f64>,
    pub critic_accuracy: Option<f64>,
    pub critic_points: Option<usize>,
    pub critic_positives: Option<usize>,
    pub policy_samples: usize,
    pub dynamics_samples: usize,
    pub critic_samples: usize,
    pub lr_policy: f64,
    /// lambda_j, written while it warms up (`algorithm.lambda_start`).
    pub lambda: Option<f64>,
}

impl Losses {
    pub fn of(record: &Record) -> Self {
        let count = |name| record.u64(name).map(|n| n as usize);
        Losses {
            imitation: record.f64("imitation_loss").expect("imitation_loss"),
            safety: record.f64("safety_loss").expect("safety_loss"),
            safety_active: record.f64("safety_active").expect("safety_active") == 1.0,
            dynamics: record.f64("dynamics_loss"),
            critic: record.f64("critic_loss"),
            critic_accuracy: record.f64("critic_accuracy"),
            critic_points: count("critic_points"),
            critic_positives: count("critic_positives"),
            policy_samples: count("policy_samples").unwrap_or(0),
            dynamics_samples: count("dynamics_samples").unwrap_or(0),
            critic_samples: count("critic_samples").unwrap_or(0),
            lr_policy: record.f64("lr_policy").expect("lr_policy"),
            lambda: record.f64("lambda"),
        }
    }
}

/// One epoch of `t` on `replay`: its losses, from its record.
pub fn train(t: &mut Trainer, epoch: u64, replay: &Replay) -> Losses {
    let mut record = Record::new(epoch);
    t.train_epoch(epoch, replay, &mut record).expect("trains");
    Losses::of(&record)
}

/// Issue 13's experiment: `k + 1` epochs straight, against `k` epochs, a checkpoint (in `dir`), a resume into a new
/// trainer and one more epoch.
pub struct Resumed {
    pub straight: Trainer,
    pub straight_losses: Vec<Losses>,
    pub resumed: Trainer,
    pub losses: Vec<Losses>,
    pub dir: tempfile::TempDir,
}

impl Resumed {
    pub fn run(config: &cabc_proto::config::RunConfig, replay: &Replay, k: u64) -> Self {
        let device = tch::Device::Cpu;
        let mut straight = Trainer::with_device(config, device);
        let straight_losses = (0..=k).map(|e| train(&mut straight, e, replay)).collect();
        let mut first = Trainer::with_device(config, device);
        let mut losses: Vec<Losses> = (0..k).map(|e| train(&mut first, e, replay)).collect();
        let dir = tempfile::tempdir().unwrap();
        cabc_learning::CheckpointWriter::new(dir.path().join("checkpoint"))
            .files(first.to_checkpoint())
            .commit()
            .unwrap();
        drop(first);
        let checkpoint = cabc_learning::Checkpoint::open(&dir.path().join("checkpoint")).unwrap();
        let mut resumed = Trainer::resume(config, &checkpoint).unwrap();
        losses.push(train(&mut resumed, k, replay));
        Resumed {
            straight,
            straight_losses,
            resumed,
            losses,
            dir,
        }
    }

    /// The checkpoint the resume started from.
    pub fn checkpoint(&self) -> std::path::PathBuf {
        self.dir.path().join("checkpoint")
    }
}
