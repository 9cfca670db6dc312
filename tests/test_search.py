"""`boxpose search` end to end with the real MuJoCo, the embedded Blender (96² renders at 1
sample) and the shipped networks: Monte Carlo and cross-entropy runs, their tables read back with
pandas, resume after a kill, two shards merged, bad search spaces refused before any work, and
counterexamples that `boxpose render` re-renders exactly. The networks see tiny renders, so the
failure rates mean nothing here; the plumbing, the determinism and the files are tested."""

import io
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import boxpose_io
from conftest import REPO, TINY_SEARCH_SPACE as SPACE, run_boxpose

NEIGHBOURS = """
[neighbours]
count = [1, 2]
size_m = { x = [0.06, 0.12], y = [0.05, 0.10], z = [0.04, 0.08] }
yaw_deg = [0.0, 360.0]
x_m = [-0.2, 0.2]
y_m = [-0.2, 0.2]
"""


def rgb(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png))).astype(int)


def recipe(base: str) -> str:
    text = (REPO / "datasets" / "recipes" / f"{base}.toml").read_text()
    for old, new in (
        ("width = 640", "width = 96"),
        ("height = 480", "height = 96"),
        ("width = 256", "width = 96"),
        ("height = 256", "height = 96"),
        ("samples = 4", "samples = 1"),
        ("denoise = true", "denoise = false"),
    ):
        text = text.replace(old, new)
    return text


@pytest.fixture(scope="module")
def spaces(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("spaces")
    (root / "floor.toml").write_text(recipe("single_box"))
    (root / "bin.toml").write_text(recipe("clutter"))
    (root / "single.toml").write_text(SPACE.format(recipe=root / "floor.toml"))
    (root / "clutter.toml").write_text(
        SPACE.format(recipe=root / "bin.toml").replace("test_single_box", "test_clutter")
        + NEIGHBOURS
    )
    return {"single": root / "single.toml", "clutter": root / "clutter.toml"}


def search(boxpose_bin: Path, *args, check=True, timeout=600) -> subprocess.CompletedProcess:
    r = subprocess.run(
        [str(boxpose_bin), "search", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=timeout,
    )
    if check:
        assert r.returncode == 0, r.stdout + r.stderr
    return r


MC = ["--samples", 6, "--batch-size", 2, "--seed", 3, "--threads", 1]


@pytest.fixture(scope="module")
def mc_run(spaces, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("mc") / "run"
    search(boxpose_bin, spaces["single"], "--out", out, "--fail-when", "mssd:0.05", *MC)
    return out


def test_monte_carlo_run_writes_its_tables_estimate_and_report(mc_run, boxpose_bin):
    samples = pd.read_parquet(mc_run / "samples.parquet")
    assert list(samples.sample_id) == list(range(6))
    assert set(samples.stage) == {"mc"} and (samples.log_weight == 0).all()
    valid = samples[samples.valid]
    assert len(valid) > 0, samples.invalid_reason.tolist()
    # the failure flag is the predicate on the stored metric (or no fit at all)
    fitted = valid[valid.mssd_over_diameter.notna()]
    assert (fitted.failed == (fitted.mssd_over_diameter > 0.05)).all()
    assert (samples.z.map(len) == samples.params.map(len)).all()
    timings = pd.read_parquet(mc_run / "timings.parquet")
    assert list(timings.sample_id) == list(range(6)) and (timings.render_s[samples.valid] > 0).all()

    summary = json.loads((mc_run / "summary.json").read_text())
    e = summary["estimate"]
    assert (
        e["samples"] == 6
        and e["valid"] == len(valid)
        and e["failures"] == int(samples.failed.sum())
    )
    assert e["ci_method"] == "clopper_pearson"
    lo, hi = e["ci95"]
    assert lo <= e["p_hat"] <= hi and 0.0 <= lo and hi <= 1.0
    assert math.isclose(e["p_valid"], len(valid) / 6)
    # one stratum (no neighbours), flat: its counts and estimate
    (stratum,) = summary["strata"]
    assert stratum["neighbours"] == 0 and stratum["samples"] == 6 and stratum["valid"] == len(valid)
    assert stratum["p_hat"] == e["p_hat"] and "strata" not in e
    assert (mc_run / "report" / "index.html").is_file()
    if samples.failed.any():
        r = subprocess.run(
            [str(boxpose_bin), "inspect", mc_run / "counterexamples"],
            capture_output=True,
            text=True,
        )
        assert r.returncode == 0, r.stderr
        assert set(pd.read_parquet(mc_run / "counterexamples" / "scenes").scene_id) == set(
            samples.sample_id[samples.failed]
        )


def wait_for_a_batch(process: subprocess.Popen, run: Path) -> Path:
    """Waits (up to 5 minutes) until the search `process` committed a batch into `run`, or ended;
    the run's folder of committed sample batches."""
    batches = run / "batches" / "samples"
    deadline = time.time() + 300
    while (
        not (batches.is_dir() and any(batches.glob("*.parquet")))
        and time.time() < deadline
        and process.poll() is None
    ):
        time.sleep(0.02)
    return batches


def test_a_killed_run_resumes_to_identical_samples(mc_run, spaces, boxpose_bin, tmp_path):
    out = tmp_path / "run"
    args = [
        str(boxpose_bin),
        "search",
        spaces["single"],
        "--out",
        out,
        "--fail-when",
        "mssd:0.05",
        *map(str, MC),
    ]
    process = subprocess.Popen(
        args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    batches = wait_for_a_batch(process, out)
    # Frozen after its first batch, so that an idle machine cannot finish the run before the
    # kill (found: CI's idle run did); a stopped process still holds its lock.
    os.killpg(process.pid, signal.SIGSTOP)
    # a second process on the same shard of the run is refused while the first one samples
    second = search(boxpose_bin, *args[2:], check=False)
    assert second.returncode == 1
    assert "shard 0 of 1 is being sampled by another process" in second.stderr
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert not (out / "samples.parquet").exists(), "killed before the end"
    committed = {p.name: p.stat().st_mtime_ns for p in batches.glob("*.parquet")}
    search(boxpose_bin, spaces["single"], "--out", out, "--fail-when", "mssd:0.05", *MC)
    assert (out / "samples.parquet").read_bytes() == (mc_run / "samples.parquet").read_bytes()
    # the batches committed before the kill were kept, not recomputed
    assert all((batches / name).stat().st_mtime_ns == mtime for name, mtime in committed.items())


def test_ctrl_c_ends_a_search_at_once(spaces, boxpose_bin, tmp_path):
    """The embedded Python turned SIGINT into a KeyboardInterrupt that Blender's render engine
    caught and printed, so a Ctrl-C left the search running to its last sample. Now it ends the
    process at once (status 130, as SIGINT's default action), and the batches committed before
    it stay for the resume."""
    out = tmp_path / "run"
    args = [boxpose_bin, "search", spaces["single"], "--out", out, "--samples", 400]
    args += ["--batch-size", 2, "--seed", 3, "--threads", 1]
    process = subprocess.Popen(
        list(map(str, args)),
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # as a terminal starts it: a CI job started in the background inherits SIGINT ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    batches = wait_for_a_batch(process, out)
    assert process.poll() is None, "the search ended before its first batch was seen"
    process.send_signal(signal.SIGINT)
    sent = time.monotonic()
    try:
        _, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
    answered = time.monotonic() - sent
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and answered < 5.0, (answered, stderr)
    assert not (out / "samples.parquet").exists() and any(batches.glob("*.parquet"))


def test_refine_depth_is_a_setting_of_the_run(spaces, boxpose_bin, tmp_path):
    """`--refine-depth` lays each fit on the depth image: the run records it, a resume without
    it is refused naming the flag, and the refined poses are not the unrefined ones."""
    out = tmp_path / "refined"
    search(boxpose_bin, spaces["single"], "--out", out, "--refine-depth", *MC)
    assert json.loads((out / "run.json").read_text())["settings"]["refine_depth"] is True
    refused = search(boxpose_bin, spaces["single"], "--out", out, *MC, check=False)
    assert refused.returncode == 1
    assert "--refine-depth is true there, false here" in refused.stderr, refused.stderr
    plain = tmp_path / "plain"
    search(boxpose_bin, spaces["single"], "--out", plain, *MC)
    refined = pd.read_parquet(out / "samples.parquet").set_index("sample_id")
    unrefined = pd.read_parquet(plain / "samples.parquet").set_index("sample_id")
    # the same scenes (the same seeds), other poses
    assert (refined.seed == unrefined.seed).all()
    fitted = refined.translation_error_m.notna() & unrefined.translation_error_m.notna()
    assert fitted.any()
    assert (refined.translation_error_m[fitted] != unrefined.translation_error_m[fitted]).any()
    # the same scenes perceived otherwise: the two runs pair sample by sample
    search(boxpose_bin, "compare", plain, out, "--json", tmp_path / "compare.json")
    assert json.loads((tmp_path / "compare.json").read_text())["pairs"] == len(refined)


def test_sensor_depth_is_a_setting_of_the_run_and_what_the_perception_reads(
    spaces, boxpose_bin, tmp_path
):
    """`--sensor-depth` perceives the simulated structured-light depth: the run records it, the
    samples' renders carry the sensor channel, the perception of the same scenes differs from the
    exact depth's, and `search agree` counts it another event."""
    every_sample_fails = ["--fail-when", "mssd:0.000001", *MC]  # so that every frame is kept
    sensor, exact = tmp_path / "sensor", tmp_path / "exact"
    search(boxpose_bin, spaces["single"], "--out", sensor, "--sensor-depth", *every_sample_fails)
    search(boxpose_bin, spaces["single"], "--out", exact, *every_sample_fails)
    assert json.loads((sensor / "run.json").read_text())["settings"]["sensor_depth"] is True
    assert json.loads((exact / "run.json").read_text())["settings"]["sensor_depth"] is False
    frames = pd.read_parquet(sensor / "counterexamples" / "frames")
    assert len(frames) > 0 and frames.sensor_depth_m_f32le.notna().all()
    assert pd.read_parquet(exact / "counterexamples" / "frames").sensor_depth_m_f32le.isna().all()
    a = pd.read_parquet(sensor / "samples.parquet").set_index("sample_id")
    b = pd.read_parquet(exact / "samples.parquet").set_index("sample_id")
    assert (a.seed == b.seed).all()  # the same scenes
    fitted = a.translation_error_m.notna() & b.translation_error_m.notna()
    assert fitted.any()
    assert (a.translation_error_m[fitted] != b.translation_error_m[fitted]).any()
    r = search(boxpose_bin, "agree", exact, sensor, check=False)
    assert r.returncode == 1 and "another event" in r.stderr
    # but the same scenes: the two runs pair sample by sample
    search(boxpose_bin, "compare", exact, sensor, "--json", tmp_path / "compare.json")
    assert json.loads((tmp_path / "compare.json").read_text())["pairs"] == len(a)


def test_a_run_kept_as_a_reference_pairs_with_itself(mc_run, tmp_path):
    """scripts/search_reference.py keeps a run's summaries as docs/reference/ holds them and pairs
    two kept runs sample by sample: a run against itself has no discordant pair."""
    script = REPO / "scripts" / "search_reference.py"
    kept = tmp_path / "kept"
    keep = [sys.executable, script, "keep", mc_run, kept]
    subprocess.run(list(map(str, keep)), check=True, capture_output=True)
    errors = pd.read_csv(kept / "errors.csv.gz")
    samples = pd.read_parquet(mc_run / "samples.parquet")
    assert list(errors.sample_id) == list(samples.sample_id)
    assert np.allclose(errors.paper_error_normalized, samples.paper_error_normalized, rtol=1e-5)
    failures = json.loads((kept / "failures.json").read_text())
    assert [f["sample_id"] for f in failures] == list(samples.sample_id[samples.failed])
    assert {"run.json", "summary.json", "error_hist.png"} <= {p.name for p in kept.iterdir()}
    pair = [sys.executable, script, "pair", kept / "errors.csv.gz", kept / "errors.csv.gz"]
    r = subprocess.run(list(map(str, pair)), check=True, capture_output=True, text=True)
    assert "6 paired samples" in r.stdout
    assert r.stdout.count("fixed 0, new 0, McNemar p = 1") == 4, r.stdout
    # a run checked against itself as the reference: it covers it, and it is Monte Carlo, so
    # Monte Carlo at its own budget is exactly as precise
    against = [sys.executable, script, "against", kept / "errors.csv.gz", mc_run]
    r = subprocess.run(list(map(str, against)), check=False, capture_output=True, text=True)
    k = int(samples.failed.sum())
    if k == 0:  # nothing to compare by: refused, and said why
        assert r.returncode != 0 and "never fails" in r.stderr, r.stderr
    else:
        assert r.returncode == 0, r.stderr
        row = r.stdout.splitlines()[-1].split(" | ")
        assert row[0] == "| mc" and row[6] == "yes", r.stdout
        assert row[-1] == ("— |" if k == len(samples) else "1.0× |"), r.stdout
    # another event (here another fit) is no reference for the run
    record = json.loads((kept / "run.json").read_text())
    record["settings"]["fit"] = "robust"
    (kept / "run.json").write_text(json.dumps(record))
    r = subprocess.run(list(map(str, against)), check=False, capture_output=True, text=True)
    assert r.returncode != 0 and "not the reference's event (fit differ)" in r.stderr, r.stderr


def test_references_of_other_seeds_pool_and_are_tested_for_agreement(mc_run, tmp_path):
    """scripts/search_reference.py pool: two Monte Carlo runs of one event with other seeds side by
    side and pooled, with the exact conditional test of equal rates; a run of the same seed or
    another sampler is no second reference."""
    script = REPO / "scripts" / "search_reference.py"
    first, second = tmp_path / "first", tmp_path / "second"
    subprocess.run(list(map(str, [sys.executable, script, "keep", mc_run, first])), check=True)
    shutil.copytree(first, second)
    errors = pd.read_csv(first / "errors.csv.gz")
    n = int(errors.valid.sum())
    # every valid sample of the first fails the paper's predicate and the run's own (exact MSSD >
    # 0.05 d), none of the second: given the n failures, all n fell in the first run where equal
    # rates put each there with chance ½
    for folder, error in [(first, 1.0), (second, 0.0)]:
        changed = errors.assign(paper_error_normalized=error, mssd_over_diameter=error)
        changed.to_csv(folder / "errors.csv.gz", index=False)
    record = json.loads((second / "run.json").read_text())
    record["settings"]["seed"] += 1
    (second / "run.json").write_text(json.dumps(record))
    pool = [sys.executable, script, "pool", first / "errors.csv.gz", second / "errors.csv.gz"]
    r = subprocess.run(list(map(str, pool)), check=True, capture_output=True, text=True)
    rows = {line.split(" | ")[0]: line.split(" | ") for line in r.stdout.splitlines()}
    paper = rows["| the paper's (normalised error > 0.005)"]
    assert paper[1].startswith(f"{n}: 1.00e+00") and paper[2].startswith("0: 0.00e+00"), r.stdout
    assert paper[3].startswith(f"{n}: 5.00e-01"), r.stdout
    assert float(paper[4].rstrip(" |")) == pytest.approx(2 * 0.5**n, rel=0.01), r.stdout
    # the cube metric's errors are the same in both runs: they agree exactly
    assert rows["| cube MSSD > 0.05 d"][4] == "1 |", r.stdout
    # `against --pool` checks a run against both together
    against = [sys.executable, script, "against", first / "errors.csv.gz", "--pool"]
    against += [second / "errors.csv.gz", mc_run]
    r = subprocess.run(list(map(str, against)), check=True, capture_output=True, text=True)
    assert f"{n} of {2 * n}, p̂ 5.00e-01" in r.stdout, r.stdout
    # the same seed again is the same samples; cross-entropy is no reference
    record["settings"]["seed"] -= 1
    (second / "run.json").write_text(json.dumps(record))
    r = subprocess.run(list(map(str, pool)), check=False, capture_output=True, text=True)
    assert r.returncode != 0 and "the same samples, not independent ones" in r.stderr, r.stderr
    record["settings"]["sampler"] = "ce"
    (second / "run.json").write_text(json.dumps(record))
    r = subprocess.run(list(map(str, pool)), check=False, capture_output=True, text=True)
    assert r.returncode != 0 and "a reference is a Monte Carlo run, not ce" in r.stderr, r.stderr


def test_two_shards_merge_to_the_single_process_table(mc_run, spaces, boxpose_bin, tmp_path):
    out = tmp_path / "run"
    args = [spaces["single"], "--out", out, "--fail-when", "mssd:0.05", *MC, "--num-shards", 2]
    first = subprocess.Popen(
        [str(boxpose_bin), "search", *map(str, args), "--shard", "1"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    search(boxpose_bin, *args, "--shard", 0)
    assert first.wait(timeout=600) == 0, first.stderr.read()
    search(boxpose_bin, "merge", out)
    assert (out / "samples.parquet").read_bytes() == (mc_run / "samples.parquet").read_bytes()


def test_a_resumed_run_with_other_settings_is_refused(mc_run, spaces, boxpose_bin):
    r = search(
        boxpose_bin,
        spaces["single"],
        "--out",
        mc_run,
        "--fail-when",
        "mssd:0.05",
        "--samples",
        6,
        "--batch-size",
        2,
        "--seed",
        4,
        check=False,
    )
    assert r.returncode != 0 and "another search" in r.stderr, r.stderr
    # the setting that differs is named, with both values
    assert "--seed is 3 there, 4 here" in r.stderr, r.stderr


def test_a_refused_search_leaves_no_run_behind(spaces, boxpose_bin, tmp_path):
    """Everything a search needs is checked before run.json is written: a refused command used
    to leave a run.json that then refused the corrected command as "another search"."""
    bad_recipes = {}
    floor = spaces["single"].parent / "floor.toml"
    for name, old, new in (
        ("samples", "samples = 1", "samples = 0"),
        ("width", "width = 96", "width = 0"),
    ):
        recipe_path = tmp_path / f"recipe-{name}.toml"
        recipe_path.write_text(floor.read_text().replace(old, new, 1))
        space = tmp_path / f"space-{name}.toml"
        space.write_text(spaces["single"].read_text().replace(str(floor), str(recipe_path)))
        bad_recipes[name] = space
    out = tmp_path / "run"
    for space, args, said in (
        (spaces["single"], ["--model", "models/keypoint-slm"], "--model models/keypoint-slm"),
        (
            spaces["single"],
            ["--crops", "predicted", "--segmenter", "models/segmenter-slm"],
            "--segmenter models/segmenter-slm",
        ),
        (spaces["single"], ["--num-shards", 0], "--num-shards 0"),
        (bad_recipes["samples"], [], "render.samples"),
        (bad_recipes["width"], [], "key 'camera.width' must be ≥ 1"),
    ):
        r = search(boxpose_bin, space, "--out", out, "--samples", 4, *args, check=False)
        assert r.returncode != 0 and said in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and not out.exists(), (args, r.stderr)
    # the corrected command starts the run
    r = search(boxpose_bin, spaces["single"], "--out", out, "--samples", 4, "--pending")
    assert json.loads(r.stdout)["batches"] == [0]


@pytest.fixture(scope="module")
def failing_run(spaces, boxpose_bin, tmp_path_factory) -> Path:
    """A run where every sample fails (a threshold nothing meets), so it has counterexamples."""
    out = tmp_path_factory.mktemp("failing") / "run"
    search(
        boxpose_bin,
        spaces["single"],
        "--out",
        out,
        "--samples",
        2,
        "--batch-size",
        2,
        "--fail-when",
        "mssd:0.000001",
        "--threads",
        1,
    )
    return out


def test_the_report_shows_each_counterexample_s_parameters_and_every_predicate_s_count(
    failing_run,
):
    """What a reader of the report needs without opening the tables: the worst samples'
    parameter values and rotation errors, and how many samples each predicate would flag."""
    html = (failing_run / "report" / "index.html").read_text()
    samples = pd.read_parquet(failing_run / "samples.parquet")
    run = json.loads((failing_run / "run.json").read_text())
    row = samples.iloc[0]
    d = run["dimensions"].index("camera.distance_m")
    assert "<code>camera.distance_m</code>" in html
    assert f"<td>{row.params[d]:.4f}</td>" in html
    assert f"<td>{row.rotation_error_deg:.1f}°</td>" in html
    valid = samples[samples.valid]
    exact = int(((valid.mssd_over_diameter > 0.1) | (valid.detected == False)).sum())  # noqa: E712
    assert f"exact MSSD &gt; 0.1 d (orientation-aware): {exact}." in html
    # a Monte Carlo run carries no weights: no weight diagnostics in its table
    assert "<td>—</td><td>—</td><td>—</td></tr></table>" in html
    # each drawn counterexample's caption is its exact re-render command, crop included
    frames = pd.read_parquet(failing_run / "counterexamples" / "frames")
    for scene_id, settings in zip(frames.scene_id, frames.render_settings, strict=True):
        crop = ",".join(map(str, json.loads(settings)["crop"]))
        command = (
            f"boxpose render {failing_run / 'counterexamples'} --scene {scene_id} --crop {crop}"
        )
        assert f"<code>{command}</code>" in html, command
        # and its ground-truth sheet (boxpose view): drawn, shown, and as wide as three panels
        sheet = failing_run / "report" / f"sample-{scene_id}-sheet.png"
        assert f'src="sample-{scene_id}-sheet.png"' in html
        with Image.open(sheet) as image:
            assert image.width > 2 * frames.width[frames.scene_id == scene_id].iloc[0]


def test_view_draws_a_counterexample_with_its_peaks_fit_and_parameters(
    failing_run, boxpose_bin, tmp_path
):
    """`boxpose view RUN --sample ID`: the counterexample's frame with the network's peaks (red)
    where the sample's peaks project, and its errors and parameters written beside it."""
    samples = pd.read_parquet(failing_run / "samples.parquet")
    row = samples[samples.failed & samples.peaks_camera_m.notna()].iloc[0]
    out = tmp_path / "sample.png"
    r = subprocess.run(
        [boxpose_bin, "view", failing_run, "--sample", str(row.sample_id), "--out", out],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    frame = pd.read_parquet(failing_run / "counterexamples" / "frames")
    frame = frame[frame.scene_id == row.sample_id].iloc[0]
    sheet = np.asarray(Image.open(out).convert("RGB")).astype(int)
    # beside three panels, a text column: wider than the panels alone
    assert sheet.shape[1] > 3 * frame.width + 16 + 200
    left = sheet[56 : 56 + frame.height, : frame.width]
    red = (np.abs(left - (214, 39, 40)).max(axis=2) <= 30).sum()
    peaks = np.asarray(row.peaks_camera_m).reshape(-1, 3)
    assert red >= 5 * len(peaks) > 0
    u = frame.fx * peaks[:, 0] / peaks[:, 2] + frame.cx
    v = frame.fy * peaks[:, 1] / peaks[:, 2] + frame.cy
    inside = (u >= 0) & (u < frame.width) & (v >= 0) & (v < frame.height)
    for x, y in zip(u[inside].round().astype(int), v[inside].round().astype(int), strict=True):
        assert np.abs(left[y, x] - (214, 39, 40)).max() <= 30, (x, y, left[y, x])
    r = subprocess.run(
        [boxpose_bin, "view", failing_run, "--scene", "0"], capture_output=True, text=True
    )
    assert r.returncode != 0 and "give --sample ID" in r.stderr, r.stderr


def test_counterexamples_re_render_exactly(failing_run, boxpose_bin, tmp_path):
    mc_run = failing_run
    samples = pd.read_parquet(mc_run / "samples.parquet")
    failed = samples[samples.failed]
    assert len(failed) == 2, samples[["valid", "invalid_reason", "score"]]
    sample = int(failed.sample_id.iloc[0])
    out = tmp_path / "rerender"
    # ground-truth-crop searches render the region around the target: render_settings say which
    frame = (
        pd.read_parquet(mc_run / "counterexamples" / "frames")
        .query(f"scene_id == {sample}")
        .iloc[0]
    )
    crop = json.loads(frame.render_settings)["crop"]
    region = ["--crop", ",".join(map(str, crop))] if crop else []
    r = subprocess.run(
        [
            str(boxpose_bin),
            "render",
            mc_run / "counterexamples",
            "--scene",
            str(sample),
            *region,
            "--out",
            out,
            "--threads",
            "1",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    again = pd.read_parquet(out / "frames").iloc[0]
    for column in (
        "width",
        "height",
        "cx",
        "cy",
        "render_seed",
        "depth_m_f32le",
        "instance_mask_png",
    ):
        assert again[column] == frame[column], column
    # Cycles at 1 sample is the same image within its noise, not bit for bit
    difference = np.abs(rgb(again.rgb_png) - rgb(frame.rgb_png))
    assert difference.mean() < 2.0, difference.mean()
    want = (
        pd.read_parquet(mc_run / "counterexamples" / "instances")
        .query(f"scene_id == {sample}")
        .sort_values("object_id")
    )
    got = pd.read_parquet(out / "instances").sort_values("object_id")
    for column in ("corners_px", "visible_pixels", "visible_fraction"):
        assert [list(v) if hasattr(v, "__len__") else v for v in want[column]] == [
            list(v) if hasattr(v, "__len__") else v for v in got[column]
        ]


def test_cross_entropy_tunes_then_estimates_from_a_frozen_proposal(spaces, boxpose_bin, tmp_path):
    out = tmp_path / "ce"
    search(
        boxpose_bin,
        spaces["single"],
        "--out",
        out,
        "--sampler",
        "ce",
        "--samples",
        4,
        "--batch-size",
        4,
        "--ce-samples-per-iteration",
        6,
        "--ce-max-iterations",
        2,
        "--ce-rho",
        0.5,
        "--fail-when",
        "mssd:0.02",
        "--threads",
        1,
    )
    samples = pd.read_parquet(out / "samples.parquet")
    tune, final = samples[samples.stage == "tune"], samples[samples.stage == "final"]
    assert len(final) == 4 and len(tune) in (6, 12)
    assert (tune[tune.iteration == 0].log_weight.abs() < 1e-9).all()
    # the frozen proposal mixes in the nominal with λ = 0.1: every weight is below 1/λ
    assert (final.log_weight <= math.log(10.0) + 1e-9).all()
    summary = json.loads((out / "summary.json").read_text())
    assert (
        summary["sampler"] == "ce"
        and summary["samples_spent"] == len(samples)
        and summary["tuning_samples"] == len(tune)
    )
    assert len(summary["ce_levels"]) == tune.iteration.nunique()
    assert summary["estimate"]["samples"] == 4


def test_clutter_on_the_segmenters_crops(spaces, boxpose_bin, tmp_path):
    out = tmp_path / "clutter"
    search(
        boxpose_bin,
        spaces["clutter"],
        "--out",
        out,
        "--crops",
        "predicted",
        "--fit",
        "robust",
        "--samples",
        3,
        "--batch-size",
        3,
        "--threads",
        1,
    )
    samples = pd.read_parquet(out / "samples.parquet")
    assert set(samples.stratum) <= {1, 2}
    scored = samples[samples.valid]
    # with the segmenter's crops a missed box is a failure, not a skipped sample
    assert (scored.detected.notna()).all() and (scored[scored.detected == False].failed).all()  # noqa: E712
    summary = json.loads((out / "summary.json").read_text())
    # strata are allocated in proportion (index mod count), each with its own estimate
    assert sorted(samples.stratum) == [1, 1, 2]
    assert [s["neighbours"] for s in summary["strata"]] == [1, 2]


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda t: t.replace("[camera]", "[camera]\nzoom = 2.0"), "zoom"),
        (
            lambda t: t.replace("distance_m = [0.45, 0.55]", "distance_m = [0.55, 0.45]"),
            "camera.distance_m",
        ),
        (
            lambda t: t.replace(
                "distance_m = [0.45, 0.55]",
                "distance_m = { normal = [9.0, 0.01], within = [0.45, 0.55] }",
            ),
            "camera.distance_m",
        ),
        (lambda t: t.replace('orientation = "so3"', 'orientation = "yaw"'), "target.yaw_deg"),
        (
            lambda t: t.replace("size_m = { x = [0.10, 0.20]", "size_m = { x = [-0.10, 0.20]"),
            "target.size_m.x",
        ),
        # a position beyond the support would be clamped, and the recorded parameter not used
        (
            lambda t: t.replace("x_m = [-0.05, 0.05]", "x_m = [5.0, 6.0]"),
            "target.x_m",
        ),
        # a value of the wrong type says what a parameter may be, not serde's enum variants
        (
            lambda t: t.replace("distance_m = [0.45, 0.55]", 'distance_m = "far"'),
            "[min, max] (uniform) or { normal = [mean, std], within = [min, max] }",
        ),
    ],
)
def test_a_bad_search_space_is_one_clear_error_before_any_work(
    edit, key, spaces, boxpose_bin, tmp_path
):
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(spaces["single"].read_text()))
    out = tmp_path / "run"
    r = search(boxpose_bin, bad, "--out", out, check=False)
    assert r.returncode != 0 and key in r.stderr, r.stderr
    assert not out.exists()


@pytest.mark.parametrize(
    "flag, value",
    [("--ce-lambda", -0.5), ("--ce-rho", 1.5), ("--ce-samples-per-iteration", 1)],
)
def test_a_bad_cross_entropy_setting_names_its_flag(flag, value, spaces, boxpose_bin, tmp_path):
    out = tmp_path / "run"
    r = search(
        boxpose_bin,
        spaces["single"],
        "--out",
        out,
        "--sampler",
        "ce",
        f"{flag}={value}",
        check=False,
    )
    assert r.returncode != 0 and f"error: {flag}:" in r.stderr, r.stderr
    assert "ce config" not in r.stderr and "sample:" not in r.stderr and not out.exists()


def refused_clutter_space(text, boxpose_bin, tmp_path) -> str:
    """Runs a search of the clutter space `text`; returns its stderr, having checked that it was
    refused before any work and without serde's or the source's words."""
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    out = tmp_path / "run"
    r = search(boxpose_bin, bad, "--out", out, check=False)
    assert r.returncode != 0 and not out.exists(), r.stderr
    assert "expected u32" not in r.stderr and "rust/" not in r.stderr, r.stderr
    return r.stderr


def test_a_negative_neighbour_count_is_refused_in_words(spaces, boxpose_bin, tmp_path):
    text = spaces["clutter"].read_text().replace("count = [1, 2]", "count = [-2, 3]")
    assert "whole numbers" in refused_clutter_space(text, boxpose_bin, tmp_path)


def test_an_unknown_recipe_key_points_to_boxpose_schema(spaces, boxpose_bin, tmp_path):
    base = spaces["clutter"].parent / "bin.toml"
    recipe = tmp_path / "bin.toml"
    recipe.write_text(base.read_text().replace("[boxes]", "[boxes]\nshine = 1.0"))
    text = spaces["clutter"].read_text().replace(str(base), str(recipe))
    assert "boxpose schema" in refused_clutter_space(text, boxpose_bin, tmp_path)


SPLITTING = [
    "--sampler",
    "splitting",
    "--samples",
    10,
    "--batch-size",
    4,
    "--splitting-level-probability",
    0.2,
    "--splitting-max-levels",
    3,
    "--fail-when",
    "mssd:0.02",
    "--seed",
    5,
    "--threads",
    1,
]


@pytest.fixture(scope="module")
def splitting_run(spaces, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("splitting") / "run"
    search(boxpose_bin, spaces["single"], "--out", out, *SPLITTING)
    return out


def test_subset_simulation_multiplies_its_levels_from_chains_it_stores(splitting_run):
    samples = pd.read_parquet(splitting_run / "samples.parquet")
    summary = json.loads((splitting_run / "summary.json").read_text())
    result = json.loads((splitting_run / "splitting.json").read_text())
    split = summary["splitting"]
    # every evaluation is one sample row, numbered once, each weighing 1
    assert list(samples.sample_id) == list(range(len(samples)))
    assert set(samples.stage) == {"split"} and (samples.log_weight == 0).all()
    assert split["evaluations"] == len(samples) == sum(lv["evaluations"] for lv in split["levels"])
    # stage 0 is 10 nominal draws; each later stage grows N·p₀ = 2 chains (more on ties) from
    # the particles above the previous level, which carry over unscored: N − chains new rows
    assert (samples.iteration == 0).sum() == 10
    levels = split["levels"]
    assert levels[0]["chains"] == 10 and levels[0]["acceptance_rate"] is None
    for level in levels[1:]:
        assert level["chains"] >= 2 and level["evaluations"] == 10 - level["chains"]
    thresholds = [lv["threshold"] for lv in levels]
    assert thresholds == sorted(thresholds), "the levels rise"
    # a stage's share above its level is what its particles say: at stage 0, the stored scores
    first = samples[samples.iteration == 0]
    above = (first.score.fillna(-math.inf) > thresholds[0]) & first.valid
    assert math.isclose(levels[0]["conditional_probability"], above.mean())
    # these settings reach the failure level at stage 1 (the first chains' stage)
    assert split["reached"] and len(levels) == 2
    # p̂ is the product of the shares over P̂(valid), the valid share of stage 0
    e = summary["estimate"]
    product = math.prod(lv["conditional_probability"] for lv in levels)
    assert thresholds[-1] == 0.0 and math.isclose(e["p_fail_and_valid"], product)
    assert math.isclose(e["p_hat"], product / e["p_valid"])
    lo, hi = e["ci95"]
    assert e["ci_method"] == "log_normal" and lo < e["p_hat"] < hi
    # the final failures are stored samples that failed
    failing = {p["evaluation"] for p in result["failures"]}
    assert failing and failing <= set(samples.sample_id[samples.failed])
    assert (splitting_run / "report" / "index.html").read_text().count("Splitting stages") == 1


def test_a_killed_subset_simulation_resumes_to_the_same_run(
    splitting_run, spaces, boxpose_bin, tmp_path
):
    out = tmp_path / "run"
    args = [str(boxpose_bin), "search", spaces["single"], "--out", out, *map(str, SPLITTING)]
    process = subprocess.Popen(
        args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    # killed once the first barrier is passed: stage 0 ranked, the chains' first move planned
    deadline = time.time() + 300
    while (
        not (out / "proposals" / "iter-0001.json").exists()
        and time.time() < deadline
        and process.poll() is None
    ):
        time.sleep(0.02)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert not (out / "splitting.json").exists(), "killed before the end"
    search(boxpose_bin, spaces["single"], "--out", out, *SPLITTING)
    for name in ("samples.parquet", "splitting.json"):
        assert (out / name).read_bytes() == (splitting_run / name).read_bytes(), name
    # the finished run is complete for a scheduler too
    r = search(boxpose_bin, spaces["single"], "--out", out, *SPLITTING, "--pending")
    assert json.loads(r.stdout)["complete"] is True
    # and another level probability is another search, named with both values
    changed = [str(a) for a in SPLITTING]
    changed[changed.index("--splitting-level-probability") + 1] = "0.1"
    r = search(boxpose_bin, spaces["single"], "--out", out, *changed, check=False)
    assert r.returncode != 0 and "--splitting-level-probability is 0.2 there, 0.1 here" in r.stderr


def test_a_splitting_run_against_a_reference_level_by_level(splitting_run, mc_run, tmp_path):
    """scripts/search_reference.py against: a subset simulation's running product at each of
    its levels beside the reference's share of samples scoring above that level, the score
    being log10(metric / threshold) of the run's own predicate (here exact MSSD > 0.02 d)."""
    script = REPO / "scripts" / "search_reference.py"
    kept = tmp_path / "kept"
    subprocess.run(list(map(str, [sys.executable, script, "keep", mc_run, kept])), check=True)
    errors = pd.read_csv(kept / "errors.csv.gz")
    # reference errors spread around the run's threshold, one sample with nothing fitted
    spread = [0.001, 0.01, 0.019, 0.03, 0.2, float("nan")][: len(errors)]
    errors = errors.assign(valid=True, mssd_over_diameter=spread)
    errors.to_csv(kept / "errors.csv.gz", index=False)
    against = [sys.executable, script, "against", kept / "errors.csv.gz", splitting_run]
    r = subprocess.run(list(map(str, against)), check=True, capture_output=True, text=True)
    # the level table's rows, named by the run's folder ("run"), not its header
    cells = [line.split(" | ") for line in r.stdout.splitlines()]
    rows = [c for c in cells if c[0] == "| run" and c[1].isdigit()]
    levels = json.loads((splitting_run / "summary.json").read_text())["splitting"]["levels"]
    assert len(rows) == len(levels), r.stdout
    score = np.log10(errors.mssd_over_diameter / 0.02).fillna(np.inf)
    running = 1.0
    for row, level in zip(rows, levels, strict=True):
        running *= level["conditional_probability"]
        above = int((score > level["threshold"]).sum())
        assert int(row[4]) == above, (level, r.stdout)
        assert float(row[3]) == pytest.approx(running, rel=1e-2), r.stdout
    # the last level is the failure level: above it are the failures, the sample with nothing
    # fitted among them
    assert levels[-1]["threshold"] == 0.0 and int(rows[-1][4]) == 3, r.stdout


@pytest.mark.parametrize(
    "args, said",
    [
        (["--samples", 12], "--splitting-level-probability: 12 particles × 0.2 = 2.4"),
        (["--splitting-max-levels", 0], "--splitting-max-levels"),
    ],
)
def test_a_bad_splitting_setting_names_its_flag(args, said, spaces, boxpose_bin, tmp_path):
    base = [str(a) for a in SPLITTING]
    for flag, value in zip(args[::2], args[1::2], strict=True):
        base[base.index(flag) + 1] = str(value)
    out = tmp_path / "run"
    r = search(boxpose_bin, spaces["single"], "--out", out, *base, check=False)
    assert r.returncode != 0 and said in r.stderr, r.stderr
    assert not out.exists()


def test_subset_simulation_refuses_a_stratified_space(spaces, boxpose_bin, tmp_path):
    r = search(boxpose_bin, spaces["clutter"], "--out", tmp_path / "run", *SPLITTING, check=False)
    assert r.returncode != 0 and "draws from one stratum" in r.stderr, r.stderr


def test_cross_entropy_tilts_only_the_named_parameters(spaces, boxpose_bin, tmp_path):
    out = tmp_path / "tilt"
    search(
        boxpose_bin,
        spaces["single"],
        "--out",
        out,
        "--sampler",
        "ce",
        "--samples",
        2,
        "--batch-size",
        4,
        "--ce-samples-per-iteration",
        4,
        "--ce-max-iterations",
        1,
        "--ce-rho",
        0.5,
        "--ce-tilt",
        "target.size_m",
        "--fail-when",
        "mssd:0.02",
        "--threads",
        1,
    )
    names = json.loads((out / "run.json").read_text())["dimensions"]
    plan = json.loads((out / "proposals" / "iter-0001.json").read_text())
    for component in plan["proposal"]["components"]:
        for name, mean, std in zip(names, component["mean"], component["std"], strict=True):
            if not name.startswith("target.size_m"):
                assert (mean, std) == (0.0, 1.0), name
    final = pd.read_parquet(out / "samples.parquet").query("stage == 'final'")
    # the weight depends on the tilted dimensions only
    assert len(final) == 2 and final.log_weight.abs().max() > 0


def test_an_unknown_tilt_is_refused_before_any_work(spaces, boxpose_bin, tmp_path):
    out = tmp_path / "run"
    r = search(
        boxpose_bin,
        spaces["single"],
        "--out",
        out,
        "--sampler",
        "ce",
        "--ce-tilt",
        "target.colour",
        check=False,
    )
    assert r.returncode != 0 and "target.colour" in r.stderr and "target.size_m.x" in r.stderr, (
        r.stderr
    )
    assert not out.exists()


def test_cross_entropy_on_clutter_pools_its_strata(spaces, boxpose_bin, tmp_path):
    out = tmp_path / "clutter-ce"
    r = search(
        boxpose_bin,
        spaces["clutter"],
        "--out",
        out,
        "--sampler",
        "ce",
        "--samples",
        4,
        "--batch-size",
        4,
        "--ce-samples-per-iteration",
        4,
        "--ce-max-iterations",
        1,
        "--ce-rho",
        0.5,
        "--fail-when",
        "mssd:0.02",
        "--threads",
        1,
    )
    samples = pd.read_parquet(out / "samples.parquet")
    final = samples[samples.stage == "final"]
    # both strata in every stage, each with its nominal share, and never tilted: the neighbour
    # count is not part of z, so it never enters the weights
    assert sorted(final.stratum) == [1, 1, 2, 2] and sorted(
        samples[samples.stage == "tune"].stratum
    ) == [1, 1, 2, 2]
    summary = json.loads((out / "summary.json").read_text())
    assert [s["neighbours"] for s in summary["strata"]] == [1, 2] and summary["estimate"][
        "samples"
    ] == 4
    # P(valid) is a probability (the weights' mean was stored, above 1 when they averaged so),
    # and each stratum is one flat entry (no Rust `Ok` wrapper, no nested stratum 0)
    e = summary["estimate"]
    assert 0.0 <= e["p_valid"] <= 1.0
    if e["valid"] == e["samples"]:
        assert e["p_valid"] == 1.0
    assert '"Ok"' not in (out / "summary.json").read_text() and "strata" not in e
    for stratum, neighbours in zip(summary["strata"], [1, 2], strict=True):
        assert stratum["neighbours"] == neighbours and stratum["samples"] == 2
        assert stratum["nominal_probability"] == 0.5
    # each stratum's own estimate is printed and in the report
    for neighbours in (1, 2):
        assert f"  {neighbours} neighbours: " in r.stdout, r.stdout
    report = (out / "report" / "index.html").read_text()
    assert "<h2>Strata</h2>" in report and report.count("<tr><td>") >= 3


def test_merge_redraws_the_report_and_lists_only_what_the_run_holds(mc_run, boxpose_bin, tmp_path):
    copy = tmp_path / "copied-run"
    shutil.copytree(mc_run, copy)
    # a run without failures has no counterexamples/ (removed here to make one)
    shutil.rmtree(copy / "counterexamples", ignore_errors=True)
    shutil.rmtree(copy / "report")
    r = search(boxpose_bin, "merge", copy)
    assert (copy / "report" / "index.html").is_file()
    assert str(copy) in (copy / "report" / "index.html").read_text()
    (line,) = [line for line in r.stdout.splitlines() if line.startswith("run: ")]
    assert "counterexamples/" not in line and "report/index.html" in line, line
    # Monte Carlo's samples carry no weights: no weight diagnostics are printed
    assert "P(fail | valid)" in r.stdout and "ESS" not in r.stdout, r.stdout


def test_a_sample_replays_to_its_recorded_outcome(mc_run, boxpose_bin, tmp_path):
    samples = pd.read_parquet(mc_run / "samples.parquet")
    failed = samples[samples.failed]
    row = (failed if not failed.empty else samples[samples.valid]).iloc[0]
    r = search(
        boxpose_bin,
        "replay",
        mc_run,
        "--sample",
        int(row.sample_id),
        "--out",
        tmp_path,
        "--threads",
        1,
    )
    assert "reproduced" in r.stdout, r.stdout
    recorded, replayed = [
        line for line in r.stdout.splitlines() if line.strip().startswith(("recorded", "replayed"))
    ]
    assert recorded.split(maxsplit=1)[1] == replayed.split(maxsplit=1)[1]
    if row.score == row.score:  # scored: the printed score is the stored one
        assert f"score {row.score:.4f}" in recorded
    assert (tmp_path / f"sample-{int(row.sample_id)}.png").is_file()
    missing = search(boxpose_bin, "replay", mc_run, "--sample", 999, "--out", tmp_path, check=False)
    assert missing.returncode != 0 and "no sample 999" in missing.stderr


def test_ground_truth_crops_render_a_region_unless_whole_frames_are_asked_for(
    spaces, boxpose_bin, tmp_path
):
    widths = {}
    for name, extra in (("region", []), ("whole", ["--whole-frames"])):
        out = tmp_path / name
        # a threshold nothing meets: every sample fails, so every frame is kept as a counterexample
        search(
            boxpose_bin,
            spaces["single"],
            "--out",
            out,
            "--samples",
            2,
            "--batch-size",
            2,
            "--fail-when",
            "mssd:0.000001",
            "--threads",
            1,
            *extra,
        )
        frames = pd.read_parquet(out / "counterexamples" / "frames")
        widths[name] = set(frames.width) | set(frames.height)
    assert widths["whole"] == {96} and max(widths["region"]) < 96, widths


def test_segmenter_crops_render_the_frame_at_the_segmenters_width_and_the_target_at_full_size(
    spaces, boxpose_bin, tmp_path
):
    """A frame wider than the segmenter's input (384×288 against the shipped segmenter's 320):
    the segmenter reads a whole frame rendered 320 wide; for a box it finds, the keypoint
    network's window around the detection is then rendered at full resolution, a box it misses
    ends the sample on the small frame. --whole-frames renders the whole frame at full size once,
    and the two runs pair sample by sample."""
    text = recipe("single_box").replace("width = 96", "width = 384")
    text = text.replace("height = 96", "height = 288")
    (tmp_path / "wide.toml").write_text(text)
    space = tmp_path / "space.toml"
    space.write_text(SPACE.format(recipe=tmp_path / "wide.toml"))
    runs = {}
    for name, extra in (("two", []), ("whole", ["--whole-frames"])):
        runs[name] = tmp_path / name
        # a threshold nothing meets: every scored sample fails and keeps its frame
        search(
            boxpose_bin, space, "--out", runs[name], "--crops", "predicted", "--samples", 4,
            "--batch-size", 4, "--fail-when", "mssd:0.000001", "--threads", 1, *extra,
        )  # fmt: skip
    samples = pd.read_parquet(runs["two"] / "samples.parquet").set_index("sample_id")
    frames = pd.read_parquet(runs["two"] / "counterexamples" / "frames")
    assert len(frames) == samples.valid.sum() > 0
    whole = pd.read_parquet(runs["whole"] / "counterexamples" / "frames")
    assert ((whole.width == 384) & (whole.height == 288)).all()
    # each scene's frame against the same camera rendered whole at full size
    both = frames.merge(whole, on="scene_id", suffixes=("", "_whole"))
    both["detected"] = samples.loc[both.scene_id, "detected"].to_numpy()
    assert len(both) > 0
    missed, found = both[both.detected == False], both[both.detected == True]  # noqa: E712
    # a missed box: the small frame, focal length × 320/384
    assert ((missed.width == 320) & (missed.height == 240)).all(), missed
    assert np.allclose(missed.fx, missed.fx_whole * 320 / 384)
    # a found box: full resolution, the window's region (the whole frame were it to fall short)
    assert len(found) > 0, "the shipped segmenter found no box in 4 samples"
    assert np.allclose(found.fx, found.fx_whole) and (found.width < 384).any(), found
    record = json.loads((runs["two"] / "run.json").read_text())["settings"]
    assert record["two_resolutions"] and not record["whole_frames"]
    assert "at its input width" in (runs["two"] / "report" / "index.html").read_text()
    search(boxpose_bin, "compare", runs["whole"], runs["two"], "--json", tmp_path / "c")
    assert json.loads((tmp_path / "c").read_text())["pairs"] == len(both)


def test_fine_tuning_on_variants_of_the_counterexamples(failing_run, spaces, boxpose_bin, tmp_path):
    """The learning loop at tiny settings: scenes around each counterexample, the run's network
    fine-tuned on them mixed with the counterexamples themselves, and a fresh-seed search with
    the fine-tuned network. (The figures of 2 steps mean nothing; the plumbing is tested.)"""
    variants = tmp_path / "variants"
    args = ["variants", failing_run, "--out", variants, "--per-failure", 2, "--threads", 1]
    r = search(boxpose_bin, *args)
    scenes = pd.read_parquet(variants / "scenes")
    frames = pd.read_parquet(variants / "frames")
    assert 1 <= len(scenes) <= 4 and sorted(frames.scene_id) == sorted(scenes.scene_id)
    # whole frames at the recipe's size, not the run's target regions
    assert (frames.width == 96).all() and (frames.height == 96).all()
    assert "fine-tune: boxpose train --init" in r.stdout
    assert run_boxpose(boxpose_bin, "inspect", variants).returncode == 0
    # written by the Rust writer, read back with pyarrow alone against the contract
    read = boxpose_io.read_dataset(variants)
    assert read["frames"].num_rows == len(frames) and read["scenes"].num_rows == len(scenes)
    inside = search(boxpose_bin, "variants", failing_run, "--out", failing_run / "v", check=False)
    assert inside.returncode == 1 and "inside the run folder" in inside.stderr
    # one shard per failure: a second command finds them done and rewrites nothing
    shard = next((variants / "frames").glob("*.parquet"))
    written = shard.stat().st_mtime_ns
    search(boxpose_bin, *args)
    assert shard.stat().st_mtime_ns == written

    def train(out, *init):
        return run_boxpose(
            boxpose_bin,
            "train",
            "--config",
            REPO / "configs" / "keypoint-slim.toml",
            "--dataset",
            failing_run / "counterexamples",
            "--dataset",
            variants,
            "--steps",
            2,
            "--batch-size",
            2,
            "--validate-every",
            2,
            "--out",
            out,
            *init,
        )

    train(tmp_path / "tuned", "--init", REPO / "models" / "keypoint-slim")
    train(tmp_path / "scratch")
    tuned = pd.read_csv(tmp_path / "tuned" / "history.csv").iloc[-1]
    scratch = pd.read_csv(tmp_path / "scratch" / "history.csv").iloc[-1]
    # the shipped weights already fit these crops far better than random ones
    assert tuned.train_loss < scratch.train_loss / 3, (tuned.train_loss, scratch.train_loss)

    after = tmp_path / "after"
    search(
        boxpose_bin, spaces["single"], "--out", after, "--model", tmp_path / "tuned" / "model",
        "--samples", 2, "--batch-size", 2, "--seed", 11, "--fail-when", "mssd:0.000001",
        "--threads", 1,
    )  # fmt: skip
    summary = json.loads((after / "summary.json").read_text())
    assert summary["samples_spent"] == 2


@pytest.fixture(scope="module")
def tiny_network(failing_run, boxpose_bin, tmp_path_factory) -> Path:
    """A one-step tiny keypoint network (its model folder): another network to compare with."""
    tiny = tmp_path_factory.mktemp("tiny") / "run"
    trained = run_boxpose(
        boxpose_bin, "train", "--config", REPO / "configs" / "tiny.toml",
        "--dataset", failing_run / "counterexamples", "--steps", 1, "--batch-size", 1,
        "--validate-every", 1, "--out", tiny,
    )  # fmt: skip
    assert trained.returncode == 0, trained.stderr
    return tiny / "model"


def test_two_runs_on_the_same_inputs_compare_pair_by_pair(
    mc_run, failing_run, tiny_network, spaces, boxpose_bin, tmp_path
):
    """`search compare`: the shipped network against a one-step tiny network on the same six
    scenes (same space, seed and settings), paired sample by sample, McNemar's exact p-value
    recomputed here from the two samples tables."""
    after = tmp_path / "after"
    # a shorter run (4 of the 6 samples, other batches) pairs over the sample ids both drew
    shorter = [*MC]
    shorter[1], shorter[3] = 4, 4
    search(boxpose_bin, spaces["single"], "--out", after, "--fail-when", "mssd:0.05",
           "--model", tiny_network, *shorter)  # fmt: skip
    r = search(boxpose_bin, "compare", mc_run, after, "--json", tmp_path / "compare.json")
    c = json.loads((tmp_path / "compare.json").read_text())
    all_before = pd.read_parquet(mc_run / "samples.parquet").set_index("sample_id")
    a = pd.read_parquet(after / "samples.parquet").set_index("sample_id")
    assert list(a.index) == [0, 1, 2, 3]
    b = all_before.loc[a.index]
    paired = b.valid & a.valid
    assert c["pairs"] == paired.sum() > 0
    assert c["unpaired"] == all_before.valid.sum() + a.valid.sum() - 2 * paired.sum()
    assert c["fixed"] == list(b.index[paired & b.failed & ~a.failed])
    assert c["new"] == list(b.index[paired & ~b.failed & a.failed])
    assert c["before"]["failures"] == (paired & b.failed).sum()
    assert c["after"]["failures"] == (paired & a.failed).sum()
    fixed, new = len(c["fixed"]), len(c["new"])
    tail = sum(math.comb(fixed + new, i) for i in range(min(fixed, new) + 1)) / 2 ** (fixed + new)
    assert c["mcnemar_p"] == pytest.approx(min(1.0, 2 * tail), abs=1e-12)
    assert f"fixed {fixed} (failed before only), new {new}" in r.stdout
    # a run against itself: nothing discordant
    same = search(boxpose_bin, "compare", mc_run, mc_run)
    assert "fixed 0 (failed before only), new 0" in same.stdout and "p = 1.000e0" in same.stdout
    # runs that drew other scenes cannot be paired, and the refusal names what differs
    other = search(boxpose_bin, "compare", mc_run, failing_run, check=False)
    assert other.returncode == 1 and "cannot be paired" in other.stderr
    assert "--seed is 3 there, 0 here" in other.stderr and "--fail-when" in other.stderr
    assert "--samples" not in other.stderr.split("cannot be paired")[1].split(");")[0]


def test_independent_runs_agree_or_are_named_when_their_intervals_do_not_overlap(
    mc_run, failing_run, spaces, boxpose_bin, tmp_path
):
    """`search agree`: a second Monte Carlo run of the same search with another seed agrees (its
    interval overlaps); a run whose interval lies apart is named with the error; the same seed
    twice is flagged as no independent evidence; another event is refused."""
    other = tmp_path / "seed4"
    reseeded = [*MC]
    reseeded[reseeded.index("--seed") + 1] = 4
    search(boxpose_bin, spaces["single"], "--out", other, "--fail-when", "mssd:0.05", *reseeded)
    r = search(boxpose_bin, "agree", mc_run, other, "--json", tmp_path / "agree.json")
    assert "the 2 runs agree" in r.stdout
    a = json.loads((tmp_path / "agree.json").read_text())
    for estimate, run in zip(a["estimates"], (mc_run, other), strict=True):
        summary = json.loads((run / "summary.json").read_text())["estimate"]
        assert estimate["p_hat"] == summary["p_hat"] and estimate["ci95"] == summary["ci95"]
    assert a["disjoint"] == [] and a["same_seed"] == []

    # a run whose interval lies above the other's (as a sampler that found a mode the other
    # never drew would report): the two are named, exit status 1
    apart = tmp_path / "apart"
    shutil.copytree(other, apart)
    summary = json.loads((apart / "summary.json").read_text())
    upper = json.loads((mc_run / "summary.json").read_text())["estimate"]["ci95"][1]
    assert upper < 0.999
    summary["estimate"].update(p_hat=0.9995, ci95=[0.999, 1.0])
    (apart / "summary.json").write_text(json.dumps(summary))
    r = search(boxpose_bin, "agree", mc_run, other, apart, check=False)
    assert r.returncode == 1 and "the runs disagree" in r.stderr
    assert f"{mc_run} and {apart}" in r.stderr and f"{other} and {apart}" in r.stderr
    assert f"{mc_run} and {other}" not in r.stderr

    # one run twice: the same samples
    r = search(boxpose_bin, "agree", mc_run, mc_run)
    assert "same sampler and seed" in r.stdout
    # another predicate is another event
    r = search(boxpose_bin, "agree", mc_run, failing_run, check=False)
    assert r.returncode == 1 and "another event" in r.stderr


def test_improve_runs_its_rounds_resumes_after_a_kill_and_refuses_other_settings(
    tiny_network, failing_run, spaces, boxpose_bin, tmp_path
):
    """`boxpose improve --control` at tiny settings: two rounds of search, variants, fine-tuning
    and paired evaluation beside the equal-budget control arm, killed once a round's network
    exists and resumed by the same command, which redoes no finished step. (A one-step tiny
    network and a threshold nothing meets make every sample fail: the plumbing is tested, not the
    gain.)"""
    out = tmp_path / "loop"
    command = [
        str(boxpose_bin), "improve", str(spaces["single"]), "--out", str(out),
        "--model", str(tiny_network), "--config", str(REPO / "configs" / "tiny.toml"),
        "--rounds", "2", "--search-samples", "2", "--eval-samples", "2", "--batch-size", "2",
        "--per-failure", "1", "--steps", "1", "--batch-size-train", "1",
        "--fail-when", "mssd:0.000001", "--threads", "1", "--learnt-repeat", "2",
        "--held-out-dataset", str(failing_run / "counterexamples"), "--held-out", "2", "--control",
    ]  # fmt: skip
    loop = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first_network = out / "round-00" / "train" / "model" / "network.toml"
    deadline = time.monotonic() + 600
    while not first_network.exists() and loop.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    loop.send_signal(signal.SIGTERM)
    _, stderr = loop.communicate(timeout=120)
    assert first_network.exists(), stderr.decode()
    assert loop.returncode != 0 and not (out / "rounds.csv").exists()
    first_search = out / "round-00" / "search" / "samples.parquet"
    searched = first_search.stat().st_mtime_ns
    time.sleep(1)  # the steps left running with the loop were stopped with it
    assert not any(p.name.endswith(".tmp") for p in out.rglob("*.json"))

    r = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert first_search.stat().st_mtime_ns == searched
    rounds = pd.read_csv(out / "rounds.csv")
    assert list(rounds["round"]) == [0, 1]
    assert (rounds.search_failures > 0).all() and rounds.fine_tuned.all()
    for network in range(3):
        assert (out / "eval" / f"model-{network}" / "summary.json").is_file()
    assert (out / "round-01" / "train" / "model" / "network.toml").is_file()
    # round 1 learns from both rounds' counterexamples and variants, each twice per epoch
    trained = tomllib.loads((out / "round-01" / "train" / "config.toml").read_text())
    assert trained["data"]["repeat"] == [2, 2, 2, 2], trained["data"]
    for row in rounds.itertuples():
        c = json.loads((out / f"round-{row.round:02d}" / "compare.json").read_text())
        assert (c["pairs"], len(c["fixed"]), len(c["new"])) == (row.pairs, row.fixed, row.new)
        # the evaluation inputs are common: network k's run is both rounds' "before"/"after"
        before = pd.read_parquet(out / "eval" / f"model-{row.round}" / "samples.parquet")
        after = pd.read_parquet(out / "eval" / f"model-{row.round + 1}" / "samples.parquet")
        assert (before.seed.to_numpy() == after.seed.to_numpy()).all()
        # and the held-out nominal boxes, paired box by box between the same two networks
        held = json.loads((out / f"round-{row.round:02d}" / "held-out-compare.json").read_text())
        c = held["counterexamples"]
        boxes = pd.read_parquet(
            out / "eval" / f"model-{row.round}" / "held-out" / "counterexamples" / "eval.parquet"
        )
        assert c["pairs"] == len(boxes[boxes.method == "paper_exact"]) > 0
        assert c["before"]["failures"] - len(c["fixed"]) + len(c["new"]) == c["after"]["failures"]
    assert "McNemar p" in r.stdout and "held-out" in r.stdout
    # the rounds page: one row per round with its rates, each network's evaluation report linked
    page = (out / "report.html").read_text()
    assert page.count("<tr><td>") == len(rounds) and "counterexamples: " in page
    for network in range(3):
        link = f"eval/model-{network}/report/index.html"
        assert link in page and (out / link).is_file()
    for row in rounds.itertuples():
        assert f"({row.failures_after} of {row.pairs})" in page

    # the control: in each round as many nominal samples as the loop drew (2 searched, 1 variant
    # per failure), every one kept, learnt from by the control's own networks with the original
    # data's mix, and its networks paired with the loop's on the same evaluation inputs
    assert "equal-budget control" in page and "against the equal-budget control" in r.stdout
    for row in rounds.itertuples():
        control = out / f"round-{row.round:02d}" / "control"
        drew = pd.read_parquet(control / "nominal" / "samples.parquet")
        assert len(drew) == 2 + row.search_failures
        assert drew.failed.sum() == drew.valid.sum()
        learnt = tomllib.loads((control / "train" / "config.toml").read_text())["data"]["datasets"]
        nominal = [str(out / f"round-{k:02d}" / "control" / "nominal" / "counterexamples")
                   for k in range(row.round + 1)]  # fmt: skip
        assert [d for d in learnt if "round-" in d] == nominal, learnt
        c = json.loads((out / f"round-{row.round:02d}" / "control-compare.json").read_text())
        assert (c["pairs"], c["before"]["failures"]) == (row.control_pairs, row.control_failures)
        against = (row.fixed_against_control, row.new_against_control)
        assert (len(c["fixed"]), len(c["new"])) == against
        control_run = pd.read_parquet(out / "eval" / f"control-{row.round + 1}" / "samples.parquet")
        loop_run = pd.read_parquet(out / "eval" / f"model-{row.round + 1}" / "samples.parquet")
        assert (control_run.seed.to_numpy() == loop_run.seed.to_numpy()).all()
        assert (out / f"round-{row.round:02d}" / "control-held-out-compare.json").is_file()

    changed = list(command)
    changed[changed.index("--steps") + 1] = "2"
    other = subprocess.run(changed, cwd=REPO, capture_output=True, text=True)
    assert other.returncode == 1 and "--steps is 1 there, 2 here" in other.stderr


def test_improve_fine_tunes_the_segmenter_beside_the_keypoint_network(
    tiny_network, failing_run, spaces, boxpose_bin, tmp_path
):
    """With --segmenter-config a round that learns fine-tunes the segmenter too, from the one the
    round searched with, on the same failing scenes and variants, and the next evaluation crops
    with the new segmenter. (A one-step tiny segmenter finds no box, so every sample fails.)"""
    tiny_segmenter = tmp_path / "segmenter"
    run_boxpose(
        boxpose_bin, "train-segmenter", "--config", REPO / "configs" / "segmenter-tiny.toml",
        "--dataset", failing_run / "counterexamples", "--steps", 1, "--validate-every", 1,
        "--out", tiny_segmenter,
    )  # fmt: skip
    out = tmp_path / "loop"
    command = [
        str(boxpose_bin), "improve", str(spaces["single"]), "--out", str(out),
        "--model", str(tiny_network), "--config", str(REPO / "configs" / "tiny.toml"),
        "--segmenter", str(tiny_segmenter / "model"), "--crops", "predicted",
        "--segmenter-config", str(REPO / "configs" / "segmenter-tiny.toml"),
        "--segmenter-steps", "1", "--rounds", "1", "--search-samples", "2", "--eval-samples", "2",
        "--batch-size", "2", "--per-failure", "1", "--steps", "1", "--batch-size-train", "1",
        "--threads", "1",
    ]  # fmt: skip
    r = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    round_dir = out / "round-00"
    tuned = round_dir / "train-segmenter"
    assert (tuned / "model" / "segmenter.toml").is_file()
    assert f"--init {tiny_segmenter / 'model'}" in r.stdout
    # the segmenter learnt from the round's failing scenes and their variants
    data = tomllib.loads((tuned / "config.toml").read_text())["data"]["datasets"]
    assert str(round_dir / "search" / "counterexamples") in data
    assert str(round_dir / "variants") in data
    # the first network's evaluation cropped with the old segmenter, the second's with the new
    segmenters = [
        json.loads((out / "eval" / f"model-{k}" / "run.json").read_text())["settings"]["segmenter"]
        for k in (0, 1)
    ]
    assert segmenters == [str(tiny_segmenter / "model"), str(tuned / "model")]
    settings = json.loads((out / "improve.json").read_text())
    assert settings["segmenter_steps"] == 1
    assert "both fine-tuned" in (out / "report.html").read_text()

    # the segmenter only crops with --crops predicted: tuning it on ground-truth crops is refused
    gt = [*command]
    gt[gt.index("predicted")] = "gt"
    gt[gt.index(str(out))] = str(tmp_path / "gt")
    r = subprocess.run(gt, cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 1 and "needs --crops predicted" in r.stderr
    assert not (tmp_path / "gt").exists()


def test_fine_tuning_from_another_network_is_one_clear_error(failing_run, boxpose_bin, tmp_path):
    r = run_boxpose(
        boxpose_bin,
        "train",
        "--config",
        REPO / "configs" / "tiny.toml",
        "--dataset",
        failing_run / "counterexamples",
        "--init",
        REPO / "models" / "keypoint-slim",
        "--out",
        tmp_path / "run",
        check=False,
    )
    assert r.returncode == 1 and "fine-tuning needs the same network settings" in r.stderr


def test_fine_tuning_may_retarget_sigma_and_the_peak_window(failing_run, boxpose_bin, tmp_path):
    """The target width and the decoding window do not shape the weights, so a fine-tuning run
    may change them; the tuned model's network.toml records the run's choice."""
    config = (REPO / "configs" / "keypoint-slim.toml").read_text()
    config = config.replace("sigma_voxels = 1.5", "sigma_voxels = 1.0\npeak_refine_radius = 1")
    assert "peak_refine_radius = 1" in config
    (tmp_path / "retargeted.toml").write_text(config)
    run_boxpose(
        boxpose_bin, "train", "--config", tmp_path / "retargeted.toml",
        "--dataset", failing_run / "counterexamples", "--steps", 1, "--batch-size", 2,
        "--validate-every", 1, "--init", REPO / "models" / "keypoint-slim",
        "--out", tmp_path / "run",
    )  # fmt: skip
    network = tomllib.loads((tmp_path / "run" / "model" / "network.toml").read_text())
    assert (network["sigma_voxels"], network["peak_refine_radius"]) == (1.0, 1)


def _small_target(space: str, xy: str) -> str:
    """The test space with a small target over `xy` (a TOML range for both x and y)."""
    return (
        space.replace(
            "size_m = { x = [0.10, 0.20], y = [0.08, 0.16], z = [0.06, 0.12] }",
            "size_m = { x = [0.06, 0.08], y = [0.06, 0.08], z = [0.05, 0.06] }",
        )
        .replace("x_m = [-0.05, 0.05]", f"x_m = {xy}")
        .replace("y_m = [-0.05, 0.05]", f"y_m = {xy}")
    )


def test_a_pile_space_drops_the_target_onto_a_stored_pile_and_leaves_what_it_misses(
    spaces, boxpose_bin, tmp_path
):
    # the pile: a clutter sample (its target in the middle, one neighbour in a far corner),
    # kept whole because every scored sample fails at MSSD > 1e-9·d
    source = tmp_path / "source.toml"
    source.write_text(
        _small_target(spaces["clutter"].read_text(), "[-0.02, 0.02]")
        .replace("count = [1, 2]", "count = [1, 1]")
        .replace("x_m = [-0.2, 0.2]", "x_m = [-0.3, -0.25]")
        .replace("y_m = [-0.2, 0.2]", "y_m = [-0.3, -0.25]")
    )
    pile_run = tmp_path / "pile-source"
    search(boxpose_bin, source, "--out", pile_run, "--samples", 2, "--batch-size", 2,
           "--threads", 1, "--fail-when", "mssd:1e-9")  # fmt: skip
    piles = pile_run / "counterexamples"
    scenes = pd.read_parquet(piles / "scenes")
    pile_id = int(scenes[scenes.stable].scene_id.iloc[0])
    stored = pd.read_parquet(piles / "objects")
    stored = stored[stored.scene_id == pile_id].sort_values("object_id")

    # the new target falls into the opposite corner, well clear of the pile's old target
    space = tmp_path / "pile.toml"
    space.write_text(
        _small_target(SPACE, "[0.28, 0.3]").format(recipe=spaces["clutter"].parent / "bin.toml")
        + f'\n[pile]\ndataset = "{piles}"\nscene_id = {pile_id}\n'
    )
    out = tmp_path / "onto-pile"
    search(boxpose_bin, space, "--out", out, "--samples", 3, "--batch-size", 3, "--threads", 1,
           "--fail-when", "mssd:1e-9")  # fmt: skip
    record = json.loads((out / "run.json").read_text())
    assert [b["size_m"] for b in record["pile"]] == [list(s) for s in stored["size_m"]]
    assert record["strata"] == [0]
    samples = pd.read_parquet(out / "samples.parquet")
    assert samples.valid.any(), samples[["valid", "invalid_reason"]]
    objects = pd.read_parquet(out / "counterexamples" / "objects")
    new_scenes = pd.read_parquet(out / "counterexamples" / "scenes")
    assert set(new_scenes.solver_status) == {"dropped onto a settled pile"}
    assert set(new_scenes.scene_id) == set(samples[samples.valid].sample_id)
    for scene_id, rows in objects.groupby("scene_id"):
        rows = rows.sort_values("object_id")
        assert len(rows) == 1 + len(stored)
        target, pile = rows.iloc[0], rows.iloc[1:]
        # the target fell (it starts above the pile) and rests on the bin's floor
        assert target.world_box_translation_m[2] < target.initial_world_box_translation_m[2]
        # the pile's boxes start where the pile left them; those the drop does not reach (its
        # old target, in the opposite corner) are still there to the bit
        for column in ("initial_world_box_translation_m", "initial_world_box_quat_wxyz"):
            assert [list(v) for v in pile[column]] == [
                list(v) for v in stored[column.replace("initial_", "")]
            ]
        old_target = pile.iloc[0]
        assert list(old_target.world_box_translation_m) == list(
            stored.iloc[0].world_box_translation_m
        ), scene_id
        assert list(old_target.world_box_quat_wxyz) == list(stored.iloc[0].world_box_quat_wxyz)


def test_a_pile_space_refuses_a_missing_pile_and_neighbours_beside_it(
    spaces, boxpose_bin, tmp_path
):
    base = SPACE.format(recipe=spaces["clutter"].parent / "bin.toml")
    for text, words in [
        (base + f'\n[pile]\ndataset = "{tmp_path}/none"\nscene_id = 0\n', "none"),
        (base + NEIGHBOURS + f'\n[pile]\ndataset = "{tmp_path}"\nscene_id = 0\n', "not both"),
    ]:
        space = tmp_path / "bad-pile.toml"
        space.write_text(text)
        r = search(boxpose_bin, space, "--out", tmp_path / "run", check=False)
        assert r.returncode != 0 and words in r.stderr, r.stderr
        assert not (tmp_path / "run").exists()


SHIFT_SPACES = sorted((REPO / "configs" / "search").glob("shift_*.toml"))


@pytest.mark.parametrize("space", SHIFT_SPACES, ids=lambda p: p.stem)
def test_a_shift_space_draws_inside_its_shifted_ranges(space, boxpose_bin, tmp_path):
    """Each shipped shift space runs end to end (on a tiny render of its own base recipe), every
    parameter it draws lies in the range it declares, and the fit's cube-group error never
    exceeds its exact-symmetry MSSD (the paper's fit knows the box's size)."""
    declared = tomllib.loads(space.read_text())
    base = declared["recipe"]
    tiny_recipe = tmp_path / f"{base}.toml"
    tiny_recipe.write_text(recipe(base))
    tiny_space = tmp_path / space.name
    tiny_space.write_text(
        space.read_text().replace(f'recipe = "{base}"', f'recipe = "{tiny_recipe}"', 1)
    )
    out = tmp_path / "run"
    search(boxpose_bin, tiny_space, "--out", out, "--samples", 3, "--batch-size", 3, "--threads", 1)
    dimensions = json.loads((out / "run.json").read_text())["dimensions"]
    samples = pd.read_parquet(out / "samples.parquet")
    assert len(samples) == 3

    def bounds(name: str) -> tuple[float, float]:
        section, key, *axis = name.split(".")
        value = declared[section][key]
        value = value[axis[0]] if axis else value
        return tuple(value["within"] if isinstance(value, dict) else value)

    for params in samples.params:
        for name, value in zip(dimensions, params, strict=True):
            if name.split(".")[0] in ("target", "camera", "lighting") and "orientation" not in name:
                low, high = bounds(name)
                assert low <= value <= high, (name, value, (low, high))
    fitted = samples.dropna(subset=["cube_mssd_over_diameter", "mssd_over_diameter"])
    assert (fitted.cube_mssd_over_diameter <= fitted.mssd_over_diameter + 1e-12).all()


def test_a_run_without_a_terminal_still_reports_its_progress(spaces, boxpose_bin, tmp_path):
    """Where the progress bar cannot be drawn (stderr a pipe or a log file), a plain line reports
    the samples done, the failures and the estimate so far — at least at each iteration's end."""
    r = search(
        boxpose_bin, spaces["single"], "--out", tmp_path / "run", "--samples", 2, "--batch-size", 2
    )
    line = next(x for x in r.stderr.splitlines() if x.startswith("mc 0: 2/2 samples"))
    assert "failures" in line and "p̂" in line and "ETA" in line


def test_an_unknown_space_or_recipe_name_lists_the_known_ones(spaces, boxpose_bin, tmp_path):
    r = search(boxpose_bin, "no_such_space", "--out", tmp_path / "a", check=False)
    assert r.returncode != 0 and "the known search spaces in configs/search: " in r.stderr
    assert "single_box" in r.stderr and "clutter" in r.stderr, r.stderr
    space = tmp_path / "space.toml"
    space.write_text(
        spaces["single"]
        .read_text()
        .replace(
            f'recipe = "{spaces["single"].with_name("floor.toml")}"', 'recipe = "no_such_recipe"'
        )
    )
    r = search(boxpose_bin, space, "--out", tmp_path / "b", check=False)
    assert r.returncode != 0 and "the known recipes in datasets/recipes: " in r.stderr, r.stderr
    assert "single_box" in r.stderr and not (tmp_path / "b").exists()
