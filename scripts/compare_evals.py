"""Two `boxpose eval` runs on the same held-out frames, paired box by box.

    .venv/bin/python scripts/compare_evals.py BEFORE AFTER [--method robust] [--fraction 0.1]

Each folder is an `eval --out` folder (its `eval.parquet`). A box succeeds when the method's
cube-group corner MSSD is below `fraction` × its diameter; a box the segmenter did not find (no
error) fails. Pairs are (scene_id, frame_id, object_id) present in both; prints the success rates,
the boxes fixed and newly failing, and McNemar's exact two-sided p (the binomial test on the
discordant pairs, as `boxpose search compare` does for search samples).
"""

from __future__ import annotations

import argparse
import sys
from math import comb
from pathlib import Path

import pandas as pd


def successes(folder: Path, method: str, fraction: float) -> pd.Series:
    path = folder / "eval.parquet"
    if not path.is_file():
        sys.exit(f"{path}: no eval.parquet (give the --out folder of a `boxpose eval` run)")
    e = pd.read_parquet(path)
    e = e[e.method == method]
    if e.empty:
        sys.exit(f"{path}: no rows of method {method!r} (it has {sorted(set(e.method))})")
    e = e.set_index(["scene_id", "frame_id", "object_id"])
    return (e.cube_mssd_m < fraction * e.diameter_m).fillna(False).astype(bool)


def mcnemar_exact(fixed: int, new: int) -> float:
    n = fixed + new
    if n == 0:
        return 1.0
    tail = sum(comb(n, k) for k in range(min(fixed, new) + 1)) / 2**n
    return min(1.0, 2 * tail)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--method", default="robust", help="the fit compared (default: robust)")
    ap.add_argument("--fraction", type=float, default=0.1, help="of the diameter (default 0.1)")
    args = ap.parse_args(argv)
    before = successes(args.before, args.method, args.fraction)
    after = successes(args.after, args.method, args.fraction)
    both = before.index.intersection(after.index)
    if both.empty:
        sys.exit("the two runs share no box: were they run on the same dataset and --held-out?")
    b, a = before[both], after[both]
    fixed, new = int((~b & a).sum()), int((b & ~a).sum())
    print(
        f"{len(both)} boxes paired: {b.mean():.1%} -> {a.mean():.1%} "
        f"(cube MSSD < {args.fraction} d, {args.method}); fixed {fixed}, new {new}, "
        f"McNemar p = {mcnemar_exact(fixed, new):.2g}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
