"""`boxpose view`: one frame's ground truth as a PNG sheet (RGB with corners by visibility,
depth, masks), checked pixel by pixel against the dataset it draws."""

from __future__ import annotations

import io
import subprocess

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from conftest import render_synthetic_dataset

HEADER = 56  # rows above the panels (title and legend)
GAP = 8  # columns between panels
VISIBLE = (44, 160, 44)  # plots::TRUTH_COLOR, the colour of a visible corner


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return render_synthetic_dataset(tmp_path_factory.mktemp("view") / "ds", 200, 150)


def view(boxpose_bin, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [boxpose_bin, "view", *map(str, args)], capture_output=True, text=True, timeout=120
    )


def test_the_sheet_shows_the_frame_its_corners_depth_and_masks(dataset, boxpose_bin, tmp_path):
    out = tmp_path / "sheet.png"
    r = view(boxpose_bin, dataset, "--scene", 1, "--frame", 1, "--out", out)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(out)
    frames = pq.read_table(dataset / "frames").to_pandas()
    frame = frames[(frames.scene_id == 1) & (frames.frame_id == 1)].iloc[0]
    w, h = int(frame.width), int(frame.height)
    sheet = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert sheet.shape == (HEADER + h, max(3 * w + 2 * GAP, 560), 3)
    rgb = np.asarray(Image.open(io.BytesIO(frame.rgb_png)).convert("RGB")).astype(int)
    depth = np.frombuffer(frame.depth_m_f32le, "<f4").reshape(h, w)
    mask = np.asarray(Image.open(io.BytesIO(frame.instance_mask_png)))
    left = sheet[HEADER:, :w]
    middle = sheet[HEADER:, w + GAP : 2 * w + GAP]
    right = sheet[HEADER:, 2 * (w + GAP) : 3 * w + 2 * GAP]
    # the image itself, where nothing is drawn over it (most pixels)
    assert (np.abs(left - rgb).max(axis=2) == 0).mean() > 0.7
    # each visible corner is a dot of the "visible" colour
    instances = pq.read_table(dataset / "instances").to_pandas()
    seen = instances[(instances.scene_id == 1) & (instances.frame_id == 1)]
    visible = 0
    for _, instance in seen.iterrows():
        corners = np.asarray(instance.corners_px).reshape(8, 2)
        for (u, v), state in zip(corners, instance.corner_visibility, strict=True):
            if state == 0 and 3 <= u < w - 3 and 3 <= v < h - 3:
                visible += 1
                x, y = round(u), round(v)
                assert np.abs(left[y, x] - VISIBLE).max() <= 30, (u, v, left[y, x])
    assert visible >= 4
    # depth: black exactly where no surface, nearer is brighter
    assert ((middle.max(axis=2) == 0) == (depth == 0)).mean() > 0.99
    near, far = (
        np.unravel_index(np.argmin(np.where(depth > 0, depth, np.inf)), depth.shape),
        (np.unravel_index(np.argmax(depth), depth.shape)),
    )
    assert middle[near].sum() > middle[far].sum()
    # masks: black background, one colour per box
    assert ((right.max(axis=2) == 0) == (mask == 0)).mean() > 0.97
    colours = {
        label: tuple(np.median(right[mask == label], axis=0).astype(int))
        for label in np.unique(mask)
        if label and (mask == label).sum() > 50
    }
    assert len(colours) >= 2 and len(set(colours.values())) == len(colours)


def test_view_names_what_is_missing(dataset, boxpose_bin, tmp_path):
    r = view(boxpose_bin, dataset, "--scene", 7, "--out", tmp_path / "x.png")
    assert r.returncode != 0 and "no frame 0 of scene 7" in r.stderr, r.stderr
    r = view(boxpose_bin, dataset, "--out", tmp_path / "x.png")
    assert r.returncode != 0 and "give --scene N" in r.stderr, r.stderr
    r = view(boxpose_bin, dataset, "--scene", 1, "--out", tmp_path)
    assert r.returncode != 0 and "is a folder" in r.stderr, r.stderr
    assert not (tmp_path / "x.png").exists()
