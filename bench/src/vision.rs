//! `cabc bench-vision`: the camera policy's training and inference throughput, for the figures issue 22 asks of
//! a GPU (the anchor there: PyTorch 2.11 on an H100, a ResNet-18 trunk plus the paper's 3x128 head with the
//! velocities, 224x224, Adam, gradient clip 1.0). The policy is the one a run trains (`Policy` with the run's
//! architecture); the optimiser `--optimiser`: the run's own Adam (`cabc_learning::train::Adam`: one flat buffer, the
//! clip's coefficient kept on the GPU), the same with the coefficient read back to the host each step, or tch's Adam
//! (one libtorch call per variable and operation, the clip read back: the first CUDA run's figure, docs/GPU.md); the
//! clip 1.0, the loss L_clone, the precision `--precision`. Images are random u8 HWC, uploaded once, as a fit's are.

use cabc_learning::train::Adam;
use cabc_models::precision::with_precision;
use cabc_models::{parse_device, Network, Policy, PolicyArch, PolicyInput, VelocityMask};
use cabc_proto::config::{MlpSize, Precision, VisionTrunk};
use serde::Serialize;
use std::time::Instant;
use tch::nn::OptimizerConfig;
use tch::{nn, Device, Kind, Reduction, Tensor};

/// `cabc bench-vision`'s options.
#[derive(Clone, Debug, clap::Args)]
pub struct VisionBenchOptions {
    /// Image side (224 in the paper).
    #[arg(long, default_value_t = 224)]
    pub side: i64,
    /// Training batch.
    #[arg(long, default_value_t = 64)]
    pub batch: i64,
    /// Timed training steps (after the warm-up).
    #[arg(long, default_value_t = 50)]
    pub steps: usize,
    #[arg(long, default_value_t = 10)]
    pub warmup: usize,
    /// fp32 or bf16 (CUDA autocast).
    #[arg(long, default_value = "fp32", value_parser = parse_precision)]
    pub precision: Precision,
    /// resnet18 or small-cnn.
    #[arg(long, default_value = "resnet18", value_parser = parse_trunk)]
    pub trunk: VisionTrunk,
    /// "auto", "cpu" or "cuda:N".
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// run (the run's own Adam), run-host-clip (its clip coefficient read back each step) or tch (tch's Adam).
    #[arg(long, default_value = "run", value_parser = ["run", "run-host-clip", "tch"])]
    pub optimiser: String,
    /// Inference batches to time (images per second at each).
    #[arg(long, value_delimiter = ',', default_value = "1,8,64")]
    pub infer: Vec<i64>,
}

fn parse_precision(s: &str) -> Result<Precision, String> {
    match s {
        "fp32" => Ok(Precision::Fp32),
        "bf16" => Ok(Precision::Bf16),
        _ => Err(format!("{s}: expected fp32 or bf16")),
    }
}

fn parse_trunk(s: &str) -> Result<VisionTrunk, String> {
    match s {
        "resnet18" => Ok(VisionTrunk::Resnet18),
        "small-cnn" => Ok(VisionTrunk::SmallCnn),
        _ => Err(format!("{s}: expected resnet18 or small-cnn")),
    }
}

/// What `cabc bench-vision` measured.
#[derive(Clone, Debug, Serialize)]
pub struct VisionBench {
    pub device: String,
    pub architecture: String,
    pub side: i64,
    pub batch: i64,
    pub precision: String,
    pub optimiser: String,
    /// Training images per second (forward, backward, clip, Adam step), median of per-step rates.
    pub train_images_per_s: f64,
    /// (batch, images per second) of inference in eval mode, no gradients.
    pub infer_images_per_s: Vec<(i64, f64)>,
}

fn synchronize(device: Device) {
    if let Device::Cuda(i) = device {
        tch::Cuda::synchronize(i as i64);
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Adam (lr 1e-3, weight decay 1e-4) with the clip 1.0, as `--optimiser` names it.
enum Optimiser {
    Run(Adam),
    Tch(nn::Optimizer),
}

impl Optimiser {
    fn new(name: &str, vs: &nn::VarStore) -> anyhow::Result<Self> {
        Ok(match name {
            "tch" => Optimiser::Tch(nn::Adam::default().wd(1e-4).build(vs, 1e-3)?),
            _ => {
                let mut adam = Adam::new(vs, 1e-3, 1e-4);
                adam.device_clip &= name == "run";
                Optimiser::Run(adam)
            }
        })
    }

    /// zero_grad, backward, clip, step.
    fn step(&mut self, loss: &Tensor) {
        match self {
            Optimiser::Run(adam) => {
                adam.zero_grad();
                loss.backward();
                adam.clip_grad_norm(1.0, &[]);
                adam.step();
            }
            Optimiser::Tch(opt) => {
                opt.zero_grad();
                loss.backward();
                opt.clip_grad_norm(1.0);
                opt.step();
            }
        }
    }
}

/// Runs the benchmark.
pub fn run(o: &VisionBenchOptions) -> anyhow::Result<VisionBench> {
    let device = parse_device(&o.device)?;
    let arch = PolicyArch::Camera {
        trunk: o.trunk,
        mlp: MlpSize {
            layers: 3,
            width: 128,
        },
        sees: VelocityMask::ALL,
    };
    let policy = Policy::new(arch, device, 1);
    let mut opt = Optimiser::new(&o.optimiser, policy.var_store())?;
    let images = |n: i64| Tensor::randint(256, [n, o.side, o.side, 3], (Kind::Uint8, device));
    let (x, v, label) = (
        images(o.batch),
        Tensor::randn([o.batch, 3], (Kind::Float, device)),
        Tensor::randn([o.batch, 2], (Kind::Float, device)),
    );
    let input = PolicyInput::Camera {
        images: x,
        velocity: v,
    };
    let mut rates = Vec::with_capacity(o.steps);
    for step in 0..o.warmup + o.steps {
        synchronize(device);
        let t = Instant::now();
        let loss = with_precision(o.precision, device, || {
            policy
                .forward_t(&input, true)
                .to_kind(Kind::Float)
                .mse_loss(&label, Reduction::Mean)
        });
        opt.step(&loss);
        synchronize(device);
        if step >= o.warmup {
            rates.push(o.batch as f64 / t.elapsed().as_secs_f64());
        }
    }
    let mut infer = Vec::new();
    for &n in &o.infer {
        let input = PolicyInput::Camera {
            images: images(n),
            velocity: Tensor::randn([n, 3], (Kind::Float, device)),
        };
        let mut r = Vec::new();
        tch::no_grad(|| {
            for step in 0..o.warmup + o.steps {
                synchronize(device);
                let t = Instant::now();
                let _ = with_precision(o.precision, device, || policy.forward_t(&input, false));
                synchronize(device);
                if step >= o.warmup {
                    r.push(n as f64 / t.elapsed().as_secs_f64());
                }
            }
        });
        infer.push((n, median(r)));
    }
    Ok(VisionBench {
        device: format!("{device:?}"),
        architecture: policy.architecture(),
        side: o.side,
        batch: o.batch,
        precision: format!("{:?}", o.precision).to_lowercase(),
        optimiser: o.optimiser.clone(),
        train_images_per_s: median(rates),
        infer_images_per_s: infer,
    })
}
