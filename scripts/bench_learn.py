"""Keypoint network speed: burn (this repo) next to PyTorch on the same architecture, same run.

For each layout (the shipped `slim`, and ResNet-18), measures the median training step (forward,
MSE loss, backward, Adam) at batch 8 on 128² RGBD crops with a 48×32×32 heatmap, and the
per-crop inference time at batch 1 and 16, then prints burn / PyTorch ratios. PyTorch runs from
build/torch-venv (torch==2.9.0, created by `make bench-learn`), on as many threads as burn uses.

    make bench-learn     # = build/torch-venv/bin/python scripts/bench_learn.py
"""

import argparse
import json
import os
import subprocess
import time
from pathlib import Path

import torch
from torch import nn

REPO = Path(__file__).resolve().parent.parent
LAYOUTS = {  # widths, blocks, head channels: rust/learn/src/config.rs
    "slim": ([32, 64, 128, 256], [2, 2, 2, 2], 128),
    "resnet18": ([64, 128, 256, 512], [2, 2, 2, 2], 256),
}


class BasicBlock(nn.Module):
    def __init__(self, cin, cout, stride):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(
                nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout)
            )

    def forward(self, x):
        identity = x if self.down is None else self.down(x)
        x = torch.relu(self.bn1(self.conv1(x)))
        return torch.relu(self.bn2(self.conv2(x)) + identity)


class KeypointNet(nn.Module):
    """rust/learn/src/model.rs, layer for layer."""

    def __init__(self, layout, depth_bins):
        super().__init__()
        widths, blocks, head = LAYOUTS[layout]
        self.stem = nn.Sequential(
            nn.Conv2d(4, widths[0], 7, 2, 3, bias=False),
            nn.BatchNorm2d(widths[0]),
            nn.ReLU(),
            nn.MaxPool2d(3, 2, 1),
        )
        layers, c = [], widths[0]
        for stage, (w, n) in enumerate(zip(widths, blocks, strict=True)):
            for b in range(n):
                layers.append(BasicBlock(c, w, 2 if stage > 0 and b == 0 else 1))
                c = w
        self.stages = nn.Sequential(*layers)
        ups = []
        for _ in range(3):
            ups += [
                nn.ConvTranspose2d(c, head, 4, 2, 1, bias=False),
                nn.BatchNorm2d(head),
                nn.ReLU(),
            ]
            c = head
        self.head = nn.Sequential(*ups)
        self.output = nn.Conv2d(c, depth_bins, 1)

    def forward(self, x):
        return self.output(self.head(self.stages(self.stem(x))))


def median(values):
    return sorted(values)[len(values) // 2]


def bench_torch(layout, batch, size, depth_bins, steps):
    net = KeypointNet(layout, depth_bins)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    n = size // 4
    times = []
    for i in range(steps + 2):
        x, target = torch.randn(batch, 4, size, size), torch.rand(batch, depth_bins, n, n)
        start = time.perf_counter()
        loss = ((net(x) - target) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        loss.item()
        if i >= 2:
            times.append((time.perf_counter() - start) * 1e3)
    net.eval()

    def per_crop(crops, repeats):
        out = []
        with torch.no_grad():
            for i in range(repeats + 1):
                x = torch.randn(crops, 4, size, size)
                start = time.perf_counter()
                net(x).numpy()
                if i >= 1:
                    out.append((time.perf_counter() - start) * 1e3 / crops)
        return median(out)

    return {
        "implementation": f"pytorch-{torch.__version__}",
        "backbone": layout,
        "batch": batch,
        "size": size,
        "depth_bins": depth_bins,
        "train_step_ms": median(times),
        "crop_ms_batch1": per_crop(1, 10),
        "crop_ms_batch16": per_crop(16, 3),
    }


def bench_burn(layout, batch, size, depth_bins, steps):
    # --workspace, not -p: the same feature set as `make setup`'s build, so burn is not rebuilt
    cmd = [
        "cargo",
        "bench",
        "--quiet",
        "--workspace",
        "--bench",
        "keypoint_step",
        "--",
        "--backbone",
        layout,
        "--batch",
        str(batch),
        "--size",
        str(size),
        "--depth-bins",
        str(depth_bins),
        "--steps",
        str(steps),
    ]
    out = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--layouts",
        default="slim,resnet18",
        help="comma-separated layouts (default: slim,resnet18)",
    )
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--depth-bins", type=int, default=48)
    ap.add_argument(
        "--steps", type=int, default=10, help="timed training steps (after 2 warm-up steps)"
    )
    ap.add_argument(
        "--threads",
        type=int,
        default=os.cpu_count(),
        help="PyTorch threads (default: every core, as burn's flex)",
    )
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(
        f"keypoint network, batch {args.batch}, {args.size}² input, "
        f"{args.depth_bins}×{args.size // 4}² heatmap, {args.threads} threads"
    )
    print(
        f"{'layout':<10} {'implementation':<20} "
        f"{'train step':>11} {'crop (b=1)':>11} {'crop (b=16)':>12}"
    )
    for layout in args.layouts.split(","):
        rows = [
            bench_burn(layout, args.batch, args.size, args.depth_bins, args.steps),
            bench_torch(layout, args.batch, args.size, args.depth_bins, args.steps),
        ]
        for r in rows:
            print(
                f"{layout:<10} {r['implementation']:<20} {r['train_step_ms']:>8.0f} ms "
                f"{r['crop_ms_batch1']:>8.1f} ms {r['crop_ms_batch16']:>9.1f} ms"
            )
        burn, ref = rows
        print(
            f"{layout:<10} {'burn / pytorch':<20} "
            f"{burn['train_step_ms'] / ref['train_step_ms']:>10.2f}× "
            f"{burn['crop_ms_batch1'] / ref['crop_ms_batch1']:>10.2f}× "
            f"{burn['crop_ms_batch16'] / ref['crop_ms_batch16']:>11.2f}×"
        )


if __name__ == "__main__":
    main()
