"""The quarter-turn experiment's table (docs/log/2026-12-04-quarter-turns-tape.md): `boxpose eval`
runs of several networks on the same held-out boxes, scored on the boxes whose top face is near-
square (|dx − dy| < 1 cm, the pair that the tape and label of `materials.tape_along = "long"`
tell apart): the share fitted with the right quarter turn (the robust fit's exact MSSD < 0.1 d)
with its 95 % Clopper–Pearson interval, every box's cube MSSD < 0.1 d beside it, and McNemar's
exact test of each run against the first, paired box by box.

python scripts/quarter_turns.py DATASET NAME=EVAL_DIR NAME=EVAL_DIR ...

Reads Parquet with pandas only (boxpose itself is not needed)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pandas as pd

KEYS = ["scene_id", "frame_id", "object_id"]
NEAR_SQUARE_M = 0.01


def binomial_cdf(k: int, n: int, p: float) -> float:
    """P(X ≤ k) for X ~ Binomial(n, p), its terms in log space (comb(n, i) overflows a float
    for the counts of a 20,000-sample run)."""
    if p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 1.0 if k >= n else 0.0
    log_p, log_q = math.log(p), math.log1p(-p)
    log_n = math.lgamma(n + 1)
    return min(
        1.0,
        sum(
            math.exp(
                log_n - math.lgamma(i + 1) - math.lgamma(n - i + 1) + i * log_p + (n - i) * log_q
            )
            for i in range(min(k, n) + 1)
        ),
    )


def _bisect(below, steps: int = 60) -> float:
    """The p in [0, 1] where the monotone predicate `below(p)` turns from True to False."""
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if below(mid) else (lo, mid)
    return (lo + hi) / 2


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The exact interval: P(X ≥ k | low) = P(X ≤ k | high) = (1 − level) / 2."""
    tail = (1 - level) / 2
    low = 0.0 if k == 0 else _bisect(lambda p: 1 - binomial_cdf(k - 1, n, p) < tail)
    high = 1.0 if k == n else _bisect(lambda p: binomial_cdf(k, n, p) > tail)
    return low, high


def mcnemar_exact(fixed: int, new: int) -> float:
    n = fixed + new
    if n == 0:
        return 1.0
    return min(1.0, 2 * binomial_cdf(min(fixed, new), n, 0.5))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("runs", nargs="+", help="NAME=EVAL_DIR, the first the reference")
    parser.add_argument(
        "--within-m",
        type=float,
        default=NEAR_SQUARE_M,
        help="a top is near-square when |dx − dy| is below this (default 0.01 m)",
    )
    args = parser.parse_args()
    objects = pd.concat(
        pd.read_parquet(p, columns=["scene_id", "object_id", "size_m"])
        for p in sorted((args.dataset / "objects").glob("*.parquet"))
    )
    sizes = pd.DataFrame(objects.size_m.tolist(), columns=["dx", "dy", "dz"])
    objects = pd.concat([objects[["scene_id", "object_id"]].reset_index(drop=True), sizes], axis=1)
    results = {}
    for run in args.runs:
        name, folder = run.split("=", 1)
        rows = pd.read_parquet(Path(folder) / "eval.parquet").query("method == 'robust'")
        rows = rows.merge(objects, on=["scene_id", "object_id"])
        rows["right_turn"] = rows.mssd_m < 0.1 * rows.diameter_m
        rows["cube_ok"] = rows.cube_mssd_m < 0.1 * rows.diameter_m
        rows["near_square_top"] = (rows.dx - rows.dy).abs() < args.within_m
        results[name] = rows.set_index(KEYS).sort_index()
    reference_name, reference = next(iter(results.items()))
    print(f"near-square top: |dx - dy| < {1000 * args.within_m:g} mm")
    print(
        f"{'network':<22} {'near-square tops: right quarter turn':<44} "
        f"{'all boxes: cube MSSD < 0.1 d':<34} paired with {reference_name} (near-square)"
    )
    for name, rows in results.items():
        square = rows[rows.near_square_top]
        k, n = int(square.right_turn.sum()), len(square)
        lo, hi = clopper_pearson(k, n)
        kc, nc = int(rows.cube_ok.sum()), len(rows)
        loc, hic = clopper_pearson(kc, nc)
        paired = ""
        if name != reference_name:
            a = reference.loc[square.index].right_turn
            b = square.right_turn
            fixed, new = int((~a & b).sum()), int((a & ~b).sum())
            paired = f"fixed {fixed}, new {new}, McNemar p = {mcnemar_exact(fixed, new):.3g}"
        print(
            f"{name:<22} {100 * k / n:5.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({k}/{n})"
            f"{'':<12} {100 * kc / nc:5.1f} % [{100 * loc:.1f}, {100 * hic:.1f}] ({kc}/{nc})"
            f"{'':<4} {paired}"
        )


if __name__ == "__main__":
    main()
