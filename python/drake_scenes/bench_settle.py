"""python -m drake_scenes.bench_settle: time Drake's drop-and-settle, and save the initial states
so another simulator (the Rust MuJoCo settle) can be timed on exactly the same drops."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

DESCRIPTION = """\
Benchmark Drake's drop-and-settle on freshly sampled scenes with a fixed number of boxes.

For each N in --boxes and each k < --scenes: sample a scene of the recipe with exactly N boxes,
project it to non-penetration, settle it with Drake, and print one JSON line
  {"boxes": N, "scene": k, "scene_id": id, "drake_settle_s": wall seconds, "stable": bool,
   "settle_time_s": simulated seconds[, "reason": why not stable]}
"drake_settle_s" is the wall time of plant construction plus simulation on this machine; it is
null, and "error" says why, when the projection failed (such scenes are not written).

Every projected scene is written to --out as a dataset (scenes/ and objects/ shard 0 of 1):
objects.initial_world_box_* hold the drop poses to settle from, objects.world_box_* Drake's
settled poses, scenes.stable Drake's verdict. Unlike a generated dataset this folder keeps
scenes that did not settle (stable = false): it is benchmark input, not training data.
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m drake_scenes.bench_settle",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python -m drake_scenes.bench_settle "
        "--recipe datasets/recipes/clutter.toml --boxes 5 20 --scenes 3 --out build/bench_settle",
    )
    parser.add_argument(
        "--recipe",
        required=True,
        type=Path,
        help="recipe TOML (support, sizes, [settle] thresholds)",
    )
    parser.add_argument(
        "--boxes", required=True, type=int, nargs="+", metavar="N", help="box counts to benchmark"
    )
    parser.add_argument(
        "--scenes", type=int, default=3, metavar="K", help="scenes per box count (default 3)"
    )
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        help="dataset folder for the initial states (overwritten)",
    )
    args = parser.parse_args(argv)
    if min(args.boxes) < 1 or args.scenes < 1:
        parser.error("--boxes and --scenes must be >= 1")

    import boxpose_io
    from drake_scenes.generate import generate_scene, tool_versions
    from drake_scenes.recipe import Recipe, RecipeError

    try:
        recipe = Recipe.load(args.recipe)
    except RecipeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    versions = tool_versions()
    scene_rows, object_rows = [], []
    scene_id = 0
    for boxes in args.boxes:
        for k in range(args.scenes):
            outcome = generate_scene(recipe, scene_id, versions, num_boxes=boxes)
            line = {"boxes": boxes, "scene": k, "scene_id": scene_id}
            if outcome.scene_row is None:
                line.update(
                    drake_settle_s=None,
                    stable=False,
                    error=f"{outcome.rejection}: {outcome.solver_status}",
                )
            else:
                scene_rows.append(outcome.scene_row)
                object_rows.extend(outcome.object_rows)
                line.update(
                    drake_settle_s=round(outcome.settle_s, 4),
                    stable=outcome.rejection is None,
                    settle_time_s=outcome.scene_row["settle_time_s"],
                )
                if outcome.rejection:
                    line["reason"] = outcome.rejection
            print(json.dumps(line), flush=True)
            scene_id += 1
    for name, rows in (("scenes", scene_rows), ("objects", object_rows)):
        boxpose_io.write_shard(
            boxpose_io.shard_path(args.out, name, 0, 1), boxpose_io.table_from_rows(name, rows)
        )
    print(f"initial states of {len(scene_rows)} scenes written to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
