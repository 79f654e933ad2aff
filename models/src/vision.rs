//! The vision trunks of the camera policy (algorithm.md 4), written with `tch::nn`:
//!
//! * ResNet-18 (He et al. 2016; torchvision's layout: 7x7/2 stem, max-pool, four stages of two basic blocks,
//!   global average pool) with the classifier removed: 512 features. Trained from scratch here.
//! * A small 4-layer CNN for CPU-only machines: 128 features.
//!
//! Both end in a global average pool, so they accept any image size. Input: float NCHW in [0, 1].

use cabc_proto::config::VisionTrunk;
use tch::{nn, nn::ModuleT, Tensor};

fn conv(
    p: nn::Path,
    c_in: i64,
    c_out: i64,
    k: i64,
    stride: i64,
    padding: i64,
    bias: bool,
) -> nn::Conv2D {
    let config = nn::ConvConfig {
        stride,
        padding,
        bias,
        ws_init: nn::Init::Const(0.0),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    nn::conv2d(p, c_in, c_out, k, config)
}

fn bn(p: nn::Path, c: i64) -> nn::BatchNorm {
    let config = nn::BatchNormConfig {
        ws_init: nn::Init::Const(1.0),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    nn::batch_norm2d(p, c, config)
}

/// conv3x3-bn-relu-conv3x3-bn, plus the identity (or a 1x1/stride downsample), then relu.
#[derive(Debug)]
struct BasicBlock {
    conv1: nn::Conv2D,
    bn1: nn::BatchNorm,
    conv2: nn::Conv2D,
    bn2: nn::BatchNorm,
    downsample: Option<(nn::Conv2D, nn::BatchNorm)>,
}

impl BasicBlock {
    fn new(p: nn::Path, c_in: i64, c_out: i64, stride: i64) -> Self {
        let downsample = (stride != 1 || c_in != c_out).then(|| {
            (
                conv(&p / "downsample" / "0", c_in, c_out, 1, stride, 0, false),
                bn(&p / "downsample" / "1", c_out),
            )
        });
        BasicBlock {
            conv1: conv(&p / "conv1", c_in, c_out, 3, stride, 1, false),
            bn1: bn(&p / "bn1", c_out),
            conv2: conv(&p / "conv2", c_out, c_out, 3, 1, 1, false),
            bn2: bn(&p / "bn2", c_out),
            downsample,
        }
    }

    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let h = xs
            .apply(&self.conv1)
            .apply_t(&self.bn1, train)
            .relu()
            .apply(&self.conv2)
            .apply_t(&self.bn2, train);
        let skip = match &self.downsample {
            Some((c, b)) => xs.apply(c).apply_t(b, train),
            None => xs.shallow_clone(),
        };
        (h + skip).relu()
    }
}

/// ResNet-18 without its classifier.
#[derive(Debug)]
pub struct ResNet18 {
    conv1: nn::Conv2D,
    bn1: nn::BatchNorm,
    blocks: Vec<BasicBlock>,
}

impl ResNet18 {
    pub const FEATURES: i64 = 512;

    pub fn new(p: &nn::Path) -> Self {
        let mut blocks = Vec::with_capacity(8);
        let mut c_in = 64;
        for (stage, c_out) in [64i64, 128, 256, 512].into_iter().enumerate() {
            for i in 0..2 {
                let stride = if stage > 0 && i == 0 { 2 } else { 1 };
                let name = format!("layer{}", stage + 1);
                blocks.push(BasicBlock::new(
                    p / name / i.to_string(),
                    c_in,
                    c_out,
                    stride,
                ));
                c_in = c_out;
            }
        }
        ResNet18 {
            conv1: conv(p / "conv1", 3, 64, 7, 2, 3, false),
            bn1: bn(p / "bn1", 64),
            blocks,
        }
    }
}

impl ModuleT for ResNet18 {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let mut h = xs
            .apply(&self.conv1)
            .apply_t(&self.bn1, train)
            .relu()
            .max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false);
        for b in &self.blocks {
            h = b.forward_t(&h, train);
        }
        h.adaptive_avg_pool2d([1, 1]).flatten(1, -1)
    }
}

/// Four strided convolutions with ReLU, then a global average pool.
#[derive(Debug)]
pub struct SmallCnn {
    convs: Vec<nn::Conv2D>,
}

impl SmallCnn {
    pub const FEATURES: i64 = 128;

    pub fn new(p: &nn::Path) -> Self {
        let spec = [
            (3, 32, 5),
            (32, 64, 3),
            (64, 128, 3),
            (128, Self::FEATURES, 3),
        ];
        let convs = spec
            .iter()
            .enumerate()
            .map(|(i, &(c_in, c_out, k))| conv(p / i.to_string(), c_in, c_out, k, 2, k / 2, true))
            .collect();
        SmallCnn { convs }
    }
}

impl ModuleT for SmallCnn {
    fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
        let h = self
            .convs
            .iter()
            .fold(xs.shallow_clone(), |h, c| h.apply(c).relu());
        h.adaptive_avg_pool2d([1, 1]).flatten(1, -1)
    }
}

/// One of the trunks.
#[derive(Debug)]
pub enum Trunk {
    Resnet18(Box<ResNet18>),
    SmallCnn(SmallCnn),
}

impl Trunk {
    pub fn new(p: &nn::Path, kind: VisionTrunk) -> Self {
        match kind {
            VisionTrunk::Resnet18 => Trunk::Resnet18(Box::new(ResNet18::new(p))),
            VisionTrunk::SmallCnn => Trunk::SmallCnn(SmallCnn::new(p)),
        }
    }

    pub fn features(kind: VisionTrunk) -> i64 {
        match kind {
            VisionTrunk::Resnet18 => ResNet18::FEATURES,
            VisionTrunk::SmallCnn => SmallCnn::FEATURES,
        }
    }
}

impl ModuleT for Trunk {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        match self {
            Trunk::Resnet18(t) => t.forward_t(xs, train),
            Trunk::SmallCnn(t) => t.forward_t(xs, train),
        }
    }
}
