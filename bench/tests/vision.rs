//! `cabc bench-vision` on the CPU at a small side: each optimiser trains the camera policy and is named in the
//! figures (the GPU's figures come from deploy/gpu-session.sh).

use cabc_bench::vision::{run, VisionBenchOptions};
use clap::Parser;

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    options: VisionBenchOptions,
}

fn options(args: &[&str]) -> Result<VisionBenchOptions, clap::Error> {
    let base = [
        "bench-vision",
        "--side",
        "32",
        "--batch",
        "4",
        "--steps",
        "2",
        "--warmup",
        "1",
    ];
    let args = base.iter().chain(args).copied();
    Cli::try_parse_from(args).map(|c| c.options)
}

#[test]
fn each_optimiser_trains_the_camera_policy_and_is_named() {
    for optimiser in ["run", "run-host-clip", "tch"] {
        let o = options(&["--device", "cpu", "--infer", "1", "--optimiser", optimiser]).unwrap();
        let bench = run(&o).unwrap();
        assert_eq!(bench.optimiser, optimiser);
        assert_eq!(bench.architecture, "policy-camera-resnet18-mlp-3x128");
        assert!(bench.train_images_per_s.is_finite() && bench.train_images_per_s > 0.0);
        assert_eq!(bench.infer_images_per_s.len(), 1);
    }
}

#[test]
fn an_unknown_optimiser_is_refused() {
    let e = options(&["--optimiser", "sgd"]).expect_err("refused");
    assert!(e.to_string().contains("sgd"), "{e}");
}
