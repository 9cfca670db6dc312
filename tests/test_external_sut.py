"""`boxpose search --sut` and `boxpose eval --sut`: another perception system under test, a
process speaking boxpose-sut/1 — the project's own pipeline through the protocol (`boxpose search
serve`) equals the built-in path sample for sample and box for box; a Python function
(examples/sut/pca_baseline.py) is scored; a system that crashes, hangs or cannot fit is counted
apart and started again; a system that cannot start is refused before any run folder is made.
Real MuJoCo, the embedded Blender at 96², real subprocesses."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import REPO, TINY_SEARCH_SPACE, render_synthetic_dataset
from test_search import recipe

COMMON = ["--samples", 4, "--batch-size", 2, "--seed", 5, "--threads", 1]
METRICS = [
    "paper_error",
    "paper_error_normalized",
    "mssd_over_diameter",
    "cube_mssd_over_diameter",
    "add_s_m",
    "translation_error_m",
    "fit_confidence",
]
PYTHON_SUT = f"exec:{sys.executable} -m boxpose_io.sut"


@pytest.fixture(scope="module")
def space(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("space")
    (root / "floor.toml").write_text(recipe("single_box"))
    (root / "single.toml").write_text(TINY_SEARCH_SPACE.format(recipe=root / "floor.toml"))
    return root / "single.toml"


def search(boxpose_bin: Path, *args, check=True, env=None) -> subprocess.CompletedProcess:
    r = subprocess.run(
        [str(boxpose_bin), "search", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
        env=env,
    )
    if check:
        assert r.returncode == 0, r.stdout + r.stderr
    return r


def test_the_own_pipeline_through_the_protocol_equals_the_built_in_path(
    space, boxpose_bin, tmp_path
):
    built_in, protocol = tmp_path / "built_in", tmp_path / "protocol"
    search(boxpose_bin, space, *COMMON, "--fit", "robust", "--whole-frames", "--out", built_in)
    serve = f"exec:{boxpose_bin} search serve --fit robust"
    search(boxpose_bin, space, *COMMON, "--sut", serve, "--out", protocol)

    a = pd.read_parquet(built_in / "samples.parquet")
    b = pd.read_parquet(protocol / "samples.parquet")
    assert a.valid.sum() >= 2 and a.paper_error.notna().sum() >= 2, a.invalid_reason.tolist()
    for column in ("sample_id", "valid", "invalid_reason", "detected", "fit_error", "failed"):
        assert a[column].tolist() == b[column].tolist(), column
    for column in METRICS:
        np.testing.assert_allclose(a[column], b[column], rtol=1e-9, atol=1e-12, err_msg=column)
    # the rotation error's arccos is steep near 0: the 4×4 text round trip moves it by < 1e-6°
    np.testing.assert_allclose(a.rotation_error_deg, b.rotation_error_deg, atol=1e-6)
    for x, y in zip(a.peaks_camera_m, b.peaks_camera_m, strict=True):
        assert (x is None) == (y is None) and (x is None or np.array_equal(x, y))

    record = json.loads((protocol / "run.json").read_text())["settings"]
    assert record["sut"] == serve and record["fit"] == "external" and record["whole_frames"]
    timings = pd.read_parquet(protocol / "timings.parquet")
    assert (timings.inference_s[b.valid.to_numpy()] > 0).all()
    page = (protocol / "report" / "index.html").read_text()
    assert "system under test" in page and "search serve" in page


def test_a_python_function_is_scored_through_the_protocol(space, boxpose_bin, tmp_path):
    out = tmp_path / "pca"
    # the `python:` form runs python3 from PATH: this interpreter's
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    search(
        boxpose_bin,
        space,
        *COMMON,
        "--sut",
        "python:examples.sut.pca_baseline:perceive",
        "--fail-when",
        "cube-mssd:0.1",
        "--out",
        out,
        env=env,
    )
    samples = pd.read_parquet(out / "samples.parquet")
    fitted = samples[samples.valid & samples.detected]
    assert len(fitted) >= 2, samples.invalid_reason.tolist()
    assert fitted.cube_mssd_over_diameter.notna().all()
    assert (fitted.failed == (fitted.cube_mssd_over_diameter > 0.1)).all()
    # a baseline of no network still lands near the box: the translation is the mask's
    assert (fitted.translation_error_m < 0.1).all(), fitted.translation_error_m.tolist()
    assert fitted.fit_confidence.isna().all()  # it gives none
    summary = json.loads((out / "summary.json").read_text())
    assert summary["estimate"]["samples"] == 4 and not summary["warnings"]


def test_a_system_that_crashes_hangs_or_cannot_fit_is_counted_apart(space, boxpose_bin, tmp_path):
    out = tmp_path / "misbehaves"
    r = search(
        boxpose_bin,
        space,
        "--samples",
        8,
        "--batch-size",
        4,
        "--seed",
        5,
        "--threads",
        1,
        "--sut",
        f"{PYTHON_SUT} tests.sut_fixtures:misbehaves",
        "--sut-timeout",
        5,
        "--out",
        out,
    )
    samples = pd.read_parquet(out / "samples.parquet")
    reached = samples[
        ~samples.invalid_reason.fillna("").str.match(r"not stable|target \d+% visible")
    ]
    kinds = {k: reached[reached.sample_id % 4 == k] for k in range(4)}
    assert all(len(rows) > 0 for rows in kinds.values()), samples.invalid_reason.tolist()
    # found nothing: a failure of the system; its print went to stderr, not into the protocol
    assert (kinds[0].valid & kinds[0].failed & (kinds[0].detected == False)).all()  # noqa: E712
    assert "must go to stderr" in r.stderr
    # crashed or hung: not scored, named, and the process started again for the next sample
    for k, said in ((1, "exited"), (2, "no answer within 5 s")):
        rows = kinds[k]
        assert (~rows.valid & ~rows.failed).all()
        assert rows.invalid_reason.str.startswith("system under test").all()
        assert rows.invalid_reason.str.contains(said).all(), rows.invalid_reason.tolist()
    # cannot fit: a failure, with the system's reason
    assert (kinds[3].failed & (kinds[3].fit_error == "too few points")).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["invalid_reasons"]["system under test"] == len(kinds[1]) + len(kinds[2])
    assert any("did not answer" in w for w in summary["warnings"]), summary["warnings"]


@pytest.mark.parametrize(
    ("sut", "said"),
    [
        ("nonsense", "use exec:COMMAND"),
        ("python:only_a_module", "python:MODULE:CALLABLE"),
        ("exec:true", "did not introduce itself"),
        ('exec:echo \'{"protocol": "boxpose-sut/0"}\'', "speaks boxpose-sut/0"),
    ],
)
def test_a_system_that_cannot_start_is_refused_before_any_run_folder(
    sut, said, space, boxpose_bin, tmp_path
):
    out = tmp_path / "run"
    r = search(boxpose_bin, space, *COMMON, "--sut", sut, "--out", out, check=False)
    assert r.returncode != 0 and said in r.stderr, r.stderr
    assert not out.exists()


def run_boxpose(boxpose_bin: Path, *args, check=True) -> subprocess.CompletedProcess:
    """From the repository root, where the default model and the test fixtures' module are."""
    r = subprocess.run(
        [str(boxpose_bin), *map(str, args)], capture_output=True, text=True, cwd=REPO, timeout=600
    )
    if check:
        assert r.returncode == 0, r.stdout + r.stderr
    return r


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    """Two scenes of 2 and 3 boxes, two views each, at 128×96."""
    return render_synthetic_dataset(tmp_path_factory.mktemp("eval_sut") / "frames", 128, 96)


def test_eval_of_the_own_pipeline_through_the_protocol_equals_its_own_eval(
    frames, boxpose_bin, tmp_path
):
    own, protocol = tmp_path / "own", tmp_path / "protocol"
    # one crop per forward pass, as the server runs them: the same arithmetic
    run_boxpose(boxpose_bin, "eval", frames, "--batch-size", 1, "--out", own)
    serve = f"exec:{boxpose_bin} search serve --fit robust"
    r = run_boxpose(boxpose_bin, "eval", frames, "--sut", serve, "--out", protocol)
    assert "cube MSSD < 0.1 d" in r.stdout and 'method "external"' in r.stdout

    keys = ["scene_id", "frame_id", "object_id"]
    a = pd.read_parquet(own / "eval.parquet").query("method == 'robust'").set_index(keys)
    b = pd.read_parquet(protocol / "eval.parquet").set_index(keys)
    assert set(b.method) == {"external"} and len(a) >= 4
    assert a.index.tolist() == b.index.tolist()
    assert a.fit_error.isna().tolist() == b.fit_error.isna().tolist()
    for column in ("paper_error", "mssd_m", "cube_mssd_m", "add_s_m", "translation_error_m"):
        np.testing.assert_allclose(a[column], b[column], rtol=1e-9, atol=1e-12, err_msg=column)
    # what an external system does not report is null, never a made-up value
    assert b.heatmap_mse.isna().all() and b.inliers.isna().all() and b.margin_nats.isna().all()
    summary = json.loads((protocol / "summary.json").read_text())
    assert summary["instances"] == len(b) and summary["system_errors"] == 0

    # the two runs pair box by box: nothing fixed, nothing new
    out = tmp_path / "compare.json"
    run_boxpose(
        boxpose_bin, "eval", "compare", own, protocol, "--method", "robust,external", "--json", out
    )
    compared = json.loads(out.read_text())
    assert compared["pairs"] == len(a) and not compared["fixed"] and not compared["new"]


def test_eval_counts_a_crashing_system_apart_and_starts_it_again(frames, boxpose_bin, tmp_path):
    out = tmp_path / "misbehaves"
    r = run_boxpose(
        boxpose_bin,
        "eval",
        frames,
        "--sut",
        f"{PYTHON_SUT} tests.sut_fixtures:misbehaves",
        "--out",
        out,
    )
    rows = pd.read_parquet(out / "eval.parquet")
    by_scene = {k: rows[rows.scene_id == k] for k in (0, 1)}
    assert len(by_scene[0]) > 0 and len(by_scene[1]) > 0
    # scene 0: found nothing, a failure of the system's own
    assert (by_scene[0].fit_error == "not found by the system").all()
    # scene 1: it crashed on every box, each time started again, never scored
    assert by_scene[1].fit_error.str.startswith("system under test").all()
    assert by_scene[1].cube_mssd_m.isna().all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["system_errors"] == len(by_scene[1]) and summary["restarts"] >= 1
    assert f"system errors {len(by_scene[1])}" in r.stdout


def test_eval_on_predicted_crops_sends_no_box_and_scores_what_the_system_says(
    frames, boxpose_bin, tmp_path
):
    # --crops predicted: the whole frame without the target's box or mask; the PCA baseline
    # needs the mask, so it gives up on every box — a failure of its own, with its reason
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    out = tmp_path / "pca"
    r = subprocess.run(
        [str(boxpose_bin), "eval", str(frames), "--crops", "predicted", "--out", str(out),
         "--sut", "python:examples.sut.pca_baseline:perceive"],
        capture_output=True, text=True, cwd=REPO, env=env, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    rows = pd.read_parquet(out / "eval.parquet")
    assert len(rows) >= 4 and rows.cube_mssd_m.isna().all()
    assert rows.fit_error.str.contains("needs the target's mask").all(), rows.fit_error.tolist()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fit_failed"] == len(rows) and summary["cube_mssd_recall_010"] == 0.0


def test_eval_refuses_a_system_that_cannot_start_before_any_output(frames, boxpose_bin, tmp_path):
    out = tmp_path / "eval"
    r = run_boxpose(boxpose_bin, "eval", frames, "--sut", "exec:true", "--out", out, check=False)
    assert r.returncode != 0 and "did not introduce itself" in r.stderr, r.stderr
    assert not out.exists()


@pytest.fixture(scope="module")
def sensor_frames(tmp_path_factory) -> Path:
    """The same two scenes with the simulated sensor's depth channel rendered too."""
    root = tmp_path_factory.mktemp("eval_sensor") / "frames"
    return render_synthetic_dataset(root, 128, 96, sensor_depth=True)


def test_eval_perceives_the_sensor_depth_and_sends_it_to_another_system(
    sensor_frames, frames, boxpose_bin, tmp_path
):
    """`eval --sensor-depth` perceives the frames' simulated sensor depth instead of the exact
    one: other poses than the exact depth's, the same depth sent to another system (the own
    pipeline through the protocol answers as the own eval), and a dataset without the channel is
    one clear error that leaves nothing behind."""
    exact, sensor, protocol = tmp_path / "exact", tmp_path / "sensor", tmp_path / "protocol"
    run_boxpose(boxpose_bin, "eval", sensor_frames, "--batch-size", 1, "--out", exact)
    run_boxpose(
        boxpose_bin, "eval", sensor_frames, "--batch-size", 1, "--sensor-depth", "--out", sensor
    )
    serve = f"exec:{boxpose_bin} search serve --fit robust"
    run_boxpose(
        boxpose_bin, "eval", sensor_frames, "--sut", serve, "--sensor-depth", "--out", protocol
    )
    keys = ["scene_id", "frame_id", "object_id"]
    a = pd.read_parquet(exact / "eval.parquet").query("method == 'robust'").set_index(keys)
    b = pd.read_parquet(sensor / "eval.parquet").query("method == 'robust'").set_index(keys)
    c = pd.read_parquet(protocol / "eval.parquet").set_index(keys)
    assert a.index.tolist() == b.index.tolist() == c.index.tolist() and len(a) >= 4
    fitted = a.translation_error_m.notna() & b.translation_error_m.notna()
    assert fitted.any()
    assert (a.translation_error_m[fitted] != b.translation_error_m[fitted]).any()
    assert b.fit_error.isna().tolist() == c.fit_error.isna().tolist()
    for column in ("paper_error", "cube_mssd_m", "translation_error_m"):
        np.testing.assert_allclose(b[column], c[column], rtol=1e-9, atol=1e-12, err_msg=column)

    missing = tmp_path / "no-sensor"
    r = run_boxpose(boxpose_bin, "eval", frames, "--sensor-depth", "--out", missing, check=False)
    assert r.returncode == 1 and "has no sensor depth" in r.stderr, r.stderr
    assert str(frames) in r.stderr and "sensor_depth = true" in r.stderr
    assert not missing.exists()
