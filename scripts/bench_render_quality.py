#!/usr/bin/env python
"""Quality-matched rendering benchmark (`make bench-render-quality`): what image quality each
Cycles setting buys, and at what cost, against a converged reference of the same scene.

For the shipped recipes' cameras, lighting and image sizes (`single_box`: one box on the floor at
256×256; `clutter`: 12 boxes in the bin at 640×480), on seeded synthetic scenes:

1. a reference at --reference-samples samples (1024, no denoising);
2. every setting of the sweep: samples × denoiser (none, OpenImageDenoise at FAST, BALANCED and
   HIGH quality) × max light bounces (the recipes' 4, and 2);
3. per setting: PSNR and SSIM of the 8-bit sRGB image against the reference, CPU-seconds per image
   (every thread of this process, `time.process_time`) and wall seconds.

Kubric's default settings (128 samples with denoising; its default image size is 256², the size
of `single_box` here) are a row of every table. The Pareto front (no setting cheaper with a higher
PSNR) is marked, and the cheapest setting whose PSNR matches Kubric's is compared with it.

    python scripts/bench_render_quality.py [--scenes 3] [--reference-samples 1024]
                                           [--samples 1,4,16,64,128] [--recipes single_box,clutter]
"""

from __future__ import annotations

import argparse
import io
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parent.parent
DENOISERS = ("none", "FAST", "BALANCED", "HIGH")
KUBRIC = (128, "HIGH", 4)  # samples, OIDN quality (Blender's default), bounces as the recipes'
RECIPE_BOXES = {"single_box": 1, "clutter": 12}


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two 8-bit images (peak 255), over every channel."""
    mse = np.mean((image.astype(np.float64) - reference.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def _gaussian_blur(x: np.ndarray, sigma: float = 1.5, radius: int = 5) -> np.ndarray:
    """Separable Gaussian filter (11 taps, σ = 1.5, Wang et al. 2004), valid region only."""
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    taps /= taps.sum()
    rows = np.lib.stride_tricks.sliding_window_view(x, 2 * radius + 1, axis=0) @ taps
    return np.lib.stride_tricks.sliding_window_view(rows, 2 * radius + 1, axis=1) @ taps


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean structural similarity (Wang, Bovik, Sheikh, Simoncelli 2004: Gaussian window σ = 1.5,
    K1 = 0.01, K2 = 0.03, dynamic range 255), averaged over the three channels."""
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    values = []
    for ch in range(3):
        x = image[..., ch].astype(np.float64)
        y = reference[..., ch].astype(np.float64)
        mx, my = _gaussian_blur(x), _gaussian_blur(y)
        sxx = _gaussian_blur(x * x) - mx * mx
        syy = _gaussian_blur(y * y) - my * my
        sxy = _gaussian_blur(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        values.append(s.mean())
    return float(np.mean(values))


@dataclass
class Row:
    samples: int
    denoiser: str
    bounces: int
    cpu_s: list[float]
    wall_s: list[float]
    psnr: list[float]
    ssim: list[float]

    def name(self) -> str:
        d = "no denoise" if self.denoiser == "none" else f"OIDN {self.denoiser.lower()}"
        return f"{self.samples:>4} spp, {d:<13}, {self.bounces} bounces"


def scene_text(recipe: str, bounces: int) -> str:
    text = (REPO / "datasets" / "recipes" / f"{recipe}.toml").read_text()
    return text.replace("[render]\n", f"[render]\nmax_bounces = {bounces}\n", 1)


def render(session, samples: int, denoiser: str) -> tuple[np.ndarray, float, float]:
    """One render of frame 0 of the loaded scene: (RGB array, CPU s, wall s)."""
    if denoiser != "none":
        session.blender.scene.cycles.denoising_quality = denoiser
    wall, cpu = time.perf_counter(), time.process_time()
    frame, _ = session.render(0, samples=samples, denoise=denoiser != "none")
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    rgb = np.asarray(Image.open(io.BytesIO(frame["rgb_png"])).convert("RGB"))
    return rgb, cpu, wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recipes", default="single_box,clutter")
    ap.add_argument("--scenes", type=int, default=3, help="synthetic scenes per recipe")
    ap.add_argument("--reference-samples", type=int, default=1024)
    ap.add_argument("--samples", default="1,4,16,64,128")
    ap.add_argument("--bounces", default="4,2")
    args = ap.parse_args()

    from blender_scripts.session import Session
    from blender_scripts.synthetic import synthetic_scene

    sweep_samples = [int(s) for s in args.samples.split(",")]
    sweep_bounces = [int(b) for b in args.bounces.split(",")]
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    session = Session()
    for recipe in args.recipes.split(","):
        rows: dict[tuple[int, str, int], Row] = {}
        for k in range(args.scenes):
            references = {}
            for bounces in sweep_bounces:
                scene, objects = synthetic_scene(
                    k, scene_text(recipe, bounces), RECIPE_BOXES[recipe], seed=500 + k,
                    stack=recipe == "clutter", spread_m=0.24 if recipe == "clutter" else None,
                )  # fmt: skip
                session.load(scene, objects)
                render(session, 1, "none")  # warm-up: BVH, device
                if bounces == max(sweep_bounces):
                    references[k], cpu, wall = render(session, args.reference_samples, "none")
                    print(f"{recipe} scene {k}: reference at {args.reference_samples} spp, "
                          f"{cpu:.0f} CPU-s, {wall:.0f} s", flush=True)  # fmt: skip
                settings = [(s, d) for s in sweep_samples for d in DENOISERS]
                if bounces == KUBRIC[2] and (KUBRIC[0], KUBRIC[1]) not in settings:
                    settings.append((KUBRIC[0], KUBRIC[1]))
                for samples, denoiser in settings:
                    image, cpu, wall = render(session, samples, denoiser)
                    row = rows.setdefault(
                        (samples, denoiser, bounces),
                        Row(samples, denoiser, bounces, [], [], [], []),
                    )
                    row.cpu_s.append(cpu)
                    row.wall_s.append(wall)
                    row.psnr.append(psnr(image, references[k]))
                    row.ssim.append(ssim(image, references[k]))
        report(recipe, rows, args)
    return 0


def report(recipe: str, rows: dict, args) -> None:
    kubric = rows[KUBRIC]
    table = sorted(rows.values(), key=lambda r: np.mean(r.cpu_s))
    best_psnr = -np.inf
    front = set()
    for r in table:  # cheapest first: on the front when no cheaper setting has a higher PSNR
        if np.mean(r.psnr) > best_psnr:
            front.add(id(r))
            best_psnr = np.mean(r.psnr)
    print(f"\n{recipe}: {args.scenes} scenes, reference {args.reference_samples} spp without "
          f"denoising; mean over scenes; * = Pareto front (PSNR against CPU)")  # fmt: skip
    print(f"{'setting':<40} {'CPU-s/img':>9} {'wall s':>7} {'PSNR dB':>8} {'SSIM':>7} "
          f"{'img/s vs Kubric':>15}")  # fmt: skip
    for r in table:
        mark = "*" if id(r) in front else " "
        kub = "  ← Kubric's default" if r is kubric else ""
        print(
            f"{mark}{r.name():<39} {np.mean(r.cpu_s):9.2f} {np.mean(r.wall_s):7.2f} "
            f"{np.mean(r.psnr):8.2f} {np.mean(r.ssim):7.4f} "
            f"{np.mean(kubric.cpu_s) / np.mean(r.cpu_s):14.2f}×{kub}"
        )
    matched = [r for r in table if np.mean(r.psnr) >= np.mean(kubric.psnr)]
    cheapest = matched[0]
    print(
        f"cheapest setting at Kubric's PSNR ({np.mean(kubric.psnr):.2f} dB) or better: "
        f"{cheapest.name().strip()}, {np.mean(kubric.cpu_s) / np.mean(cheapest.cpu_s):.2f}× "
        "Kubric's images per CPU-second"
    )


if __name__ == "__main__":
    raise SystemExit(main())
