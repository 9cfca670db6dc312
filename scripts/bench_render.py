#!/usr/bin/env python
"""Rendering benchmark, in one run:

1. seconds per 640×480 frame (clutter recipe camera, 12 synthetic boxes in its bin) at 1, 16 and
   64 samples, without and with OpenImageDenoise (Python, blender_scripts.session);
2. seconds per 128×128 crop re-render from Rust (boxpose-render, embedded Blender) with the scene
   reused, reused after moving a box, and rebuilt before every render
   (`cargo bench -p boxpose-render --bench crop_rerender`).

    python scripts/bench_render.py [--samples 1,16,64] [--repeats 2] [--crop-samples 16]
                                   [--skip-rust]

Cycles uses every core; the machine's load average is printed, since renders slow down 2–3×
when other jobs share the cores. CPU seconds (all threads of the process) are printed too: they
depend far less on other jobs, and CPU / cores estimates the wall time on an idle machine.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", default="1,16,64")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--boxes", type=int, default=12)
    ap.add_argument("--crop-samples", type=int, default=16)
    ap.add_argument("--crop-repeats", type=int, default=5)
    ap.add_argument("--skip-rust", action="store_true")
    args = ap.parse_args()

    from blender_scripts.bench import bench_scene
    from blender_scripts.session import Session

    print(
        f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())} "
        f"on {os.cpu_count()} cores"
    )
    t = time.perf_counter()
    session = Session()
    print(f"Blender started in {time.perf_counter() - t:.2f} s")
    scene, objects = bench_scene(args.boxes)
    t = time.perf_counter()
    session.load(scene, objects)
    print(f"scene with {args.boxes} boxes built in {time.perf_counter() - t:.2f} s")
    session.render(0, samples=1, denoise=False)  # warm-up: Cycles device init, BVH
    rows = []
    for samples in (int(s) for s in args.samples.split(",")):
        for denoise in (False, True):
            times, cpu = [], []
            for _ in range(args.repeats):
                t, c = time.perf_counter(), time.process_time()
                session.render(0, samples=samples, denoise=denoise)
                times.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            mean, cpu_mean = sum(times) / len(times), sum(cpu) / len(cpu)
            rows.append((samples, denoise, mean, min(times)))
            print(
                f"640x480 frame at {samples:3d} samples"
                f"{' + denoise' if denoise else '          '}: "
                f"mean {mean:6.2f} s, min {min(times):6.2f} s, "
                f"CPU {cpu_mean:6.2f} s ({len(times)} renders)",
                flush=True,
            )
    print(f"load average after the frames: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    del session

    if not args.skip_rust:
        cmd = ["cargo", "bench", "-q", "-p", "boxpose-render", "--bench", "crop_rerender", "--",
               "--samples", str(args.crop_samples), "--repeats", str(args.crop_repeats),
               "--boxes", str(args.boxes)]  # fmt: skip
        print("$ " + " ".join(cmd), flush=True)
        r = subprocess.run(cmd, cwd=REPO)
        if r.returncode != 0:
            return r.returncode
        print(f"load average at the end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
