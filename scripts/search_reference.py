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

    python scripts/search_reference.py pool REFERENCE/errors.csv.gz OTHER/errors.csv.gz ...
        Monte Carlo runs of the same event with other seeds (independent samples, checked), under
        each predicate: each run's failures with their 95 % Clopper–Pearson interval, the runs
        pooled, and for two runs whether they agree (the exact conditional test of two rates:
        given k₁ + k₂ failures, k₁ ~ Binomial(k₁ + k₂, n₁ / (n₁ + n₂)) when the rates are equal).

    python scripts/search_reference.py against REFERENCE/errors.csv.gz [--pool OTHER/errors.csv.gz]
            RUN [RUN ...]
        checks finished runs of any sampler against a Monte Carlo reference of the same event
        (space, recipe, crops, networks, fit; the predicate is each run's own, applied to the
        reference's errors; `--pool` adds more Monte Carlo runs of the event, as `pool` does):
        each run's estimate, whether its 95 % interval covers the reference's p̂, and the samples
        Monte Carlo would need for the run's own precision, as a ratio ("× fewer": (δ_MC / δ)²,
        δ_MC = √((1 − p)/(n p)) at the run's budget n with the reference's p); then the runs'
        spread and the ratio it implies; and for subset simulation, level by level, the run's
        running product of conditional shares against the reference's share of samples scoring
        above the same level (the score is log10(metric / threshold), +∞ with nothing fitted):
        where a run parts from Monte Carlo, not only whether it does.

Reads Parquet with pandas only (boxpose itself is not needed)."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
from quarter_turns import binomial_cdf, clopper_pearson, mcnemar_exact

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


def scores(errors: pd.DataFrame, column: str, threshold: float) -> pd.Series:
    """The search's continuous score, log10(metric / threshold): a sample fails exactly when it
    is > 0, and is +∞ when nothing was fitted (`boxpose search`'s `FailurePredicate::score`)."""
    return np.log10(errors[column] / threshold).fillna(np.inf)


def fails(errors: pd.DataFrame, column: str, threshold: float) -> pd.Series:
    return scores(errors, column, threshold) > 0


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


# run.json's predicate metric → the errors column it judges
PREDICATE_COLUMNS = {
    "paper_error": "paper_error_normalized",
    "cube_mssd": "cube_mssd_over_diameter",
    "mssd": "mssd_over_diameter",
}
# what must agree between a run and the reference for them to estimate the same event
EVENT_SETTINGS = ["crops", "fit", "model", "segmenter", "refine_depth", "sensor_depth"]


def event_of(run_json: dict) -> dict:
    settings = run_json["settings"]
    event = {key: settings.get(key, False) for key in EVENT_SETTINGS}
    event.update(space=run_json["space_toml"], recipe=run_json["recipe_toml"])
    return event


def monte_carlo_delta(p: float, samples: float) -> float:
    """Monte Carlo's coefficient of variation with `samples` draws at probability p."""
    return ((1 - p) / (samples * p)) ** 0.5


def load_references(paths: list[Path]) -> tuple[dict, list[pd.DataFrame]]:
    """The first reference's run.json and every reference's valid samples: Monte Carlo runs of
    one event with distinct seeds, so that their samples are independent and may be pooled."""
    first, frames, seeds = None, [], set()
    for path in paths:
        record = json.loads((path.parent / "run.json").read_text())
        settings = record["settings"]
        if settings["sampler"] != "mc":
            raise SystemExit(f"{path}: a reference is a Monte Carlo run, not {settings['sampler']}")
        if first is None:
            first = record
        differ = [k for k, v in event_of(record).items() if v != event_of(first)[k]]
        if differ:
            differ_text = ", ".join(differ)
            raise SystemExit(f"{path}: not the first reference's event ({differ_text} differ)")
        if settings["seed"] in seeds:
            raise SystemExit(
                f"{path}: seed {settings['seed']} again: the same samples, not independent ones"
            )
        seeds.add(settings["seed"])
        errors = pd.read_csv(path)
        if "valid" in errors:
            errors = errors[errors.valid.astype(bool)]
        frames.append(errors)
    return first, frames


def rates_agree(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided p of the exact conditional test that two runs fail at one rate: given the
    k1 + k2 failures, k1 ~ Binomial(k1 + k2, n1 / (n1 + n2)) (exact for Poisson counts; for rare
    events the binomial counts of Monte Carlo are those)."""
    k, share = k1 + k2, n1 / (n1 + n2)
    if k == 0:
        return 1.0
    lower = binomial_cdf(k1, k, share)
    upper = 1.0 - binomial_cdf(k1 - 1, k, share) if k1 > 0 else 1.0
    return min(1.0, 2 * min(lower, upper))


def pool(references: list[Path]) -> None:
    _, frames = load_references(references)
    sizes = [len(f) for f in frames]
    head = " | ".join(path.parent.name for path in references)
    print(f"| predicate | {head} | pooled, {sum(sizes):,} samples | the runs agree (p) |")
    print("| --- " * (len(frames) + 3) + "|")
    for name, column, threshold in PREDICATES:
        counts = [int(fails(f, column, threshold).sum()) for f in frames]
        cells = []
        for k, n in [*zip(counts, sizes, strict=True), (sum(counts), sum(sizes))]:
            low, high = clopper_pearson(k, n)
            cells.append(f"{k}: {k / n:.2e} [{low:.2e}, {high:.2e}]")
        agree = "—"
        if len(frames) == 2:
            agree = f"{rates_agree(counts[0], sizes[0], counts[1], sizes[1]):.2g}"
        print(f"| {name} | {' | '.join(cells)} | {agree} |")


def against(references: list[Path], runs: list[Path]) -> None:
    reference, frames = load_references(references)
    errors = pd.concat(frames, ignore_index=True)
    reference_dir = " + ".join(str(path.parent) for path in references)
    rows, level_rows, estimates, budgets = [], [], [], []
    p_reference, first_predicate = None, None
    for run in runs:
        record = json.loads((run / "run.json").read_text())
        summary = json.loads((run / "summary.json").read_text())
        differ = [k for k, v in event_of(record).items() if v != event_of(reference)[k]]
        if differ:
            raise SystemExit(f"{run}: not the reference's event ({', '.join(differ)} differ)")
        settings = record["settings"]
        predicate = settings["predicate"]
        threshold = predicate.get("threshold", predicate.get("fraction"))
        failing = int(fails(errors, PREDICATE_COLUMNS[predicate["metric"]], threshold).sum())
        if first_predicate is None:
            first_predicate = predicate
            p_reference, event_name = failing / len(errors), f"{predicate['metric']} > {threshold}"
            low, high = clopper_pearson(failing, len(errors))
            print(
                f"reference {reference_dir}: {event_name}: {failing} of {len(errors)}, "
                f"p̂ {p_reference:.2e} [{low:.2e}, {high:.2e}]"
            )
            if failing == 0:
                raise SystemExit("the reference never fails under this predicate: no ratio to give")
        elif predicate != first_predicate:
            raise SystemExit(f"{run}: another predicate than the first run's")
        estimate = summary["estimate"]
        p_hat, (lo, hi) = estimate["p_hat"], estimate["ci95"] or (float("nan"),) * 2
        delta, spent = estimate["relative_error"], summary["samples_spent"]
        delta_mc = monte_carlo_delta(p_reference, spent)
        splitting = summary.get("splitting") or {}
        # subset simulation's chance of a move keeping its chain's scene seed (0 before it existed)
        kept = (settings.get("splitting") or {}).get("keep_scene_seed", 0) if splitting else ""
        lineages = splitting.get("distinct_ancestors", "")
        stages = len(splitting.get("levels", [])) or ""
        score = scores(errors, PREDICATE_COLUMNS[predicate["metric"]], threshold)
        running = 1.0 / estimate.get("p_valid", 1.0)  # splitting's p̂ is of P(fail | valid)
        for number, level in enumerate(splitting.get("levels", [])):
            running *= level["conditional_probability"]
            above = int((score > level["threshold"]).sum())
            low, high = clopper_pearson(above, len(errors))
            share = above / len(errors)
            ratio_text = f"{running / share:.2f}" if above else "—"
            level_rows.append(
                f"| {run.name} | {number} | {level['threshold']:.3f} | {running:.2e} "
                f"| {above} | {share:.2e} [{low:.2e}, {high:.2e}] | {ratio_text} |"
            )
        covers = "yes" if lo <= p_reference <= hi else "**no**"
        # no failure, no relative error: the run says nothing to compare precisions by
        delta_text, ratio = ("—", "—")
        if delta:
            delta_text, ratio = f"{delta:.2f}", f"{(delta_mc / delta) ** 2:.1f}×"
        rows.append(
            f"| {settings['sampler']} | {kept} | {settings['seed']} | {spent:,} | {stages} "
            f"| {p_hat:.2e} [{lo:.2e}, {hi:.2e}] | {covers} | {delta_text} | {lineages} "
            f"| {delta_mc:.2f} | {ratio} |"
        )
        estimates.append(p_hat)
        budgets.append(spent)
    print(
        "| sampler | scene seed kept | seed | evaluations | stages | p̂ [95 % CI] "
        "| covers the reference | δ | lineages | Monte Carlo's δ at that budget | × fewer than MC |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))
    if len(estimates) > 1:
        series = pd.Series(estimates)
        spread = series.std() / p_reference
        budget = sum(budgets) / len(budgets)
        delta_mc = monte_carlo_delta(p_reference, budget)
        print(
            f"{len(estimates)} runs: mean p̂ {series.mean():.2e}, spread (std / reference p̂) "
            f"{spread:.2f} at a mean {budget:,.0f} evaluations, where Monte Carlo's δ is "
            f"{delta_mc:.2f}: {(delta_mc / spread) ** 2:.1f}× fewer by the spread"
        )
    if level_rows:
        print(
            "\nsubset simulation level by level: the run's p̂ of scoring above each level (the "
            "running product) against the reference's share"
        )
        print(
            "| run | stage | level | run's p̂ above it | reference samples above it "
            "| reference share [95 % CI] | run / reference |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- |")
        print("\n".join(level_rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    keep_parser = commands.add_parser("keep", help="a run's summaries into a folder")
    keep_parser.add_argument("run", type=Path)
    keep_parser.add_argument("out", type=Path)
    pair_parser = commands.add_parser("pair", help="two runs' errors.csv.gz paired")
    pair_parser.add_argument("before", type=Path)
    pair_parser.add_argument("after", type=Path)
    against_parser = commands.add_parser(
        "against", help="runs of any sampler checked against a Monte Carlo reference"
    )
    against_parser.add_argument("reference", type=Path, help="the reference's errors.csv.gz")
    against_parser.add_argument(
        "--pool",
        type=Path,
        action="append",
        default=[],
        help="another Monte Carlo run of the event (another seed), pooled with the reference",
    )
    against_parser.add_argument("runs", type=Path, nargs="+")
    pool_parser = commands.add_parser(
        "pool", help="Monte Carlo runs of one event with other seeds, side by side and pooled"
    )
    pool_parser.add_argument("references", type=Path, nargs="+", help="each run's errors.csv.gz")
    args = parser.parse_args()
    if args.command == "keep":
        keep(args.run, args.out)
    elif args.command == "pair":
        pair(args.before, args.after)
    elif args.command == "pool":
        pool(args.references)
    else:
        against([args.reference, *args.pool], args.runs)


if __name__ == "__main__":
    main()
