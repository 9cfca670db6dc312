"""`make bench-search`: CPU-seconds per search sample by stage, in both perception modes; on one
real pipeline event the samples each sampler needs for 20% relative error (Monte Carlo,
cross-entropy tilting every parameter, cross-entropy with `--ce-tilt auto`, subset simulation),
as ratios to Monte Carlo measured in the same run; then the same ratios on the analytic failure
sets of known probability (the estimator tests' printouts), in one run (docs/benchmarks.md,
"Search").

Each configuration is one `boxpose search` process with one Cycles thread; its CPU time comes
from the kernel (user + system of the child), the per-stage split from the run's timings table.
Its wall time is the core-seconds the work needs: while the one Cycles thread renders, a second
thread spins on the idle core and yields it when another process wants it (two such processes
side by side each take the same wall time as one alone), so the process CPU counts that spin.
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
    """One `boxpose search` run in `out` (replaced): its samples, timings, summary and CPU time;
    for a run that fails, `{"error": its last stderr line}`."""
    if out.exists():
        shutil.rmtree(out)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    result = subprocess.run(
        [str(boxpose), "search", *map(str, args), "--out", str(out), "--threads", "1"],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    if result.returncode != 0:
        lines = result.stderr.strip().splitlines()
        return {"error": lines[-1] if lines else f"exit status {result.returncode}"}
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
        "--splitting-samples", type=int, default=500, help="subset simulation's particles per stage"
    )
    parser.add_argument(
        "--fail-when", default="paper", help="the real pipeline event (failure predicate)"
    )
    parser.add_argument("--no-analytic", action="store_true", help="skip the analytic failure sets")
    parser.add_argument(
        "--clutter-samples",
        type=int,
        default=30,
        help="samples of each clutter run (segmenter crops, two resolutions and whole frames)",
    )
    parser.add_argument(
        "--clutter-only", action="store_true", help="only the clutter runs, then stop"
    )
    parser.add_argument("--out", type=Path, default=REPO / "build" / "bench_search")
    args = parser.parse_args()

    clutter(args)
    if args.clutter_only:
        return
    runs = {}
    configurations = (
        ("gt", args.mc_samples, []),
        ("gt, whole frames", args.samples, ["--whole-frames"]),
        ("predicted", args.samples, []),
    )
    for name, n, extra in configurations:
        crops = name.split(",")[0]
        folder = args.out / ("mc-" + name.replace(", ", "-").replace(" ", "-"))
        runs[name] = checked(
            search(
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

    common = [args.space, "--batch-size", 25, "--fail-when", args.fail_when]
    ce = ["--sampler", "ce", "--samples", args.ce_final, "--ce-samples-per-iteration", args.ce_tune]
    samplers = {
        "Monte Carlo": runs["gt"],
        "cross-entropy, every parameter tilted": search(
            args.boxpose,
            args.out / "ce-gt",
            *common,
            *ce,
            "--ce-components",
            args.ce_components,
        ),
        "cross-entropy, --ce-tilt auto": search(
            args.boxpose, args.out / "ce-auto-gt", *common, *ce, "--ce-tilt", "auto"
        ),
        "subset simulation": search(
            args.boxpose,
            args.out / "splitting-gt",
            *common,
            "--sampler",
            "splitting",
            "--samples",
            args.splitting_samples,
        ),
    }
    target = 0.2
    print(
        f"\n## Samples for {target:.0%} relative error on a real event "
        f"({args.space}, ground-truth crops, --fail-when {args.fail_when})\n"
    )
    print(
        "| sampler | p̂ | 95% CI | samples spent | relative error "
        "| samples for 20% RE (tuning included) | × fewer than Monte Carlo |"
    )
    print("|---|---|---|---|---|---|---|")
    mc = runs["gt"]["summary"]["estimate"]
    p = mc["p_hat"]
    mc_needed = (1 - p) / (target**2 * p) if p > 0 else float("inf")
    for name, run in samplers.items():
        if "error" in run:
            print(f"| {name} | failed: {run['error']} | | | | | |")
            continue
        summary = run["summary"]
        e = summary["estimate"]
        needed = mc_needed if name == "Monte Carlo" else samples_for(summary, target)
        finite = 0 < needed < float("inf") and mc_needed < float("inf")
        ratio = mc_needed / needed if finite else float("nan")
        print(
            f"| {name} | {e['p_hat']:.3e} | {fmt(e['ci95'])} | {summary['samples_spent']} "
            f"| {rel(e)} | {needed:.0f} | {ratio:.2f} |"
        )
        for warning in summary["warnings"]:
            print(f"|   warning: {warning} | | | | | | |")
    auto = samplers["cross-entropy, --ce-tilt auto"].get("summary", {})
    if "ce_tilt" in auto:
        tilt = auto["ce_tilt"]
        nothing = "nothing" if tilt.get("held_at_nominal") else "every parameter"
        chosen = [t["parameter"] for t in tilt["tests"] if t["tilted"]] or [nothing]
        print(f"\n--ce-tilt auto chose: {', '.join(chosen)}")
    if not args.no_analytic:
        analytic()


def clutter(args) -> None:
    """The `clutter` space with the segmenter's crops (the robust fit): each sample rendered at
    two resolutions (the default) against whole frames at full resolution, the same samples,
    paired by `boxpose search compare`."""
    runs = {}
    for name, extra in (("two resolutions", []), ("whole frames", ["--whole-frames"])):
        runs[name] = checked(
            search(
                args.boxpose,
                args.out / ("clutter-" + name.replace(" ", "-")),
                "clutter",
                "--crops",
                "predicted",
                "--fit",
                "robust",
                "--samples",
                args.clutter_samples,
                "--batch-size",
                10,
                "--seed",
                5,
                *extra,
            )
        )
    print("\n## clutter, segmenter crops, one Cycles thread\n")
    print(
        "| frames | samples | render | inference | fit | wall-s / sample | process CPU-s / sample "
        "| detected | failed (paper) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        t, rows = r["timings"], r["rows"]
        valid = rows[rows.valid]
        print(
            f"| {name} | {r['samples']} | {t.render_s.mean():.3f} | {t.inference_s.mean():.3f} "
            f"| {t.fit_s.mean():.3f} | {r['wall_s'] / r['samples']:.3f} "
            f"| {r['cpu_s'] / r['samples']:.3f} "
            f"| {int((valid.detected == True).sum())}/{len(valid)} "  # noqa: E712
            f"| {int(valid.failed.sum())}/{len(valid)} |"
        )
    two, whole = (runs[k]["wall_s"] / runs[k]["samples"] for k in runs)
    print(
        f"\ntwo-resolution renders: {whole / two:.2f}× fewer seconds per sample than whole frames"
    )
    paired_errors(*(runs[k]["rows"] for k in runs))
    compare = subprocess.run(
        [
            str(args.boxpose),
            "search",
            "compare",
            *(str(args.out / f"clutter-{k}") for k in ("whole-frames", "two-resolutions")),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    print(compare.stdout or compare.stderr)


def paired_errors(two: pd.DataFrame, whole: pd.DataFrame) -> None:
    """The same samples' errors in both runs, where both detected the target: what rendering at
    two resolutions changes beyond Cycles' noise (each render draws its own pixels' noise)."""
    both = two.set_index("sample_id").join(
        whole.set_index("sample_id"), lsuffix="_two", rsuffix="_whole", how="inner"
    )
    both = both[(both.detected_two == True) & (both.detected_whole == True)]  # noqa: E712
    print(f"\nerrors of the {len(both)} samples both detected (two resolutions | whole frames):")
    for column in ("cube_mssd_over_diameter", "rotation_error_deg", "translation_error_m"):
        a, b = both[column + "_two"], both[column + "_whole"]
        gap = (a - b).abs()
        print(
            f"  {column}: median {a.median():.4f} | {b.median():.4f}, "
            f"paired |difference| median {gap.median():.4f}, max {gap.max():.4f}"
        )


def checked(run: dict) -> dict:
    """The timing runs must succeed: the tables below are made of them."""
    if "error" in run:
        raise SystemExit(f"bench-search: a timing run failed: {run['error']}")
    return run


def samples_for(summary: dict, target: float) -> float:
    """Samples a run needs for relative error `target`: its tuning (cross-entropy) charged as
    spent, the estimating stage scaled by (relative error / target)²; subset simulation's whole
    budget scaled so."""
    e = summary["estimate"]
    re = e.get("relative_error")
    if not re:
        return float("inf")
    if summary["sampler"] == "splitting":
        return summary["samples_spent"] * (re / target) ** 2
    return summary["tuning_samples"] + e["samples"] * (re / target) ** 2


def analytic() -> None:
    """The estimator tests on analytic failure sets of known p (no rendering), their printed
    ratios to Monte Carlo at 10% relative error."""
    print("\n## Analytic failure sets (known p; evaluations for 10% RE, ratios to Monte Carlo)\n")
    tests = (
        ("estimators", ["ce_beats_monte_carlo_twentyfold_at_1e3"]),
        ("auto_tilt", []),
        ("splitting", ["splitting_beats_monte_carlo_hundredfold_at_1e6"]),
    )
    for test, names in tests:
        result = subprocess.run(
            ["cargo", "test", "--release", "-q", "-p", "boxpose-search-stats", "--test", test]
            + names
            + ["--", "--nocapture"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        )
        for line in result.stdout.splitlines():
            if "×" in line or "MC" in line:
                print(f"{test}: {line.strip().lstrip('.')}")  # -q prints a dot per test


def fmt(ci) -> str:
    return f"[{ci[0]:.2e}, {ci[1]:.2e}]" if ci else "none"


def rel(e: dict) -> str:
    if e["p_hat"] <= 0:
        return "–"
    re = e.get("relative_error") or (((1 - e["p_hat"]) / (e["p_hat"] * e["valid"])) ** 0.5)
    return f"{re:.3f}"


if __name__ == "__main__":
    main()
