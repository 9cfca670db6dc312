"""`boxpose eval-geometry` on a real tiny dataset (Drake scenes, Blender renders): the heatmap →
pose stage with perfect heatmaps, then with the paper's failure mode (confident outlier peaks)."""

import subprocess
import sys

import pandas as pd
import pyarrow.parquet as pq
import pytest

from conftest import REPO, run_boxpose


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval") / "tiny"
    subprocess.run(
        [
            sys.executable,
            REPO / "scripts" / "make_scenes.py",
            "--recipe",
            "tiny",
            "--dataset",
            root,
            "--num-scenes",
            "3",
            "--no-inspect",
        ],
        check=True,
        capture_output=True,
    )
    return root


def evaluate(boxpose_bin, dataset, out, outliers):
    result = run_boxpose(
        boxpose_bin,
        "eval-geometry",
        dataset,
        "--out",
        out,
        "--outliers",
        outliers,
        "--min-visible-fraction",
        "0.2",
    )
    assert "per-instance metrics" in result.stdout
    assert pq.read_schema(out).metadata[b"boxpose.table"] == b"eval_geometry"
    return pd.read_parquet(out)


def test_perfect_heatmaps_give_the_true_pose_and_both_exact_searches_agree(
    tiny_dataset, boxpose_bin, tmp_path
):
    rows = evaluate(boxpose_bin, tiny_dataset, tmp_path / "clean.parquet", 0)
    assert rows.fit_error.isna().all()
    paper = rows[rows.method == "paper_exact"].set_index(["scene_id", "frame_id", "object_id"])
    fast = rows[rows.method == "fast_exact"].set_index(["scene_id", "frame_id", "object_id"])
    assert len(paper) >= 3
    # Same optimum: the same pose, so the same errors, instance by instance.
    pd.testing.assert_series_equal(paper.paper_error, fast.paper_error, rtol=1e-6)
    # 3 mm corner noise on 64³ voxels: every pose within 5 % of the box diameter.
    assert (paper.mssd_m < 0.05 * paper.diameter_m).all()


def test_four_confident_outliers_break_the_paper_search_but_not_the_robust_fit(
    tiny_dataset, boxpose_bin, tmp_path
):
    rows = evaluate(boxpose_bin, tiny_dataset, tmp_path / "outliers.parquet", 4)
    recall = rows.assign(ok=rows.mssd_m < 0.1 * rows.diameter_m).groupby("method").ok.mean()
    assert recall["robust"] >= 0.6
    assert recall["paper_exact"] <= 0.3
    assert recall["robust"] > recall["paper_exact"]


def test_every_fit_row_carries_its_confidence(tiny_dataset, boxpose_bin, tmp_path):
    clean = evaluate(boxpose_bin, tiny_dataset, tmp_path / "clean.parquet", 0)
    noisy = evaluate(boxpose_bin, tiny_dataset, tmp_path / "outliers.parquet", 4)
    assert set(clean.method) == {
        "paper_exact",
        "fast_exact",
        "robust",
        "size_and_pose",
        "robust_fixed",
        "size_and_pose_ls",
    }
    for rows in (clean, noisy):
        fitted = rows[rows.fit_error.isna()]
        assert fitted.confidence.between(
            0, 1
        ).all()  # 1 when no different box is a hypothesis (infinite margin)
        assert (fitted.inliers >= 3).all() and (fitted.inliers <= 8).all()
        assert (fitted.noise_scale_m > 0).all()
        assert fitted.mirror_ambiguous.dtype == bool
        # a positive margin and only a positive margin gives a positive confidence; no other box
        # hypothesis (an infinite margin, confidence 1) is written as null, never as ±inf
        assert ((fitted.margin_nats.fillna(float("inf")) > 0) == (fitted.confidence > 0)).all()
        assert (fitted.margin_nats.isna() == (fitted.confidence == 1.0)).all()

    def robust(rows):
        return rows[rows.method == "robust"]

    # perfect heatmaps with 3 mm noise: every peak a corner, millimetre noise
    assert (robust(clean).inliers == 8).mean() >= 0.8
    assert robust(clean).noise_scale_m.median() < 0.006
    # 4 of the 8 peaks are confident outliers: the robust fit counts about 4 inliers
    assert robust(noisy).inliers.median() <= 5 < robust(clean).inliers.median()


def test_its_own_earlier_table_is_replaced(tiny_dataset, boxpose_bin, tmp_path):
    # the table is read back through the dataset reader's checks before it is replaced (an
    # infinite margin, once written as +inf, made a rerun refuse it: fit_table's unit test)
    out = tmp_path / "again.parquet"
    first = evaluate(boxpose_bin, tiny_dataset, out, 0)
    second = evaluate(boxpose_bin, tiny_dataset, out, 0)
    pd.testing.assert_frame_equal(
        first.drop(columns="fit_time_us"), second.drop(columns="fit_time_us")
    )


def test_missing_dataset_is_a_clear_error(boxpose_bin, tmp_path):
    result = run_boxpose(boxpose_bin, "eval-geometry", tmp_path / "nope", check=False)
    assert result.returncode != 0 and "does not exist" in result.stderr
