"""Re-rendering from Rust (`boxpose render`, embedded Blender through pyo3) against the rows the
Python worker wrote: identical ground truth, the same image within noise, crops, clean errors."""

import io
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import bpy  # noqa: F401  (installed by `make setup`: a missing bpy fails, never skips)
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from conftest import render_synthetic_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Two scenes, two 96×72 views each, rendered by the Python worker."""
    return render_synthetic_dataset(tmp_path_factory.mktemp("rust") / "ds", 96, 72)


def boxpose(boxpose_bin: Path, *args, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(boxpose_bin), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
    )


def rgb(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png))).astype(int)


def test_rust_rerender_reproduces_the_dataset(dataset, boxpose_bin, tmp_path):
    out = tmp_path / "out"
    r = boxpose(
        boxpose_bin, "render", dataset, "--scene", 1, "--frame", 0, "--frame", 1, "--out", out
    )
    assert r.returncode == 0, r.stderr
    # Blender's noise (CUDA probe, leak report at exit) is filtered out
    assert "Not freed memory" not in r.stderr and "CUEW" not in r.stdout + r.stderr
    assert (out / "scene-000001-frame-001-rgb.png").is_file()

    want_f = (
        pd.read_parquet(dataset / "frames")
        .query("scene_id == 1")
        .sort_values("frame_id")
        .reset_index(drop=True)
    )
    got_f = pd.read_parquet(out / "frames").sort_values("frame_id").reset_index(drop=True)
    for col in (
        "width",
        "height",
        "fx",
        "fy",
        "cx",
        "cy",
        "render_seed",
        "samples",
        "denoise",
        "blender_version",
        "render_settings",
        "depth_m_f32le",
        "instance_mask_png",
    ):
        assert list(got_f[col]) == list(want_f[col]), col
    for col in ("world_camera_quat_wxyz", "world_camera_translation_m"):
        assert np.array_equal(np.stack(got_f[col]), np.stack(want_f[col])), col
    for a, b in zip(got_f.rgb_png, want_f.rgb_png, strict=True):
        assert np.abs(rgb(a) - rgb(b)).mean() < 2.0

    key = ["frame_id", "object_id"]
    want_i = (
        pd.read_parquet(dataset / "instances")
        .query("scene_id == 1")
        .sort_values(key)
        .reset_index(drop=True)
    )
    got_i = pd.read_parquet(out / "instances").sort_values(key).reset_index(drop=True)
    assert len(got_i) == len(want_i) == 2 * 3
    for col in want_i.columns:
        for a, b in zip(got_i[col], want_i[col], strict=True):
            if isinstance(b, np.ndarray) or b is None:
                assert (a is None and b is None) or np.array_equal(a, b), col
            else:
                assert a == b, col


def test_tape_along_long_from_the_dataset_stage_to_the_rust_render(boxpose_bin, tmp_path):
    """A recipe with materials.tape_along = "long", end to end at 48²: the dataset worker's label
    keypoints follow each box's longer top side, and `boxpose render` (the embedded Blender the
    search uses too, which knows the option from the scene's recipe_toml) re-renders the frame
    with the same look and ground truth."""
    from blender_scripts import sampling
    from test_render_blender import label_u_in_box, long_side_unit

    dataset = render_synthetic_dataset(tmp_path / "ds", 48, 48, tape_along="long")
    want = pd.read_parquet(dataset / "instances").query("scene_id == 1 and frame_id == 0")
    labelled = [row for _, row in want.iterrows() if row.label_keypoints_camera_m is not None]
    assert labelled, "no box of scene 1 drew a label: choose another seed"
    for row in labelled:
        assert np.allclose(label_u_in_box(row), long_side_unit(row.size_m))
    objects = pd.read_parquet(dataset / "objects").query("scene_id == 1 and has_label")
    assert any(
        sampling.draw_appearance(
            o.texture_seed, o.size_m, o.has_tape, True, tape_along="random"
        ).label.rotated
        != (o.size_m[1] > o.size_m[0])
        for o in objects.itertuples()
    ), '"random" draws every label along the longer side here: choose another seed'

    out = tmp_path / "out"
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 1, "--frame", 0, "--out", out)
    assert r.returncode == 0, r.stderr
    got = pd.read_parquet(out / "instances").sort_values("object_id")
    for a, b in zip(got.label_keypoints_camera_m, want.label_keypoints_camera_m, strict=True):
        assert (a is None and b is None) or np.array_equal(a, b)
    want_rgb = pd.read_parquet(dataset / "frames").query("scene_id == 1 and frame_id == 0")
    got_rgb = pd.read_parquet(out / "frames")
    assert np.abs(rgb(got_rgb.rgb_png.iloc[0]) - rgb(want_rgb.rgb_png.iloc[0])).mean() < 2.0


def test_rust_output_is_a_valid_dataset(dataset, boxpose_bin, tmp_path):
    out = tmp_path / "out"
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 0, "--out", out)
    assert r.returncode == 0, r.stderr
    r = boxpose(boxpose_bin, "inspect", out)
    assert r.returncode == 0, r.stderr.splitlines()[0]


def test_rust_render_leaves_no_blender_temp_folder(dataset, boxpose_bin, tmp_path):
    # Blender makes a blender_XXXXXX folder in TMPDIR at start-up; the embedded interpreter never
    # runs the Python exit handler that removes it, so the binary removes it at exit.
    temp = tmp_path / "tmp"
    temp.mkdir()
    r = boxpose(
        boxpose_bin,
        "render",
        dataset,
        "--scene",
        0,
        "--frame",
        0,
        "--samples",
        1,
        "--out",
        tmp_path / "out",
        env={"TMPDIR": str(temp)},
    )
    assert r.returncode == 0, r.stderr
    assert list(temp.iterdir()) == []


def test_rust_crop_and_samples(dataset, boxpose_bin, tmp_path):
    out = tmp_path / "crop"
    r = boxpose(
        boxpose_bin,
        "render",
        dataset,
        "--scene",
        0,
        "--crop",
        "10,8,74,56",
        "--samples",
        2,
        "--out",
        out,
    )
    assert r.returncode == 0, r.stderr
    f = pd.read_parquet(out / "frames").iloc[0]
    assert (f.width, f.height, f.samples) == (64, 48, 2)
    assert json.loads(f.render_settings)["crop"] == [10, 8, 74, 56]
    full = pd.read_parquet(dataset / "frames").query("scene_id == 0 and frame_id == 0").iloc[0]
    assert (f.cx, f.cy) == (full.cx - 10, full.cy - 8)
    mask = np.asarray(Image.open(out / "scene-000000-frame-000-mask.png"))
    full_mask = np.asarray(Image.open(io.BytesIO(full.instance_mask_png)))
    assert np.array_equal(mask, full_mask[8:56, 10:74])
    depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(48, 64)
    full_depth = np.frombuffer(full.depth_m_f32le, "<f4").reshape(72, 96)
    assert np.allclose(depth, full_depth[8:56, 10:74], atol=1e-6)
    assert rgb((out / "scene-000000-frame-000-rgb.png").read_bytes()).shape == (48, 64, 3)


def test_rust_errors_are_clear(dataset, boxpose_bin, tmp_path):
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 9, "--out", tmp_path / "x")
    assert r.returncode != 0 and "scene 9 is not in" in r.stderr
    r = boxpose(
        boxpose_bin,
        "render",
        dataset,
        "--scene",
        0,
        "--crop",
        "0,0,500,10",
        "--out",
        tmp_path / "x",
    )
    assert (
        r.returncode != 0
        and "crop (0, 0, 500, 10) is not a non-empty region of the 96×72 image" in r.stderr
    )
    # an argument error, not a failure inside Blender: no traceback, and no output folder
    assert "Traceback" not in r.stderr and not (tmp_path / "x").exists(), r.stderr
    # the scene has frames 0 and 1: another id would silently draw a new camera
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 0, "--frame", 7, "--out", tmp_path / "x")
    assert r.returncode != 0 and "--frame 7: scene 0 of" in r.stderr, r.stderr
    assert "has frames 0, 1 only" in r.stderr
    r = boxpose(
        boxpose_bin, "render", dataset, "--scene", 0, "--samples", 0, "--out", tmp_path / "x"
    )
    assert r.returncode != 0 and "--samples" in r.stderr and "1.." in r.stderr, r.stderr
    assert not (tmp_path / "x").exists()
    fake = tmp_path / "nobpy" / "bpy"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('No module named bpy (simulated)')\n")
    r = boxpose(
        boxpose_bin,
        "render",
        dataset,
        "--scene",
        0,
        "--out",
        tmp_path / "x",
        env={"PYTHONPATH": str(fake.parent)},
    )
    assert r.returncode != 0 and "bpy is not importable by the embedded Python" in r.stderr
    assert not (tmp_path / "x" / "frames").exists()
    before = sorted(p.name for p in (dataset / "frames").iterdir())
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 0, "--out", dataset)
    assert r.returncode != 0 and "is the input dataset" in r.stderr
    assert sorted(p.name for p in (dataset / "frames").iterdir()) == before


def folder_bytes(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def test_render_refuses_an_out_holding_a_dataset(dataset, boxpose_bin, tmp_path):
    """The render writes one `part-00000-of-00001` shard per table: into another dataset, or an
    earlier render, those would replace its rows (its manifest then describing a dataset that is
    gone). Such an --out is refused, and left exactly as it was."""
    other = tmp_path / "other"
    shutil.copytree(dataset, other)
    (other / "manifest.json").write_text('{"scenes": 2}\n')
    manifest_only = tmp_path / "manifest-only"
    manifest_only.mkdir()
    (manifest_only / "manifest.json").write_text("{}\n")
    for out, held in (
        (other, "scenes, objects, frames, instances, manifest.json"),
        (manifest_only, "manifest.json"),
    ):
        before = folder_bytes(out)
        r = boxpose(boxpose_bin, "render", dataset, "--scene", 1, "--out", out)
        assert r.returncode != 0 and f"already holds a dataset ({held})" in r.stderr, r.stderr
        assert "choose a new or empty folder for --out" in r.stderr
        assert folder_bytes(out) == before

    # a second render into one folder would drop the first one's rows
    out = tmp_path / "renders"
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 0, "--threads", 1, "--out", out)
    assert r.returncode == 0, r.stderr
    before = folder_bytes(out)
    r = boxpose(boxpose_bin, "render", dataset, "--scene", 1, "--out", out)
    assert r.returncode != 0 and "choose a new or empty folder for --out" in r.stderr, r.stderr
    assert folder_bytes(out) == before


def test_blender_output_survives_a_crash_while_it_is_filtered(dataset, boxpose_bin, tmp_path):
    """Blender's start-up and first render run with stdout and stderr filtered (its CUDA-probe
    noise dropped). Whatever is written there before a crash reaches the terminal: the text is
    written into the filtered stderr from outside, then the process is killed (SIGKILL: nothing
    in it can run after that)."""
    process = subprocess.Popen(
        [str(boxpose_bin), "render", str(dataset), "--scene", "0", "--out", str(tmp_path / "x")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    stderr_link = Path(f"/proc/{process.pid}/fd/2")
    original = os.readlink(stderr_link)
    deadline = time.monotonic() + 120
    while os.readlink(stderr_link) == original:
        assert process.poll() is None, "the render ended before its output was filtered"
        assert time.monotonic() < deadline, "stderr was never redirected"
        time.sleep(0.001)
    with open(stderr_link, "w") as filtered_stderr:
        filtered_stderr.write("Blender's last words before the crash\n")
    os.kill(process.pid, signal.SIGKILL)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == -signal.SIGKILL
    assert "Blender's last words before the crash" in stderr
