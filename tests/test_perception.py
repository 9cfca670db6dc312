"""`boxpose predict`, `boxpose eval` and `boxpose search replay` perceive a box through one
library function (`inference::perceive`: crop → heatmap → peaks → fit → mirror check with the
depth image), so they report the same pose for the same crop. A search run with the size-and-pose
fit, where every sample fails so that its frames are kept as a dataset (counterexamples/), gives
the crop: predict and eval run on that stored frame, replay renders it again."""

import json
import subprocess

import numpy as np
import pandas as pd
import pytest

from conftest import REPO
from test_search import SPACE, recipe

TARGET_OBJECT_ID = 0


def boxpose(boxpose_bin, *args) -> subprocess.CompletedProcess:
    r = subprocess.run(
        [str(boxpose_bin), *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return r


@pytest.fixture(scope="module")
def size_fit_run(boxpose_bin, tmp_path_factory) -> tuple[object, pd.Series]:
    """A search of the size-and-pose fit and one of its scored samples."""
    root = tmp_path_factory.mktemp("perception")
    (root / "floor.toml").write_text(recipe("single_box"))
    (root / "single.toml").write_text(SPACE.format(recipe=root / "floor.toml"))
    run = root / "run"
    boxpose(
        boxpose_bin,
        "search",
        root / "single.toml",
        "--out",
        run,
        "--fit",
        "size",
        "--samples",
        2,
        "--batch-size",
        2,
        # a threshold nothing meets: every scored sample fails and keeps its frame
        "--fail-when",
        "mssd:0.000001",
        "--threads",
        1,
    )
    samples = pd.read_parquet(run / "samples.parquet")
    scored = samples[samples.fitted_corners_camera_m.notna()]
    assert not scored.empty, samples[["valid", "invalid_reason", "fit_error"]]
    return run, scored.iloc[0]


def test_predict_eval_and_replay_report_the_same_pose(size_fit_run, boxpose_bin, tmp_path):
    run, sample = size_fit_run
    scene = int(sample.sample_id)
    dataset = run / "counterexamples"
    searched_corners = np.asarray(sample.fitted_corners_camera_m).reshape(8, 3)

    boxpose(
        boxpose_bin,
        "predict",
        dataset,
        "--scene",
        scene,
        "--crops",
        "gt",
        "--out",
        tmp_path / "predict",
    )
    boxes = json.loads((tmp_path / "predict" / "predictions.json").read_text())["boxes"]
    (predicted,) = [b for b in boxes if b["object_id"] == TARGET_OBJECT_ID]
    fit = predicted["fit"]
    assert fit is not None, predicted["fit_error"]
    # the same float operations on the same fit: equal to the last bit
    assert np.array_equal(np.asarray(fit["corners_camera_m"]), searched_corners)
    assert fit["confidence"]["confidence"] == sample.fit_confidence

    boxpose(boxpose_bin, "eval", dataset, "--out", tmp_path / "eval")
    rows = pd.read_parquet(tmp_path / "eval" / "eval.parquet")
    (evaluated,) = rows[
        (rows.scene_id == scene)
        & (rows.object_id == TARGET_OBJECT_ID)
        & (rows.method == "size_and_pose")
    ].itertuples()
    truth = (
        pd.read_parquet(dataset / "instances")
        .query(f"scene_id == {scene} and object_id == {TARGET_OBJECT_ID}")
        .iloc[0]
    )
    predicted_centre = np.asarray(fit["pose_translation_m"])
    true_centre = np.asarray(truth.camera_box_translation_m)
    assert evaluated.translation_error_m == pytest.approx(
        np.linalg.norm(predicted_centre - true_centre), abs=1e-12
    )
    assert evaluated.translation_error_m == sample.translation_error_m
    assert evaluated.rotation_error_deg == sample.rotation_error_deg
    assert evaluated.mssd_m / evaluated.diameter_m == pytest.approx(
        sample.mssd_over_diameter, rel=1e-12
    )
    assert evaluated.cube_mssd_m / evaluated.diameter_m == pytest.approx(
        sample.cube_mssd_over_diameter, rel=1e-12
    )
    assert evaluated.confidence == fit["confidence"]["confidence"]
    assert evaluated.mirror_ambiguous == fit["confidence"]["mirror_ambiguous"]

    # replay renders the sample again and perceives it through the same function
    r = boxpose(
        boxpose_bin,
        "search",
        "replay",
        run,
        "--sample",
        scene,
        "--out",
        tmp_path / "replay",
        "--threads",
        1,
    )
    (replayed,) = [line for line in r.stdout.splitlines() if line.strip().startswith("replayed")]
    assert (
        f"cube MSSD/d {evaluated.cube_mssd_m / evaluated.diameter_m:.3f}, "
        f"MSSD/d {evaluated.mssd_m / evaluated.diameter_m:.3f}"
    ) in replayed, replayed
    assert "reproduced" in r.stdout, r.stdout
