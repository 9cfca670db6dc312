"""`make bench-search`: CPU-seconds per search sample by stage, in both perception modes, and on
one real pipeline event the samples Monte Carlo and cross-entropy need for 20% relative error,
measured in one run (docs/benchmarks.md, "Search").

Each configuration is one `boxpose search` process with one Cycles thread; its CPU time comes
from the kernel (user + system of the child), the per-stage split from the run's timings table.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import time
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parent.parent


def search(boxpose: Path, out: Path, *args) -> dict:
    if out.exists():
        shutil.rmtree(out)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(
        [str(boxpose), "search", *map(str, args), "--out", str(out), "--threads", "1"],
        check=True,
        cwd=REPO,
        stdout=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    samples = pd.read_parquet(out / "samples.parquet")
    timings = pd.read_parquet(out / "timings.parquet")
    summary = json.loads((out / "summary.json").read_text())
    return {
        "samples": len(samples),
        "cpu_s": cpu,
        "wall_s": wall,
        "timings": timings,
        "summary": summary,
        "rows": samples,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--boxpose", type=Path, default=REPO / "target" / "release" / "boxpose")
    parser.add_argument("--space", default="single_box")
    parser.add_argument(
        "--samples", type=int, default=100, help="samples of the segmenter-crop timing run"
    )
    parser.add_argument(
        "--mc-samples",
        type=int,
        default=1000,
        help="Monte Carlo samples (ground-truth crops): the timing run and the event's reference",
    )
    parser.add_argument(
        "--ce-tune", type=int, default=200, help="cross-entropy samples per tuning iteration"
    )
    parser.add_argument(
        "--ce-final", type=int, default=500, help="cross-entropy samples from the frozen proposal"
    )
    parser.add_argument(
        "--ce-components", type=int, default=3, help="cross-entropy mixture components"
    )
    parser.add_argument(
        "--fail-when", default="paper", help="the real pipeline event (failure predicate)"
    )
    parser.add_argument("--out", type=Path, default=REPO / "build" / "bench_search")
    args = parser.parse_args()

    runs = {}
    configurations = (
        ("gt", args.mc_samples, []),
        ("gt, whole frames", args.samples, ["--whole-frames"]),
        ("predicted", args.samples, []),
    )
    for name, n, extra in configurations:
        crops = name.split(",")[0]
        folder = args.out / ("mc-" + name.replace(", ", "-").replace(" ", "-"))
        runs[name] = search(
            args.boxpose,
            folder,
            args.space,
            "--samples",
            n,
            "--batch-size",
            25,
            "--crops",
            crops,
            "--fail-when",
            args.fail_when,
            *extra,
        )
    print(f"\n## Seconds per sample by stage, {args.space}, one Cycles thread\n")
    print(
        "| crops | samples | settle | render | inference | fit | stages (wall) "
        "| process CPU-s / sample | samples/s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for crops, r in runs.items():
        t = r["timings"]
        stages = t[["settle_s", "render_s", "inference_s", "fit_s"]].mean()
        print(
            f"| {crops} | {r['samples']} | {stages.settle_s:.3f} | {stages.render_s:.3f} "
            f"| {stages.inference_s:.3f} | {stages.fit_s:.3f} | {stages.sum():.3f} "
            f"| {r['cpu_s'] / r['samples']:.3f} | {r['samples'] / r['wall_s']:.2f} |"
        )

    region, whole = (runs[k]["cpu_s"] / runs[k]["samples"] for k in ("gt", "gt, whole frames"))
    print(
        f"\nground-truth crops: region renders {region:.3f} CPU-s per sample, "
        f"whole frames {whole:.3f}: {whole / region:.2f}× faster"
    )

    mc = runs["gt"]["summary"]["estimate"]
    ce_run = search(
        args.boxpose,
        args.out / "ce-gt",
        args.space,
        "--sampler",
        "ce",
        "--samples",
        args.ce_final,
        "--batch-size",
        25,
        "--ce-samples-per-iteration",
        args.ce_tune,
        "--ce-components",
        args.ce_components,
        "--fail-when",
        args.fail_when,
    )
    ce = ce_run["summary"]["estimate"]
    tuning = ce_run["summary"]["tuning_samples"]
    target = 0.2
    print(
        f"\n## Samples for {target:.0%} relative error on a real event "
        f"({args.space}, ground-truth crops, --fail-when {args.fail_when})\n"
    )
    print(
        "| sampler | p̂ | 95% CI | samples in estimate | relative error "
        "| samples for 20% RE (tuning included) |"
    )
    print("|---|---|---|---|---|---|")
    p = mc["p_hat"]
    mc_needed = (1 - p) / (target**2 * p) if p > 0 else float("inf")
    print(
        f"| Monte Carlo | {p:.3e} | {fmt(mc['ci95'])} | {mc['samples']} | {rel(mc)} "
        f"| {mc_needed:.0f} |"
    )
    ce_re = ce.get("relative_error")
    ce_needed = tuning + ce["samples"] * (ce_re / target) ** 2 if ce_re else float("inf")
    print(
        f"| cross-entropy | {ce['p_hat']:.3e} | {fmt(ce['ci95'])} "
        f"| {ce['samples']} (+{tuning} tuning) | {rel(ce)} | {ce_needed:.0f} |"
    )
    if ce_needed > 0 and mc_needed < float("inf"):
        print(f"\nMonte Carlo / cross-entropy samples for 20% RE: {mc_needed / ce_needed:.2f}×")


def fmt(ci) -> str:
    return f"[{ci[0]:.2e}, {ci[1]:.2e}]" if ci else "none"


def rel(e: dict) -> str:
    if e["p_hat"] <= 0:
        return "–"
    re = e.get("relative_error") or (((1 - e["p_hat"]) / (e["p_hat"] * e["valid"])) ** 0.5)
    return f"{re:.3f}"


if __name__ == "__main__":
    main()
