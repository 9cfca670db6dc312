"""python -m drake_scenes: generate the `scenes` and `objects` tables of a dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DESCRIPTION = """\
Generate physically stable box scenes with Drake and write them as the `scenes` and `objects`
tables of a boxpose dataset (Parquet shards, see docs/dataset.md).

For each scene: sample boxes (count, anisotropic size, mass, friction, cardboard material) and
random drop poses over the support; project the poses to non-penetration with a nonlinear
program (SNOPT, IPOPT fallback, jittered retries); drop and simulate until every box is at rest
over the recipe's window; certify (speeds, penetration, boxes still on the support). Scenes that
fail a check are counted by reason and not written. The drop is simulated by Drake, or, for a
recipe with `[settle] engine = "mujoco"`, by MuJoCo (`boxpose settle-drops`, ≈ 50× less CPU,
the same rules); `scenes.physics_backend` records which.

Sharding: scene ids 0..num_scenes-1; shard i takes the ids with id % N == i. A scene's seed
depends only on the recipe seed and its id, so the rows never depend on N. Shards are written
as <out>/{scenes,objects}/part-iiiii-of-NNNNN.parquet, atomically; a shard whose two files both
exist is skipped (resume).
"""

EPILOG = """\
examples:
  python -m drake_scenes --recipe datasets/recipes/tiny.toml --out datasets/generated/tiny
  python -m drake_scenes --recipe datasets/recipes/clutter.toml --out datasets/generated/clutter --shard 1 --num-shards 4

exit status: 0 on success (or shard already present), 2 for a bad or impossible recipe.
"""  # noqa: E501  (printed verbatim by --help: the example stays one copyable line)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m drake_scenes",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--recipe", required=True, type=Path, help="recipe TOML, e.g. datasets/recipes/tiny.toml"
    )
    parser.add_argument(
        "--out", required=True, type=Path, help="dataset folder (created if missing)"
    )
    parser.add_argument(
        "--shard", type=int, default=0, help="index of this shard, 0 <= i < N (default 0)"
    )
    parser.add_argument(
        "--num-shards", type=int, default=1, metavar="N", help="number of shards (default 1)"
    )
    parser.add_argument(
        "--num-scenes", type=int, metavar="K", help="override the recipe's num_scenes"
    )
    parser.add_argument(
        "--boxpose",
        type=Path,
        metavar="PATH",
        help='the boxpose binary that settles the drops of a recipe with settle.engine = "mujoco" '
        "(default: target/release/boxpose, then PATH)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.num_shards < 1 or not 0 <= args.shard < args.num_shards:
        parser.error(
            f"need 0 <= --shard < --num-shards, got shard {args.shard} of {args.num_shards}"
        )
    if args.num_scenes is not None and args.num_scenes < 0:
        parser.error("--num-scenes must be >= 0")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # Imported after parsing so that --help is instant and needs neither Drake nor the schema.
    from drake_scenes.generate import run_shard
    from drake_scenes.recipe import Recipe, RecipeError

    try:
        recipe = Recipe.load(args.recipe)
        summary = run_shard(
            recipe,
            args.out,
            args.shard,
            args.num_shards,
            args.num_scenes,
            progress=not args.no_progress,
            boxpose=args.boxpose,
        )
    except RecipeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(summary.report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
