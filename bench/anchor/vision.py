"""PyTorch's figure for `cabc bench-vision`, measured in the same call on the same machine (issue 48).

The same network and step as bench/src/vision.rs: torchvision's ResNet-18 without its classifier (512 features)
plus the 3x128 ReLU head on the features and the 3 velocities, 2 outputs; Adam (lr 1e-3, weight decay 1e-4),
L_clone (MSE), gradient-norm clip 1.0; u8 NHWC images on the device, permuted and divided by 255 inside the step;
bf16 as CUDA autocast. Prints one JSON object in bench-vision's shape.

    python3 bench/anchor/vision.py --precision fp32|bf16 [--side 224] [--batch 64] [--steps 50] [--warmup 10]
"""

import argparse
import json
import statistics
import time

import torch
import torchvision


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--side", type=int, default=224)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--warmup", type=int, default=10)
    p.add_argument("--precision", choices=["fp32", "bf16"], default="fp32")
    p.add_argument("--infer", default="1,8,64")
    p.add_argument("--tf32", choices=["default", "on", "off"], default="default",
                   help="cuDNN's TF32 for fp32 convolutions (PyTorch's default: on)")
    o = p.parse_args()
    if o.tf32 != "default":
        torch.backends.cudnn.allow_tf32 = o.tf32 == "on"
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    torch.manual_seed(1)
    trunk = torchvision.models.resnet18()
    trunk.fc = torch.nn.Identity()
    head = torch.nn.Sequential(
        torch.nn.Linear(512 + 3, 128), torch.nn.ReLU(),
        torch.nn.Linear(128, 128), torch.nn.ReLU(),
        torch.nn.Linear(128, 128), torch.nn.ReLU(),
        torch.nn.Linear(128, 2),
    )
    trunk.to(device)
    head.to(device)
    params = list(trunk.parameters()) + list(head.parameters())
    opt = torch.optim.Adam(params, lr=1e-3, weight_decay=1e-4)
    bf16 = o.precision == "bf16" and device.type == "cuda"

    def images(n):
        return torch.randint(0, 256, (n, o.side, o.side, 3), dtype=torch.uint8, device=device)

    def forward(x, v):
        with torch.autocast("cuda", dtype=torch.bfloat16, enabled=bf16):
            f = trunk(x.permute(0, 3, 1, 2).float() / 255.0)
            return head(torch.cat([f, v], 1))

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    x, v = images(o.batch), torch.randn(o.batch, 3, device=device)
    label = torch.randn(o.batch, 2, device=device)
    trunk.train()
    rates = []
    for step in range(o.warmup + o.steps):
        sync()
        t = time.perf_counter()
        loss = torch.nn.functional.mse_loss(forward(x, v).float(), label)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        sync()
        if step >= o.warmup:
            rates.append(o.batch / (time.perf_counter() - t))
    trunk.eval()
    infer = []
    with torch.no_grad():
        for n in [int(s) for s in o.infer.split(",")]:
            xi, vi = images(n), torch.randn(n, 3, device=device)
            r = []
            for step in range(o.warmup + o.steps):
                sync()
                t = time.perf_counter()
                forward(xi, vi)
                sync()
                if step >= o.warmup:
                    r.append(n / (time.perf_counter() - t))
            infer.append([n, statistics.median_high(r)])
    print(json.dumps({
        "device": str(device),
        "architecture": f"pytorch {torch.__version__} torchvision resnet18 + mlp 3x128",
        "side": o.side,
        "batch": o.batch,
        "precision": o.precision,
        "cudnn_tf32": torch.backends.cudnn.allow_tf32,
        "train_images_per_s": statistics.median_high(rates),
        "infer_images_per_s": infer,
    }))


if __name__ == "__main__":
    main()
