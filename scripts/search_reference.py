"""A search run's summaries as the repository keeps them, and two such runs paired sample by sample.

    python scripts/search_reference.py keep RUN OUT
        writes OUT/run.json, summary.json, errors.csv.gz (every sample's errors), failures.json
        (the failing samples with their parameters) and error_hist.png: what
        docs/reference/single_box-gt-20000/ holds, without the images of the run.

    python scripts/search_reference.py pair BEFORE/errors.csv.gz AFTER/errors.csv.gz
        pairs two runs of the same inputs (same space and seed: equal sample ids and seeds, checked)
        and prints, under each predicate, the failures of each with their 95 % Clopper–Pearson
        interval, the discordant pairs and McNemar's exact test; and the median, 99th percentile
        and largest paper error, rotation and translation error of each.

Reads Parquet with pandas only (boxpose itself is not needed)."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import pandas as pd
from quarter_turns import clopper_pearson, mcnemar_exact

COLUMNS = [
    "sample_id",
    "seed",
    "valid",
    "paper_error_normalized",
    "cube_mssd_over_diameter",
    "mssd_over_diameter",
    "add_s_m",
    "rotation_error_deg",
    "translation_error_m",
    "fit_confidence",
    "failed",
]
# (name, column, threshold): a sample fails when the column is above the threshold or missing
# (nothing fitted), as `boxpose search --fail-when` counts it
PREDICATES = [
    ("the paper's (normalised error > 0.005)", "paper_error_normalized", 0.005),
    ("cube MSSD > 0.1 d", "cube_mssd_over_diameter", 0.1),
    ("cube MSSD > 0.05 d", "cube_mssd_over_diameter", 0.05),
    ("exact MSSD > 0.1 d", "mssd_over_diameter", 0.1),
]


def keep(run: Path, out: Path) -> None:
    samples = pd.read_parquet(run / "samples.parquet")
    out.mkdir(parents=True, exist_ok=True)
    for name in ["run.json", "summary.json"]:
        shutil.copyfile(run / name, out / name)
    shutil.copyfile(run / "report" / "error_hist.png", out / "error_hist.png")
    samples[COLUMNS].to_csv(out / "errors.csv.gz", index=False, float_format="%.6g")
    failing = samples[samples.failed]
    records = failing[COLUMNS].to_dict(orient="records")
    for record, params in zip(records, failing.params, strict=True):
        record["params"] = [float(p) for p in params]
    (out / "failures.json").write_text(json.dumps(records, indent=1) + "\n")
    print(f"{len(samples)} samples, {len(failing)} failing → {out}")


def fails(errors: pd.DataFrame, column: str, threshold: float) -> pd.Series:
    return errors[column].isna() | (errors[column] > threshold)


def pair(before_path: Path, after_path: Path) -> None:
    before = pd.read_csv(before_path).set_index("sample_id")
    after = pd.read_csv(after_path).set_index("sample_id")
    common = before.index.intersection(after.index)
    if len(common) == 0:
        raise SystemExit("the two runs share no sample id")
    before, after = before.loc[common], after.loc[common]
    if not (before.seed == after.seed).all():
        raise SystemExit("the runs drew other inputs for the same sample ids: not a pairing")
    # a sample either run could not score (not settled, not visible) is no pair (files kept
    # before the column existed hold valid samples only)
    valid = pd.Series(True, index=common)
    for errors in (before, after):
        if "valid" in errors:
            valid &= errors.valid.astype(bool)
    before, after = before[valid], after[valid]
    common = before.index
    n = len(common)
    print(f"{n} paired samples (ids {common.min()}–{common.max()}, both valid)")
    for name, column, threshold in PREDICATES:
        a, b = fails(before, column, threshold), fails(after, column, threshold)
        fixed, new = int((a & ~b).sum()), int((~a & b).sum())
        cells = []
        for label, failed in [("before", a), ("after", b)]:
            k = int(failed.sum())
            low, high = clopper_pearson(k, n)
            cells.append(f"{label} {k} ({k / n:.2e} [{low:.2e}, {high:.2e}])")
        p = mcnemar_exact(fixed, new)
        print(f"  {name}: {', '.join(cells)}; fixed {fixed}, new {new}, McNemar p = {p:.2g}")
    for column in ["paper_error_normalized", "rotation_error_deg", "translation_error_m"]:
        quantiles = [
            f"{label} " + " / ".join(f"{errors[column].quantile(q):.3g}" for q in (0.5, 0.99, 1.0))
            for label, errors in [("before", before), ("after", after)]
        ]
        print(f"  {column} median / 99 % / max: {'; '.join(quantiles)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    keep_parser = commands.add_parser("keep", help="a run's summaries into a folder")
    keep_parser.add_argument("run", type=Path)
    keep_parser.add_argument("out", type=Path)
    pair_parser = commands.add_parser("pair", help="two runs' errors.csv.gz paired")
    pair_parser.add_argument("before", type=Path)
    pair_parser.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.command == "keep":
        keep(args.run, args.out)
    else:
        pair(args.before, args.after)


if __name__ == "__main__":
    main()
