#!/usr/bin/env python
"""What each Cycles setting costs the networks (`make bench-render-accuracy`): the same fresh
scenes rendered at several samples-and-denoising settings, each through `make scenes`, then
`boxpose eval` with the shipped keypoint network on ground-truth crops and on the segmenter's.

    python scripts/bench_render_accuracy.py [--recipe train] [--scenes 8] [--views 1]
        [--settings 1:none,1,2,4,16,64] [--model models/keypoint-slim]

A setting is SAMPLES (with OpenImageDenoise) or SAMPLES:none. The scenes are Drake's, once, for
the recipe with another seed (scenes the networks never saw) and --views views per scene; each
setting renders them with only `[render] samples` and `denoise` changed. The last setting is the
reference: every other row counts the boxes whose outcome (robust fit within 0.1 d) differs from
it, paired box by box, so that a loss is told from the noise of a small set.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

import boxpose_io

REPO = Path(__file__).resolve().parent.parent
FRESH_SEED_OFFSET = 1000  # scenes of the recipe's distribution that no training set holds


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def set_key(text: str, key: str, value: str) -> str:
    """The recipe text with a top-level-in-its-section `key = …` line's value replaced."""
    new, count = re.subn(rf"(?m)^{key} = [^#\n]*", f"{key} = {value}", text, count=1)
    if count != 1:
        raise SystemExit(f"the recipe has no `{key} = …` line to set")
    return new


def run(cmd: list[str]) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout[-1500:]}{r.stderr[-2000:]}")


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    ap.add_argument("--recipe", default="train", help="recipe name (default train)")
    ap.add_argument("--scenes", type=int, default=8)
    ap.add_argument("--views", type=int, default=1, help="frames per scene (default 1)")
    ap.add_argument("--settings", default="1:none,1,2,4,16,64")
    ap.add_argument("--model", default="models/keypoint-slim")
    ap.add_argument("--segmenter", default="models/segmenter-slim")
    ap.add_argument("--boxpose", default=str(REPO / "target" / "release" / "boxpose"))
    ap.add_argument("--keep", type=Path, help="keep the datasets and evaluations in this folder")
    args = ap.parse_args()

    text = (REPO / "datasets" / "recipes" / f"{args.recipe}.toml").read_text()
    seed = int(re.search(r"(?m)^seed = (\d+)", text)[1]) + FRESH_SEED_OFFSET
    text = set_key(set_key(text, "seed", str(seed)), "frames_per_scene", str(args.views))
    settings = []
    for item in args.settings.split(","):
        samples, _, denoiser = item.partition(":")
        settings.append((int(samples), denoiser != "none"))
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"load average at start: {load}; recipe {args.recipe} at seed {seed}, "
          f"{args.scenes} scenes × {args.views} views")  # fmt: skip

    work = Path(tempfile.mkdtemp(prefix="bench-accuracy-")) if args.keep is None else args.keep
    work.mkdir(parents=True, exist_ok=True)
    scenes_dir = work / "scenes"
    (work / "recipe.toml").write_text(text)
    run([sys.executable, "-m", "drake_scenes", "--recipe", str(work / "recipe.toml"),
         "--out", str(scenes_dir), "--num-scenes", str(args.scenes), "--no-progress"])  # fmt: skip

    outcomes, rows = {}, []
    for samples, denoise in settings:
        name = f"{samples} spp{' + OIDN' if denoise else ''}"
        tag = f"s{samples}{'d' if denoise else ''}"
        recipe = set_key(set_key(text, "samples", str(samples)), "denoise", str(denoise).lower())
        (work / f"{tag}.toml").write_text(recipe)
        dataset = work / tag
        if not (dataset / "frames").is_dir():
            shutil.rmtree(dataset, ignore_errors=True)
            for table in ("scenes", "objects"):  # Drake's rows, with this setting's recipe text
                rows_ = pq.read_table(scenes_dir / table)
                if table == "scenes":
                    column = rows_.schema.get_field_index("recipe_toml")
                    rows_ = rows_.set_column(
                        column, "recipe_toml", pa.array([recipe] * rows_.num_rows, pa.string())
                    )
                rows_ = rows_.cast(boxpose_io.arrow_schema(table))
                boxpose_io.write_shard(boxpose_io.shard_path(dataset, table, 0, 1), rows_)
            cpu = children_cpu_s()
            run([sys.executable, str(REPO / "scripts" / "make_scenes.py"), "--recipe",
                 str(work / f"{tag}.toml"), "--dataset", str(dataset),
                 "--num-scenes", str(args.scenes), "--no-inspect"])  # fmt: skip
            (dataset / "cpu_s.txt").write_text(f"{children_cpu_s() - cpu}\n")
        cpu_s = float((dataset / "cpu_s.txt").read_text())
        frames = pq.read_table(dataset / "frames", columns=["scene_id"]).num_rows
        summary = {}
        for crops in ("gt", "predicted"):
            out = work / f"eval-{tag}-{crops}"
            run([args.boxpose, "eval", str(dataset), "--model", args.model, "--crops", crops,
                 "--segmenter", args.segmenter, "--out", str(out)])  # fmt: skip
            summary[crops] = json.loads((out / "summary.json").read_text())
            if crops == "gt":
                fits = pd.read_parquet(out / "eval.parquet")
                fits = fits[fits.method == "robust"].set_index(
                    ["scene_id", "frame_id", "object_id"]
                )
                outcomes[name] = (fits.mssd_m < 0.1 * fits.diameter_m).sort_index()
                median = float((fits.mssd_m / fits.diameter_m).median())
        rows.append((name, cpu_s / frames, summary, median))

    reference = rows[-1][0]
    print(f"\n{outcomes[reference].size} boxes at least 25 % visible; paired against {reference}")
    print(
        "| setting | CPU-s / image (make scenes) | corner recall | robust fit < 0.05 d / < 0.1 d "
        "| median MSSD / d | outcome differs from the reference | segmenter's crops < 0.1 d |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, cpu_per_image, summary, median in rows:
        gt, predicted = summary["gt"], summary["predicted"]
        ours, theirs = outcomes[name].align(outcomes[reference], join="inner")
        better, worse = int((ours & ~theirs).sum()), int((~ours & theirs).sum())
        print(
            f"| {name} | {cpu_per_image:.1f} | {gt['corner_recall']:.1%} | "
            f"{gt['robust_mssd_recall_005']:.1%} / {gt['robust_mssd_recall_010']:.1%} | "
            f"{median:.4f} | {'—' if name == reference else f'+{better} / −{worse}'} | "
            f"{predicted['robust_mssd_recall_010']:.1%} |"
        )
    print(f"\ndatasets and evaluations: {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
