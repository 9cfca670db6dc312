"""`boxpose export bop|coco`: the exported files read back in Python and checked, field by field,
against the Parquet rows they came from (poses in mm, K, depth, masks, pixel counts, visibility,
models and their symmetries; COCO RLE masks, boxes and areas, and the corners as COCO keypoints)."""

import io
import json
import os
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import bpy  # noqa: F401  (installed by `make setup`: a missing bpy fails, never skips)
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image

from blender_scripts import geometry as geo
from conftest import render_synthetic_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Two scenes, two 96×72 views each, rendered by the Python worker. Scene 0's two boxes get the
    same square-based size, so they share one BOP obj_id whose model has 7 discrete symmetries."""
    return render_synthetic_dataset(
        tmp_path_factory.mktemp("export") / "ds", 96, 72, shared_size_in_scene_0=True
    )


def boxpose(boxpose_bin: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(boxpose_bin), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        env=dict(os.environ),
    )


@pytest.fixture(scope="module")
def bop(dataset, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bop") / "boxpose_bop"
    r = boxpose(boxpose_bin, "export", "bop", dataset, out)
    assert r.returncode == 0, r.stderr
    assert not out.with_name("boxpose_bop.partial").exists()
    return out


@pytest.fixture(scope="module")
def coco(dataset, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("coco") / "boxpose_coco"
    r = boxpose(boxpose_bin, "export", "coco", dataset, out)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def coco_keypoints(dataset, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("coco_keypoints") / "boxpose_coco"
    r = boxpose(boxpose_bin, "export", "coco", dataset, out, "--keypoints")
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def rows(dataset):
    frames = (
        pd.read_parquet(dataset / "frames")
        .sort_values(["scene_id", "frame_id"])
        .reset_index(drop=True)
    )
    instances = (
        pd.read_parquet(dataset / "instances")
        .sort_values(["scene_id", "frame_id", "object_id"])
        .reset_index(drop=True)
    )
    return frames, instances


def png(path) -> np.ndarray:
    return np.asarray(Image.open(path))


def decode(blob: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(blob)))


def camera(f) -> geo.Camera:
    world_camera = np.eye(4)
    world_camera[:3, :3] = geo.quat_to_matrix(f.world_camera_quat_wxyz)
    world_camera[:3, 3] = f.world_camera_translation_m
    return geo.Camera(int(f.width), int(f.height), f.fx, f.fy, f.cx, f.cy, world_camera)


def load(path: Path):
    return json.loads(path.read_text())


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = path.read_text().splitlines()
    end = lines.index("end_header")
    header = lines[:end]
    nv = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    nf = int(next(line.split()[2] for line in header if line.startswith("element face")))
    verts = np.array([[float(x) for x in line.split()] for line in lines[end + 1 : end + 1 + nv]])
    faces = np.array(
        [[int(x) for x in line.split()] for line in lines[end + 1 + nv : end + 1 + nv + nf]]
    )
    return verts, faces


def test_bop_layout_and_models(bop, dataset):
    objects = pd.read_parquet(dataset / "objects")
    sizes_mm = sorted({tuple(np.round(np.asarray(s) * 1e4).astype(int)) for s in objects.size_m})
    assert len(sizes_mm) == len(objects) - 1  # scene 0's two boxes share a size
    for split_scene in ("test/000000", "test/000001"):
        for name in (
            "scene_camera.json",
            "scene_gt.json",
            "scene_gt_info.json",
            "rgb",
            "depth",
            "mask",
            "mask_visib",
        ):
            assert (bop / split_scene / name).exists(), name
    for name in ("camera.json", "test_targets_bop19.json", "dataset_info.md", "dataset_info.json"):
        assert (bop / name).is_file(), name

    cam = load(bop / "camera.json")
    f0 = pd.read_parquet(dataset / "frames").iloc[0]
    assert (cam["width"], cam["height"], cam["fx"], cam["fy"], cam["cx"], cam["cy"]) == (
        96,
        72,
        f0.fx,
        f0.fy,
        f0.cx,
        f0.cy,
    )

    for models in ("models", "models_eval"):
        info = load(bop / models / "models_info.json")
        assert sorted(map(int, info)) == list(range(1, len(sizes_mm) + 1))
        for obj_id, key in enumerate(sizes_mm, start=1):
            size = np.array(key) / 10.0  # mm, the order obj_ids are assigned in
            m = info[str(obj_id)]
            assert np.allclose([m["size_x"], m["size_y"], m["size_z"]], size)
            assert np.allclose([m["min_x"], m["min_y"], m["min_z"]], -size / 2)
            assert m["diameter"] == pytest.approx(np.linalg.norm(size))
            verts, faces = read_ply(bop / models / f"obj_{obj_id:06d}.ply")
            pts, normals = verts[:, :3], verts[:, 3:]
            assert np.allclose(np.unique(np.abs(pts), axis=0), size / 2)  # every vertex a corner
            assert (
                len(np.unique(pts, axis=0)) == 8 and len(faces) == 12 and (faces[:, 0] == 3).all()
            )
            # triangles wind counter-clockwise seen from outside: their normal agrees with the
            # vertex normals
            tri = pts[faces[:, 1:]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            assert (np.einsum("ij,ij->i", n, normals[faces[:, 1]]) > 0).all()
            assert np.isclose(
                np.abs(np.einsum("ij,ij->i", n, tri[:, 0])).sum() / 2 / 3, size.prod(), rtol=1e-9
            )  # encloses the box volume
            syms = [np.array(s).reshape(4, 4) for s in m["symmetries_discrete"]]
            distinct = len(set(key))
            assert len(syms) == {3: 3, 2: 7, 1: 23}[distinct]
            corners = geo.box_corners(size)
            seen = set()
            for s in syms:
                r = s[:3, :3]
                assert np.allclose(s[3], [0, 0, 0, 1]) and np.allclose(s[:3, 3], 0)
                assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
                assert not np.allclose(r, np.eye(3))
                moved = corners @ r.T
                assert all(
                    np.isclose(moved, c).all(axis=1).any() for c in corners
                )  # maps the box onto itself
                seen.add(tuple(np.round(r).astype(int).ravel()))
            assert len(seen) == len(syms)
    # scene 0's boxes (equal sides dx = dy) map to the model with 7 symmetries
    md = (bop / "dataset_info.md").read_text()
    assert "| 7 |" in md and "| 3 |" in md


def test_bop_cameras_images_and_depth(bop, rows):
    frames, _ = rows
    for f in frames.itertuples():
        scene = bop / "test" / f"{f.scene_id:06d}"
        c = load(scene / "scene_camera.json")[str(f.frame_id)]
        assert np.allclose(
            np.reshape(c["cam_K"], (3, 3)), [[f.fx, 0, f.cx], [0, f.fy, f.cy], [0, 0, 1]]
        )
        r_wc = geo.quat_to_matrix(f.world_camera_quat_wxyz)
        r_w2c, t_w2c = np.reshape(c["cam_R_w2c"], (3, 3)), np.asarray(c["cam_t_w2c"])
        assert np.allclose(r_w2c @ r_wc, np.eye(3), atol=1e-9)
        assert np.allclose(
            r_w2c @ (1000 * np.asarray(f.world_camera_translation_m)) + t_w2c, 0, atol=1e-6
        )  # camera centre → origin, mm

        assert np.array_equal(png(scene / "rgb" / f"{f.frame_id:06d}.png"), decode(f.rgb_png))
        d = png(scene / "depth" / f"{f.frame_id:06d}.png")
        assert d.dtype == np.uint16 and d.shape == (72, 96)
        depth_mm = 1000 * np.frombuffer(f.depth_m_f32le, "<f4").reshape(72, 96).astype(np.float64)
        assert c["depth_scale"] == 0.1
        assert (
            np.abs(d * c["depth_scale"] - depth_mm).max() <= 0.051
        )  # ≤ half a 0.1 mm step, far inside 1 mm
        assert ((d == 0) == (depth_mm == 0)).all()


def test_bop_ground_truth_matches_the_rows(bop, rows):
    frames, instances = rows
    info = load(bop / "models" / "models_info.json")
    checked = 0
    for f in frames.itertuples():
        scene = bop / "test" / f"{f.scene_id:06d}"
        gt = load(scene / "scene_gt.json")[str(f.frame_id)]
        gt_info = load(scene / "scene_gt_info.json")[str(f.frame_id)]
        mine = instances[(instances.scene_id == f.scene_id) & (instances.frame_id == f.frame_id)]
        assert len(gt) == len(gt_info) == len(mine) > 0
        k = np.array([[f.fx, 0, f.cx], [0, f.fy, f.cy], [0, 0, 1]])
        mask = decode(f.instance_mask_png)
        depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(72, 96)
        cam = camera(f)
        for gt_id, (g, gi, i) in enumerate(zip(gt, gt_info, mine.itertuples(), strict=True)):
            r, t = np.reshape(g["cam_R_m2c"], (3, 3)), np.asarray(g["cam_t_m2c"])
            assert np.allclose(r, geo.quat_to_matrix(i.camera_box_quat_wxyz), atol=1e-12)
            assert np.allclose(t, 1000 * np.asarray(i.camera_box_translation_m), atol=1e-9)
            m = info[str(g["obj_id"])]
            size_mm = np.array([m["size_x"], m["size_y"], m["size_z"]])
            assert np.allclose(size_mm, 1000 * np.asarray(i.size_m), atol=0.05)
            # the BOP chain model (mm) → camera → pixels lands on the dataset's corners
            corners_mm = geo.box_corners(1000 * np.asarray(i.size_m)) @ r.T + t
            assert np.allclose(corners_mm, 1000 * np.reshape(i.corners_camera_m, (8, 3)), atol=1e-6)
            uvw = corners_mm @ k.T
            assert np.allclose(uvw[:, :2] / uvw[:, 2:], np.reshape(i.corners_px, (8, 2)), atol=1e-6)

            visib = png(scene / "mask_visib" / f"{f.frame_id:06d}_{gt_id:06d}.png")
            assert np.array_equal(visib > 0, mask == i.object_id + 1) and set(np.unique(visib)) <= {
                0,
                255,
            }
            amodal = png(scene / "mask" / f"{f.frame_id:06d}_{gt_id:06d}.png") > 0
            silhouette = geo.silhouette_mask(cam, np.reshape(i.corners_camera_m, (8, 3)))
            assert np.array_equal(amodal, silhouette)
            assert gi["px_count_visib"] == i.visible_pixels == visib.astype(bool).sum()
            assert gi["px_count_all"] == silhouette.sum()
            assert gi["px_count_valid"] == (silhouette & (depth > 0)).sum()
            assert gi["visib_fract"] == pytest.approx(i.visible_fraction, abs=1e-6)
            if i.visible_bbox_px is None:
                assert gi["bbox_visib"] == [-1, -1, -1, -1]
            else:
                x0, y0, x1, y1 = i.visible_bbox_px
                assert gi["bbox_visib"] == [x0, y0, x1 - x0, y1 - y0]
            ys, xs = np.nonzero(silhouette)
            x, y, w, h = gi["bbox_obj"]
            # the silhouette's box, possibly reaching past the image (never inside its in-image
            # part)
            assert (
                x <= xs.min() and y <= ys.min() and x + w - 1 >= xs.max() and y + h - 1 >= ys.max()
            )
            if x >= 0 and y >= 0 and x + w <= 96 and y + h <= 72:
                assert [x, y, w, h] == [
                    xs.min(),
                    ys.min(),
                    xs.max() - xs.min() + 1,
                    ys.max() - ys.min() + 1,
                ]
            checked += 1
    assert checked == len(instances)


def test_bop_test_targets(bop, rows):
    _, instances = rows
    targets = load(bop / "test_targets_bop19.json")
    want = Counter()
    for scene_id, frame_id in {
        (s, f) for s, f in zip(instances.scene_id, instances.frame_id, strict=True)
    }:
        gt = load(bop / "test" / f"{scene_id:06d}" / "scene_gt.json")[str(frame_id)]
        info = load(bop / "test" / f"{scene_id:06d}" / "scene_gt_info.json")[str(frame_id)]
        for g, gi in zip(gt, info, strict=True):
            if gi["visib_fract"] >= 0.1:
                want[(scene_id, frame_id, g["obj_id"])] += 1
    got = {(t["scene_id"], t["im_id"], t["obj_id"]): t["inst_count"] for t in targets}
    assert got == dict(want) and len(got) > 0


def rle_decode(segm: dict) -> np.ndarray:
    """Uncompressed COCO RLE → H×W bool (runs alternate 0/1, column-major, starting with 0s)."""
    h, w = segm["size"]
    counts = np.asarray(segm["counts"], dtype=np.int64)
    assert counts.sum() == h * w
    values = np.arange(len(counts)) % 2 == 1
    return np.repeat(values, counts).reshape(w, h).T


def test_coco_annotations_match_the_rows(coco, rows):
    frames, instances = rows
    doc = load(coco / "annotations.json")
    assert doc["categories"] == [{"id": 1, "name": "box", "supercategory": "box"}]
    images = {im["id"]: im for im in doc["images"]}
    assert len(images) == len(frames)
    by_key = {(im["scene_id"], im["frame_id"]): im for im in images.values()}
    for f in frames.itertuples():
        im = by_key[(f.scene_id, f.frame_id)]
        assert (im["width"], im["height"]) == (96, 72)
        assert np.array_equal(png(coco / "images" / im["file_name"]), decode(f.rgb_png))
    visible = instances[instances.visible_pixels > 0]
    assert len(doc["annotations"]) == len(visible) > 0
    assert len({a["id"] for a in doc["annotations"]}) == len(doc["annotations"])
    frames_by_key = {(f.scene_id, f.frame_id): f for f in frames.itertuples()}
    for a in doc["annotations"]:
        im = images[a["image_id"]]
        f = frames_by_key[(im["scene_id"], im["frame_id"])]
        i = visible[
            (visible.scene_id == f.scene_id)
            & (visible.frame_id == f.frame_id)
            & (visible.object_id == a["object_id"])
        ].iloc[0]
        own = decode(f.instance_mask_png) == i.object_id + 1
        assert a["category_id"] == 1 and a["iscrowd"] == 0
        assert np.array_equal(rle_decode(a["segmentation"]), own)
        assert a["area"] == i.visible_pixels == own.sum()
        x0, y0, x1, y1 = i.visible_bbox_px
        assert a["bbox"] == [x0, y0, x1 - x0, y1 - y0]
        silhouette = geo.silhouette_mask(camera(f), np.reshape(i.corners_camera_m, (8, 3)))
        amodal = rle_decode(a["amodal_segmentation"])
        assert np.array_equal(amodal, silhouette) and a["amodal_area"] == silhouette.sum()
        ys, xs = np.nonzero(silhouette)
        assert a["amodal_bbox"] == [
            xs.min(),
            ys.min(),
            xs.max() - xs.min() + 1,
            ys.max() - ys.min() + 1,
        ]
        assert a["visib_fract"] == pytest.approx(i.visible_fraction, abs=1e-6)


def test_coco_evaluates_to_ap_1_with_pycocotools(coco):
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    gt = COCO(str(coco / "annotations.json"))
    dets = [
        {
            "image_id": a["image_id"],
            "category_id": 1,
            "segmentation": a["segmentation"],
            "bbox": a["bbox"],
            "score": 1.0,
        }
        for a in gt.dataset["annotations"]
    ]
    for iou in ("segm", "bbox"):
        e = COCOeval(gt, gt.loadRes(dets), iou)
        e.evaluate()
        e.accumulate()
        e.summarize()
        assert e.stats[0] == pytest.approx(1.0), iou


# The dataset's 4-state corner visibility (0 visible, 1 occluded by another object, 2 self-occluded,
# 3 outside the image) as COCO's flag (2 visible, 1 labelled but hidden, 0 not labelled): the
# mapping docs/export.md states.
COCO_VISIBILITY = {0: 2, 1: 1, 2: 1, 3: 0}

# Per-corner OKS sigmas for pycocotools' keypoint evaluation, as docs/export.md states and argues.
CORNER_SIGMAS = np.full(8, 0.05)


def expected_keypoints(instance) -> list[float]:
    corners = np.reshape(instance.corners_px, (8, 2))
    keypoints = []
    for (x, y), state in zip(corners, instance.corner_visibility, strict=True):
        v = COCO_VISIBILITY[int(state)]
        keypoints += [x, y, v] if v > 0 else [0, 0, 0]
    return keypoints


def annotated_instance(doc: dict, annotation: dict, instances: pd.DataFrame):
    image = next(im for im in doc["images"] if im["id"] == annotation["image_id"])
    (row,) = instances[
        (instances.scene_id == image["scene_id"])
        & (instances.frame_id == image["frame_id"])
        & (instances.object_id == annotation["object_id"])
    ].itertuples()
    return row


def test_coco_keypoints_are_the_corners_with_coco_visibility(coco_keypoints, rows):
    _, instances = rows
    doc = load(coco_keypoints / "annotations.json")
    states = Counter()
    for a in doc["annotations"]:
        i = annotated_instance(doc, a, instances)
        assert a["keypoints"] == expected_keypoints(i)  # exact: the floats round-trip
        assert a["num_keypoints"] == sum(COCO_VISIBILITY[int(s)] > 0 for s in i.corner_visibility)
        states.update(int(s) for s in i.corner_visibility)
    # the fixture holds visible, occluded and self-occluded corners (none outside the image: see
    # the next test), so each hidden state's mapping is exercised
    assert {0, 1, 2} <= set(states), states


def test_coco_keypoints_outside_the_image_are_not_labelled(dataset, boxpose_bin, tmp_path):
    """A corner outside the image has no position in it: COCO's (0, 0, 0), not counted in
    num_keypoints. The fixture has none, so a copy of it marks two corners of a box as outside."""
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    (shard,) = (copy / "instances").glob("*.parquet")
    table = pq.read_table(shard)
    visibility = table.column("corner_visibility").to_pylist()
    visible_pixels = table.column("visible_pixels").to_pylist()
    target = visible_pixels.index(max(visible_pixels))  # a box surely annotated
    visibility[target][0] = visibility[target][5] = 3
    column = table.schema.get_field_index("corner_visibility")
    field = table.schema.field(column)
    pq.write_table(
        table.set_column(column, field, pa.array(visibility, type=field.type)),
        shard,
        compression="zstd",
    )
    out = tmp_path / "coco"
    r = boxpose(boxpose_bin, "export", "coco", copy, out, "--keypoints")
    assert r.returncode == 0, r.stderr
    doc = load(out / "annotations.json")
    instances = pd.read_parquet(copy / "instances")
    (moved,) = [
        a
        for a in doc["annotations"]
        if annotated_instance(doc, a, instances).corner_visibility[0] == 3
    ]
    i = annotated_instance(doc, moved, instances)
    assert moved["keypoints"][0:3] == moved["keypoints"][15:18] == [0, 0, 0]
    assert moved["keypoints"] == expected_keypoints(i)
    assert moved["num_keypoints"] == 8 - 2


def test_coco_keypoint_category_names_corners_and_skeleton_joins_box_edges(coco_keypoints):
    (category,) = load(coco_keypoints / "annotations.json")["categories"]
    assert category["keypoints"] == [f"corner_{i}" for i in range(8)]
    # corner order and sign patterns from the Python geometry, independent of the Rust code
    signs = np.sign(geo.box_corners(np.ones(3)))
    edges = {tuple(edge) for edge in category["skeleton"]}
    assert len(category["skeleton"]) == len(edges) == 12
    for a, b in edges:
        assert 1 <= a < b <= 8  # 1-based, as COCO
        assert (signs[a - 1] != signs[b - 1]).sum() == 1  # an edge: one sign apart
    assert Counter(c for edge in edges for c in edge) == {c: 3 for c in range(1, 9)}


def test_coco_without_keypoints_is_unchanged(coco, coco_keypoints):
    """`--keypoints` only adds fields: without it the export is the one written before the option
    existed (no keypoint field anywhere), and the two exports differ in nothing else."""
    plain = load(coco / "annotations.json")
    with_keypoints = load(coco_keypoints / "annotations.json")
    assert "keypoints" not in plain["categories"][0] and "skeleton" not in plain["categories"][0]
    assert not any("keypoints" in a or "num_keypoints" in a for a in plain["annotations"])
    for a in with_keypoints["annotations"]:
        del a["keypoints"], a["num_keypoints"]
    del with_keypoints["categories"][0]["keypoints"], with_keypoints["categories"][0]["skeleton"]
    assert with_keypoints == plain
    images = sorted(p.name for p in (coco / "images").iterdir())
    assert images == sorted(p.name for p in (coco_keypoints / "images").iterdir())
    for name in images:
        assert (coco / "images" / name).read_bytes() == (
            coco_keypoints / "images" / name
        ).read_bytes()


def test_coco_keypoints_evaluate_to_ap_1_with_pycocotools(coco_keypoints):
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    gt = COCO(str(coco_keypoints / "annotations.json"))

    def keypoint_ap(shift_px: float) -> float:
        dets = []
        for a in gt.dataset["annotations"]:
            keypoints = np.reshape(a["keypoints"], (8, 3)).copy()
            keypoints[:, 0] += shift_px
            dets.append(
                {
                    "image_id": a["image_id"],
                    "category_id": 1,
                    "keypoints": keypoints.ravel().tolist(),
                    "score": 1.0,
                }
            )
        e = COCOeval(gt, gt.loadRes(dets), "keypoints")
        e.params.kpt_oks_sigmas = CORNER_SIGMAS
        e.evaluate()
        e.accumulate()
        e.summarize()
        return e.stats[0]

    assert keypoint_ap(0.0) == pytest.approx(1.0)
    # the sigmas make the evaluation discriminate: a 2-pixel error on these small boxes (a few
    # hundred visible pixels) costs most of the AP
    assert keypoint_ap(2.0) < 0.5


def test_exports_name_their_source_without_the_machines_absolute_path(bop, coco, dataset):
    """A shared export records the dataset's folder name, not where it lay on the exporting
    machine."""
    parent = str(dataset.resolve().parent)
    texts = [
        (bop / "dataset_info.json").read_text(),
        (bop / "dataset_info.md").read_text(),
        (coco / "annotations.json").read_text(),
    ]
    assert all(parent not in text for text in texts)
    assert json.loads(texts[0])["source"] == dataset.resolve().name
    assert dataset.resolve().name in json.loads(texts[2])["info"]["description"]


def test_a_partial_dataset_exports_with_a_warning(dataset, boxpose_bin, tmp_path):
    """A dataset missing a shard (an unfinished render) still exports and evaluates what is
    there, but says so instead of looking complete."""
    partial = tmp_path / "partial"
    shutil.copytree(dataset, partial)
    for table in ("frames", "instances"):
        (shard,) = (partial / table).glob("part-00000-of-00001.parquet")
        shard.rename(shard.with_name("part-00000-of-00002.parquet"))
    for args in (
        ("export", "bop", partial, tmp_path / "bop"),
        ("export", "coco", partial, tmp_path / "coco"),
        ("eval-geometry", partial, "--out", tmp_path / "geometry.parquet"),
    ):
        r = boxpose(boxpose_bin, *args)
        assert r.returncode == 0, r.stderr
        assert "frames: 1 of 2 shards missing" in r.stderr, r.stderr
        assert "instances: 1 of 2 shards missing" in r.stderr, r.stderr


def test_export_help_and_refusals(boxpose_bin, dataset, bop, tmp_path):
    r = boxpose(boxpose_bin, "export", "--help")
    assert (
        r.returncode == 0
        and "bop" in r.stdout
        and "coco" in r.stdout
        and "docs/export.md" in r.stdout
    )
    r = boxpose(boxpose_bin, "export", "bop", dataset, bop)
    assert r.returncode != 0 and "is not an empty folder" in r.stderr
    r = boxpose(boxpose_bin, "export", "coco", tmp_path / "missing", tmp_path / "x")
    assert r.returncode != 0 and not (tmp_path / "x").exists()


def test_predict_reads_the_bop_depth_with_its_depth_scale(
    bop, dataset, rows, boxpose_bin, tmp_path
):
    """`predict` on the BOP export's own files (uint16 depth × depth_scale = mm, 0.1 here) finds
    the pose it finds on the dataset row, with the depth_scale given or, by default, read from
    the scene's scene_camera.json; read as millimetres the box lands 10× too far, and predict
    warns."""
    frames, instances = rows
    f = frames.iloc[0]
    target = instances[
        (instances.scene_id == f.scene_id)
        & (instances.frame_id == f.frame_id)
        & (instances.visible_pixels > 0)
    ].iloc[0]
    r = boxpose(
        boxpose_bin, "predict", dataset, "--scene", f.scene_id, "--frame", f.frame_id,
        "--out", tmp_path / "row",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    boxes = load(tmp_path / "row" / "predictions.json")["boxes"]
    (from_row,) = [b for b in boxes if b["object_id"] == target.object_id]

    scene = bop / "test" / f"{f.scene_id:06d}"
    depth_scale = load(scene / "scene_camera.json")[str(f.frame_id)]["depth_scale"]
    files = [
        "predict",
        "--rgb", scene / "rgb" / f"{f.frame_id:06d}.png",
        "--depth", scene / "depth" / f"{f.frame_id:06d}.png",
        "--intrinsics", f"{f.fx},{f.fy},{f.cx},{f.cy}",
        "--bbox", ",".join(str(int(v)) for v in target.visible_bbox_px),
    ]  # fmt: skip
    r = boxpose(boxpose_bin, *files, "--depth-scale", depth_scale, "--out", tmp_path / "files")
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    (from_files,) = load(tmp_path / "files" / "predictions.json")["boxes"]
    # the row's reference depth is its mask's median, the files' the whole box's: a few mm apart
    row_fit, files_fit = from_row["fit"], from_files["fit"]
    for key in ("pose_translation_m", "size_m"):
        assert np.allclose(row_fit[key], files_fit[key], atol=0.01), key
    assert abs(np.dot(row_fit["pose_quat_wxyz"], files_fit["pose_quat_wxyz"])) > np.cos(
        np.radians(5) / 2
    )

    # without --depth-scale, the PNG in SCENE/depth/ takes its image's scale from the scene
    r = boxpose(boxpose_bin, *files, "--out", tmp_path / "bop-default")
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    (by_default,) = load(tmp_path / "bop-default" / "predictions.json")["boxes"]
    assert by_default["fit"] == from_files["fit"]

    r = boxpose(boxpose_bin, *files, "--depth-scale", 1, "--out", tmp_path / "millimetres")
    assert r.returncode == 0, r.stderr
    assert "warning:" in r.stderr and "--depth-scale" in r.stderr, r.stderr
    (misread,) = load(tmp_path / "millimetres" / "predictions.json")["boxes"]
    assert misread["reference_depth_m"] > 5 * from_files["reference_depth_m"]
