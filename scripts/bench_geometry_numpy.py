"""Batched NumPy brute force of the paper's correspondence search, timed against boxpose-geometry.

The paper (section III-D-2) fits every ordered injective assignment of the m = 5 highest-scoring
NMS peaks to the 8 box corners (8!/3! = 6720) by least squares "in a single pass using PyTorch".
This script does the same with NumPy: all 6720 Kabsch fits of a box at once with a batched SVD,
then (second figure) all boxes at once. It reads the scenes, and the Rust timings, that the Rust
example `bench_inputs` writes, checks that the minima agree with the Rust searches, and prints
the speed ratios.

    .venv/bin/python scripts/bench_geometry_numpy.py [--inputs FILE] [--scenes N]

Without --inputs it first runs
`cargo run --release -p boxpose-geometry --example bench_inputs -- FILE N`.
"""

import argparse
import itertools
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

CORNER_SIGNS = np.array(
    [[1 if (i >> axis) & 1 else -1 for axis in range(3)] for i in range(8)], float
)


def brute_force(points, scores, sizes, m):
    """Least sum of squared residuals over all assignments, for a batch of boxes.

    points (B, n, 3), scores (B, n), sizes (B, 3) -> (B,) minima.
    """
    assignments = np.array(list(itertools.permutations(range(8), m)))  # (K, m)
    # The m highest scores, ties to the lower index, as the Rust side.
    top = np.argsort(-scores, axis=1, kind="stable")[:, :m]
    peaks = np.take_along_axis(points, top[:, :, None], axis=1)  # (B, m, 3)
    corners = CORNER_SIGNS[None] * sizes[:, None, :] / 2  # (B, 8, 3)
    models = corners[:, assignments]  # (B, K, m, 3)
    models = models - models.mean(axis=2, keepdims=True)
    peaks = peaks - peaks.mean(axis=1, keepdims=True)
    cross = np.einsum("bkmi,bmj->bkij", models, peaks)  # Σ a bᵀ
    u, _, vt = np.linalg.svd(cross)
    # R = V diag(1, 1, d) Uᵀ with d = det(V Uᵀ): a proper rotation.
    d = np.sign(np.linalg.det(np.einsum("bkji,bklj->bkil", vt, u)))
    v = np.swapaxes(vt, -1, -2).copy()
    v[..., :, 2] *= d[..., None]
    rotation = v @ np.swapaxes(u, -1, -2)
    residual = np.einsum("bkij,bkmj->bkmi", rotation, models) - peaks[:, None]
    return (residual**2).sum(axis=(2, 3)).min(axis=1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=Path, help="JSON written by the bench_inputs example")
    parser.add_argument("--scenes", type=int, default=200)
    args = parser.parse_args()
    if args.inputs is None:
        args.inputs = Path(tempfile.mkdtemp()) / "geometry_bench_inputs.json"
        subprocess.run(
            [
                "cargo",
                "run",
                "--release",
                "-q",
                "-p",
                "boxpose-geometry",
                "--example",
                "bench_inputs",
                "--",
                str(args.inputs),
                str(args.scenes),
            ],
            check=True,
        )
    data = json.loads(args.inputs.read_text())
    m = data["m"]
    scenes = data["scenes"]
    points = np.array([s["points"] for s in scenes])
    scores = np.array([s["scores"] for s in scenes])
    sizes = np.array([s["size"] for s in scenes])
    rust_minima = np.array([s["paper_sse"] for s in scenes])
    fast_minima = np.array([s["fast_sse"] for s in scenes])

    brute_force(points[:1], scores[:1], sizes[:1], m)  # warm-up
    started = time.perf_counter()
    per_box = np.concatenate(
        [
            brute_force(points[i : i + 1], scores[i : i + 1], sizes[i : i + 1], m)
            for i in range(len(scenes))
        ]
    )
    per_box_seconds = (time.perf_counter() - started) / len(scenes)
    started = time.perf_counter()
    all_at_once = brute_force(points, scores, sizes, m)
    all_at_once_seconds = (time.perf_counter() - started) / len(scenes)

    tolerance = 1e-9 * rust_minima + 1e-12
    for name, minima in [
        ("numpy per box", per_box),
        ("numpy all boxes", all_at_once),
        ("rust fast", fast_minima),
    ]:
        worst = np.max(np.abs(minima - rust_minima) - tolerance)
        status = "agree" if worst <= 0 else f"DISAGREE (worst excess {worst:.3e})"
        print(f"{name} vs rust paper-exact minima: {status}")

    fast = data["rust_fast_exact_seconds_per_box"]
    paper = data["rust_paper_exact_seconds_per_box"]
    print(
        f"{len(scenes)} boxes, m = {m}, "
        f"{len(list(itertools.permutations(range(8), m)))} assignments each"
    )
    print(f"  numpy brute force, one box per call:   {per_box_seconds * 1e6:10.1f} µs/box")
    print(f"  numpy brute force, all boxes per call: {all_at_once_seconds * 1e6:10.1f} µs/box")
    print(f"  rust paper-exact (brute force, SVD):   {paper * 1e6:10.1f} µs/box")
    print(f"  rust fast exact (branch and bound):    {fast * 1e6:10.2f} µs/box")
    print(f"  ratio numpy per box / rust fast:   {per_box_seconds / fast:8.0f}x")
    print(f"  ratio numpy all boxes / rust fast: {all_at_once_seconds / fast:8.0f}x")


if __name__ == "__main__":
    main()
