#!/usr/bin/env python
"""`make scenes` throughput: images per second of the whole driver (Drake scenes, Blender
renders, ground truth, Parquet) per recipe, for each setting of --jobs, in one run; or, with
--variants, box instances per CPU-second of each recipe as shipped and changed by some keys.

    python scripts/bench_scenes.py [--recipes clutter,train_large,single_box] [--scenes 8]
                                   [--shards 4] [--jobs 1,2] [--reference-driver PATH]
    python scripts/bench_scenes.py --recipes train_large --variants \
        'settle.engine="mujoco"' 'settle.engine="mujoco",camera.width=320,camera.height=256'

--variants: each is a comma-separated list of recipe keys and TOML values that replace (or add)
the recipe's; the recipe as shipped is the reference row, run first. A box instance counts when
at least a quarter of the box is visible in its frame (the networks' training threshold) and the
whole box lies inside the frame.

Each recipe's first --scenes scenes (its own seed, so every setting renders the same scenes) in
--shards shards, into a fresh folder per setting. --reference-driver runs another version of
the driver (e.g. `git show REV:scripts/make_scenes.py > /tmp/make_scenes_rev.py`) first, with
its own defaults, as the row the others are compared with; otherwise the first --jobs setting
is the reference. Wall time is what a user waits for; CPU seconds (every process the driver
started) are printed beside it, since other jobs on the machine inflate wall times.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

REPO = Path(__file__).resolve().parent.parent
DRIVER = REPO / "scripts" / "make_scenes.py"


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


MIN_VISIBLE_FRACTION = 0.25


def with_keys(text: str, variant: str) -> str:
    """Recipe TOML `text` with the keys of `variant` ("section.key=value,…") set: a key's line
    is replaced in its section, or added at the section's top when the recipe does not set it."""
    lines = text.splitlines()
    # commas inside a list value ("boxes.count=[3, 20]") do not separate keys
    for assignment in filter(None, re.split(r",(?![^\[]*\])", variant)):
        dotted, value = (part.strip() for part in assignment.split("=", 1))
        section, key = dotted.split(".")
        start = lines.index(f"[{section}]")
        end = next(
            (i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines)
        )
        found = [i for i in range(start + 1, end) if lines[i].split("=")[0].strip() == key]
        if found:
            lines[found[0]] = f"{key} = {value}"
        else:
            lines.insert(start + 1, f"{key} = {value}")
    return "\n".join(lines) + "\n"


def generate(driver: Path, recipe_path: Path, dataset: Path, args, extra: list[str]) -> dict:
    cmd = [
        sys.executable, str(driver), "--recipe", str(recipe_path), "--dataset", str(dataset),
        "--num-scenes", str(args.scenes), "--num-shards", str(args.shards), "--no-inspect", *extra,
    ]  # fmt: skip
    wall, cpu = time.perf_counter(), children_cpu_s()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - wall, children_cpu_s() - cpu
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    frames = pq.read_table(dataset / "frames", columns=["scene_id"]).num_rows
    return {"frames": frames, "instances": whole_instances(dataset), "wall_s": wall, "cpu_s": cpu}


def whole_instances(dataset: Path) -> int:
    """Box instances a keypoint crop can be taken of: at least MIN_VISIBLE_FRACTION visible, and
    the whole box inside its frame (every projected corner in the image). A box cut by the edge
    of a frame counts in no variant: a region frame cuts its neighbours, a whole frame rarely."""
    sizes = {
        (f["scene_id"], f["frame_id"]): (f["width"], f["height"])
        for f in pq.read_table(
            dataset / "frames", columns=["scene_id", "frame_id", "width", "height"]
        ).to_pylist()
    }
    rows = pq.read_table(
        dataset / "instances", columns=["scene_id", "frame_id", "visible_fraction", "corners_px"]
    ).to_pylist()
    count = 0
    for row in rows:
        width, height = sizes[(row["scene_id"], row["frame_id"])]
        u, v = row["corners_px"][0::2], row["corners_px"][1::2]
        inside = min(u) >= -0.5 and min(v) >= -0.5 and max(u) <= width - 0.5
        count += (
            row["visible_fraction"] >= MIN_VISIBLE_FRACTION and inside and max(v) <= height - 0.5
        )
    return count


def bench_variants(args) -> None:
    """One row per recipe and variant: instances per CPU-second against the recipe as shipped."""
    print(
        "| recipe | variant | frames | whole instances ≥ 25 % visible | wall s | CPU s "
        "| instances per CPU-s | vs shipped |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory(prefix="bench-scenes-") as tmp:
        for recipe in args.recipes.split(","):
            shipped = (REPO / "datasets" / "recipes" / f"{recipe}.toml").read_text()
            reference = None
            for n, variant in enumerate(["", *args.variants]):
                path = Path(tmp) / f"{recipe}-{n}" / f"{recipe}.toml"
                path.parent.mkdir()
                path.write_text(with_keys(shipped, variant))
                result = generate(DRIVER, path, Path(tmp) / f"{recipe}-{n}" / "data", args, [])
                rate = result["instances"] / result["cpu_s"]
                reference = reference or rate
                print(
                    f"| {recipe} | {variant or 'as shipped'} | {result['frames']} | "
                    f"{result['instances']} | {result['wall_s']:.0f} | {result['cpu_s']:.0f} | "
                    f"{rate:.3f} | {rate / reference:.2f}× |",
                    flush=True,
                )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    ap.add_argument("--recipes", default="clutter,train_large,single_box")
    ap.add_argument("--scenes", type=int, default=8, help="scenes per recipe (default 8)")
    ap.add_argument("--shards", type=int, default=4, help="shards per dataset (default 4)")
    ap.add_argument("--jobs", default="1,2", help="--jobs settings to compare (default 1,2)")
    ap.add_argument("--reference-driver", type=Path, help="another make_scenes.py, run first")
    ap.add_argument(
        "--variants",
        nargs="+",
        metavar="KEYS",
        help="recipe variants, e.g. 'settle.engine=\"mujoco\",camera.width=320'; "
        "instances per CPU-second against the recipe as shipped (--jobs 1)",
    )
    args = ap.parse_args()
    print(
        f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())} "
        f"on {os.cpu_count()} cores; {args.scenes} scenes in {args.shards} shards per recipe"
    )
    if args.variants:
        bench_variants(args)
        return 0

    settings = [(f"--jobs {j}", DRIVER, ["--jobs", j]) for j in args.jobs.split(",")]
    if args.reference_driver:
        settings.insert(0, (f"{args.reference_driver.name}", args.reference_driver, []))
    print("| recipe | driver | frames | wall s | CPU s | images/s | vs reference |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory(prefix="bench-scenes-") as tmp:
        for recipe in args.recipes.split(","):
            reference = None
            for n, (name, driver, extra) in enumerate(settings):
                recipe_path = REPO / "datasets" / "recipes" / f"{recipe}.toml"
                result = generate(driver, recipe_path, Path(tmp) / f"{recipe}-{n}", args, extra)
                rate = result["frames"] / result["wall_s"]
                reference = reference or rate
                print(
                    f"| {recipe} | {name} | {result['frames']} | {result['wall_s']:.0f} | "
                    f"{result['cpu_s']:.0f} | {rate:.3f} | {rate / reference:.2f}× |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
