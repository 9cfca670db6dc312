"""The Blender stage: camera conventions, ground truth against the rendered passes, crops,
re-renders, pose changes, the simulated sensor. Tiny renders (≤ 128², 1 sample) on the CPU."""

import io
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

import boxpose_io
from blender_scripts import geometry as geo, sampling, sensor
from blender_scripts.exr import read_exr
from blender_scripts.groundtruth import OCCLUDED_BY_OTHER, OUTSIDE_IMAGE, SELF_OCCLUDED, VISIBLE
from blender_scripts.recipe import parse_render_recipe
from blender_scripts.session import RenderInputError, check_scene_objects
from blender_scripts.synthetic import synthetic_scene
from drake_scenes.recipe import Recipe, RecipeError

REPO = Path(__file__).resolve().parent.parent
RECIPES = REPO / "datasets" / "recipes"


def recipe_text(
    name: str = "tiny", width: int = 64, height: int = 64, frames: int = 1, **render
) -> str:
    text = (RECIPES / f"{name}.toml").read_text()
    lines = []
    section = None
    for line in text.splitlines():
        if line.startswith("["):
            section = line.strip("[] ")
        key = line.split("=")[0].strip()
        if section == "camera" and key == "width":
            line = f"width = {width}"
        elif section == "camera" and key == "height":
            line = f"height = {height}"
        elif section == "camera" and key == "frames_per_scene":
            line = f"frames_per_scene = {frames}"
        elif section == "render" and key in render:
            value = render[key]
            line = f"{key} = {str(value).lower() if isinstance(value, bool) else value}"
        lines.append(line)
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Without rendering


def test_recipes_parse():
    for path in sorted(RECIPES.glob("*.toml")):
        r = parse_render_recipe(path.read_text(), str(path))
        assert r.camera.width > 0 and r.render.samples >= 1


def with_half_extent(text: str, value: str) -> str:
    old = next(t for t in text.splitlines() if t.startswith("half_extent_m"))
    return text.replace(old, f"half_extent_m = {value}")


@pytest.mark.parametrize(
    "value, accepted",
    [
        ("[0.4, 0.3]", True),  # (x, y), not a [min, max] range
        ("[0.3, 0.4]", True),
        ("[0.25, 0.25]", True),
        ("[0.4, 0.0]", False),
        ("[-0.4, 0.3]", False),
        ("[0.4, inf]", False),
        ("[nan, 0.3]", False),
        ("[0.4]", False),
        ("[0.4, 0.3, 0.2]", False),
        ("[0.4, true]", False),
    ],
)
def test_both_stages_read_support_half_extent_alike(value, accepted):
    """half_extent_m is the support's (x, y) half size: the Drake and the Blender readers accept
    the same values (finite, positive, in either order) and keep them in order."""
    text = with_half_extent(recipe_text(), value)
    for read in (lambda t: Recipe.from_toml(t).support, lambda t: parse_render_recipe(t).support):
        if accepted:
            assert list(read(text).half_extent_m) == json.loads(value)
        else:
            with pytest.raises(RecipeError, match="half_extent_m"):
                read(text)


def test_camera_conversion_is_a_pure_axis_flip():
    world_camera = geo.look_at([1.0, -2.0, 1.5], [0.1, 0.2, 0.0])
    blender = geo.blender_camera_matrix(world_camera)
    forward = np.array([0.1, 0.2, 0.0]) - np.array([1.0, -2.0, 1.5])
    forward /= np.linalg.norm(forward)
    # Blender looks down its −z axis, with +y up in the image; OpenCV's y points down.
    assert np.allclose(-blender[:3, 2], forward)
    assert np.allclose(blender[:3, 1], -world_camera[:3, 1])
    assert np.allclose(blender[:3, 0], world_camera[:3, 0])
    assert np.allclose(blender[:3, 3], world_camera[:3, 3])
    # image-down (OpenCV y) points downwards in the world for a camera above the scene
    assert world_camera[2, 1] < 0


def test_intrinsics_from_hfov():
    cam = geo.Camera.from_hfov(64, 48, math.radians(50.0), np.eye(4))
    assert cam.fx == cam.fy == pytest.approx(32.0 / math.tan(math.radians(25.0)))
    assert (cam.cx, cam.cy) == (31.5, 23.5)
    crop = cam.crop(10, 5, 42, 37)
    assert (crop.width, crop.height, crop.cx, crop.cy) == (32, 32, 21.5, 18.5)
    # half the width: the same view, pixel centres k ↦ (k − 0.5) / 2
    half = cam.scaled(32)
    assert (half.width, half.height, half.cx, half.cy) == (32, 24, 15.5, 11.5)
    assert half.fx == half.fy == pytest.approx(cam.fx / 2)
    point = np.array([[0.03, -0.02, 0.5]])
    assert np.allclose(half.project(point), (cam.project(point) - 0.5) / 2)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        assert np.allclose(geo.matrix_to_quat(geo.quat_to_matrix(q)), q, atol=1e-12)


@pytest.mark.parametrize("tape_along", ["random", "long"])
def test_label_corners_lie_on_the_top_face(tape_along):
    for seed in range(40):
        size = (0.12, 0.07, 0.05)
        look = sampling.draw_appearance(seed, size, True, True, tape_along=tape_along)
        corners = look.label.corners_box(size)
        assert np.allclose(corners[:, 2], 0.025)
        assert np.all(np.abs(corners[:, 0]) <= 0.06 + 1e-12) and np.all(
            np.abs(corners[:, 1]) <= 0.035 + 1e-12
        )
        # corner order: bit0 → +u, bit1 → +v, counter-clockwise seen from +z: 0 → 1 → 3 → 2
        e1, e2 = corners[1] - corners[0], corners[2] - corners[0]
        assert np.cross(e1, e2)[2] > 0
        assert look == sampling.draw_appearance(seed, size, True, True, tape_along=tape_along)


# Draws of the code before materials.tape_along existed (commit f2a5592): "random" must reproduce
# them bit for bit, so that the existing datasets (and the networks trained on them) stay valid.
# (texture_seed, size, has_tape, has_label) → (tape axis, tape offset, label rotated, label centre,
# label half extents, label pattern seed, noise offset).
DRAWS_BEFORE_TAPE_ALONG = [
    (
        (7, (0.2, 0.15, 0.1), True, True),
        (
            1,
            0.0022854576604671266,
            True,
            (0.04069490543305419, -0.010722421656468917),
            (0.04112866717800611, 0.044189619990123025),
            37.347295375288134,
            (6.715229267629823, -69.05126609063458, -68.6304338160424),
        ),
    ),
    (
        (12345, (0.1, 0.3, 0.08), True, True),
        (
            0,
            0.023096157531984,
            True,
            (-0.016939675947478267, -0.04685433977855916),
            (0.071344354302455, 0.015761707818434948),
            627.1581694847655,
            (34.73345478602752, 64.32464676586758, 98.08012014996251),
        ),
    ),
    (
        (2**40 + 3, (0.12, 0.12, 0.05), True, True),
        (
            0,
            0.0038471800713267795,
            True,
            (-0.005185020700246138, -0.016149663273691106),
            (0.025202008723835607, 0.01801465452700471),
            760.6887592938886,
            (0.9070522181090439, -18.95878996153499, 72.27623289817936),
        ),
    ),
    (
        (5, (0.1, 0.2, 0.1), False, True),
        (
            None,
            None,
            True,
            (-0.004255173282869327, -0.009774836274913457),
            (0.04482456897586428, 0.020382750402405565),
            803.7556034641852,
            (57.16042602255803, 1.5598025393834831, -44.62790440663469),
        ),
    ),
    (
        (6, (0.25, 0.2, 0.1), True, False),
        (
            1,
            -0.000743611080430644,
            None,
            None,
            None,
            None,
            (76.78047765108931, 48.25725372139948, 63.54654141148407),
        ),
    ),
]


def appearance_facts(look: sampling.BoxAppearance) -> tuple:
    tape, label = look.tape, look.label
    return (
        tape and tape.axis,
        tape and tape.offset_m,
        label and label.rotated,
        label and label.centre_m,
        label and label.half_m,
        label and label.pattern_seed,
        look.noise_offset,
    )


@pytest.mark.parametrize("row, before", DRAWS_BEFORE_TAPE_ALONG)
def test_tape_along_random_draws_what_the_code_before_it_drew(row, before):
    seed, size, has_tape, has_label = row
    look = sampling.draw_appearance(seed, size, has_tape, has_label, tape_along="random")
    assert appearance_facts(look) == before


def long_side_unit(size) -> np.ndarray:
    """The unit vector, in the box frame, of the longer side of the +z face (x on a tie)."""
    return np.array([1.0, 0.0]) if size[0] >= size[1] else np.array([0.0, 1.0])


def label_u_in_box(instance: dict) -> np.ndarray:
    """The label's u axis in the box frame's (x, y), from an instances row's ground truth."""
    camera_box = geo.pose_matrix(
        instance["camera_box_quat_wxyz"], instance["camera_box_translation_m"]
    )
    corners = np.reshape(instance["label_keypoints_camera_m"], (4, 3))
    corners_box = geo.transform(np.linalg.inv(camera_box), corners)
    u = corners_box[1, :2] - corners_box[0, :2]  # corner 1 differs from corner 0 in +u only
    return u / np.linalg.norm(u)


@pytest.mark.parametrize(
    "size", [(0.20, 0.15, 0.1), (0.15, 0.20, 0.1), (0.12, 0.121, 0.05), (0.12, 0.12, 0.05)]
)
def test_tape_along_long_follows_the_longer_side_of_the_top_face(size):
    """Boxes longer along x, longer along y, nearly square and square: the tape runs along the
    longer side and the label's u axis (its long axis) lies along it; every other draw is the one
    "random" makes (the stream stays aligned)."""
    long_axis = int(size[1] > size[0])
    flipped = 0
    for seed in range(30):
        look = sampling.draw_appearance(seed, size, True, True, tape_along="long")
        random = sampling.draw_appearance(seed, size, True, True, tape_along="random")
        assert look.tape.axis == long_axis
        corners = look.label.corners_box(size)[:, :2]
        u = corners[1] - corners[0]  # corner 1 differs from corner 0 in +u only
        assert np.allclose(u / np.linalg.norm(u), long_side_unit(size))
        # the label stays on the face, with its margin
        assert np.all(np.abs(corners) <= 0.5 * np.array(size[:2]) + 1e-12)
        same = ("noise_offset", "noise_scale", "fibre_scale", "color_variation")
        assert all(getattr(look, k) == getattr(random, k) for k in same)
        assert look.tape.color == random.tape.color and look.tape.width_m <= 0.048
        assert look.label.pattern_seed == random.label.pattern_seed
        flipped += random.tape.axis != long_axis
    assert 0 < flipped < 30  # "random" takes the other side on some boxes, so this test bites


def test_tape_along_of_another_value_is_refused():
    with pytest.raises(ValueError, match="tape_along"):
        sampling.draw_appearance(1, (0.1, 0.2, 0.1), True, True, tape_along="short")


@pytest.mark.parametrize("value", ['"short"', '"Long"', '""', "1", "true", '["long"]'])
def test_both_stages_refuse_another_tape_along_naming_the_key_and_values(value):
    text = recipe_text().replace("[materials]\n", f"[materials]\ntape_along = {value}\n")
    for read in (Recipe.from_toml, parse_render_recipe):
        with pytest.raises(RecipeError, match=r"materials\.tape_along.*\"long\" or \"random\""):
            read(text, "bad")


@pytest.mark.parametrize("value, means", [(None, "random"), ("random", "random"), ("long", "long")])
def test_both_stages_read_tape_along_random_when_absent(value, means):
    text = recipe_text()
    assert "tape_along" not in text  # no shipped recipe sets it: their data must not change
    if value is not None:
        text = text.replace("[materials]\n", f'[materials]\ntape_along = "{value}"\n')
    assert Recipe.from_toml(text).materials.tape_along == means
    assert parse_render_recipe(text).materials.tape_along == means


def test_render_seed_is_deterministic_and_per_frame():
    assert sampling.render_seed(5, 0) == sampling.render_seed(5, 0)
    assert len({sampling.render_seed(5, f) for f in range(100)}) == 100
    assert 0 <= sampling.render_seed(-3, 7) < 2**31


def test_silhouette_of_a_box_matches_its_projection():
    cam = geo.Camera.from_hfov(
        80, 60, math.radians(60.0), geo.look_at([0.5, 0.0, 0.6], [0.0, 0.0, 0.0])
    )
    corners = geo.transform(cam.camera_world, geo.box_corners((0.2, 0.1, 0.1)))
    mask = geo.silhouette_mask(cam, corners)
    assert 0 < mask.sum() < mask.size
    # half of the box behind the camera: clipped, still a sane silhouette
    cam2 = geo.Camera.from_hfov(
        80, 60, math.radians(60.0), geo.look_at([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    )
    corners2 = geo.transform(cam2.camera_world, geo.box_corners((1.0, 0.5, 0.5)))
    assert geo.silhouette_mask(cam2, corners2).all()


def test_check_scene_objects_names_the_problem():
    text = recipe_text()
    scene, objects = synthetic_scene(3, text, 3, seed=1)
    assert [o["object_id"] for o in check_scene_objects([scene], objects)[3]] == [0, 1, 2]
    with pytest.raises(RenderInputError, match=r"scene 3 .*num_objects=3.*missing \[1\]"):
        check_scene_objects([scene], [objects[0], objects[2]])
    orphan = dict(objects[0], scene_id=9)
    with pytest.raises(RenderInputError, match=r"scene_id=9, object_id=0\).*references scene 9"):
        check_scene_objects([scene], objects + [orphan])


def test_sensor_noise_grows_with_depth_and_drops_edges():
    rng = np.random.default_rng(0)
    h, w = 60, 80
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, :40] = 0.8  # a near plane on the left, a far plane on the right
    noisy = sensor.simulate(depth, 100.0, 100.0, 39.5, 29.5, rng)
    near, far = noisy[:, 5:35], noisy[:, 50:75]
    assert (near > 0).mean() > 0.95 and (far > 0).mean() > 0.95
    err_near = np.std(near[near > 0] - 0.8)
    err_far = np.std(far[far > 0] - 2.0)
    assert err_far > 3 * err_near  # ∝ depth²: (2.0 / 0.8)² ≈ 6
    assert np.all(noisy[:, 39:41] == 0)  # the depth edge returns nothing
    assert np.all(noisy[:, 40:42] == 0)  # projector shadow beside the near plane


def test_exr_reader_rejects_other_files():
    with pytest.raises(ValueError, match="not an OpenEXR"):
        read_exr(b"\x89PNG\r\n\x1a\n" + bytes(32))


# ---------------------------------------------------------------------------------------------
# With Blender


@pytest.fixture(scope="module")
def session():
    from blender_scripts.session import Session

    return Session()


def decode(frame: dict):
    h, w = frame["height"], frame["width"]
    rgb = np.asarray(Image.open(io.BytesIO(frame["rgb_png"])))
    depth = np.frombuffer(frame["depth_m_f32le"], "<f4").reshape(h, w)
    mask = np.asarray(Image.open(io.BytesIO(frame["instance_mask_png"])))
    return rgb, depth, mask


def frame_camera(frame: dict) -> geo.Camera:
    t = geo.pose_matrix(frame["world_camera_quat_wxyz"], frame["world_camera_translation_m"])
    return geo.Camera(
        frame["width"], frame["height"], frame["fx"], frame["fy"], frame["cx"], frame["cy"], t
    )


CLUTTER_SIZE = 128


@pytest.fixture(scope="module")
def clutter(session):
    """A cluttered scene (boxes close together, one stacked) at 128², 1 sample, 3 views."""
    text = recipe_text("clutter", CLUTTER_SIZE, CLUTTER_SIZE, frames=3, samples=1, denoise=False)
    scene, objects = synthetic_scene(0, text, 6, seed=4, stack=True, spread_m=0.12)
    session.load(scene, objects)
    renders = [session.render(f) for f in range(3)]
    return scene, objects, renders


def test_frame_row_contents(clutter):
    scene, objects, renders = clutter
    frame, instances = renders[0]
    assert (frame["width"], frame["height"]) == (CLUTTER_SIZE, CLUTTER_SIZE)
    assert frame["fx"] == frame["fy"] and frame["cx"] == frame["cy"] == (CLUTTER_SIZE - 1) / 2
    assert frame["samples"] == 1 and frame["denoise"] is False
    assert frame["render_seed"] == sampling.render_seed(scene["seed"], 0)
    settings = json.loads(frame["render_settings"])
    assert settings["cycles_seed"] == frame["render_seed"] and settings["crop"] is None
    assert frame["blender_version"].startswith("5.0")
    rgb, depth, mask = decode(frame)
    assert rgb.shape == (CLUTTER_SIZE, CLUTTER_SIZE, 3) and rgb.dtype == np.uint8 and rgb.std() > 1
    assert mask.dtype == np.uint16
    assert [i["object_id"] for i in instances] == list(range(len(objects)))


def test_depth_is_planar_z_and_matches_the_intrinsics(session):
    """On the floor (z = 0), the rendered depth equals the planar depth of the ray through each
    pixel centre, computed from the stored intrinsics and pose: this pins down the depth
    convention (planar, not ray length) and the camera model to far below a pixel."""
    text = recipe_text("tiny", 96, 72, frames=2)
    scene, objects = synthetic_scene(2, text, 3, seed=8)
    session.load(scene, objects)
    for frame_id in range(2):
        frame, _ = session.render(frame_id)
        _, depth, mask = decode(frame)
        cam = frame_camera(frame)
        v, u = np.nonzero((mask == 0) & (depth > 0))
        rays = np.stack(
            [(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, dtype=float)], axis=1
        )
        rays_world = rays @ cam.world_camera[:3, :3].T
        c = cam.centre
        planar = -c[2] / rays_world[:, 2]  # z = 1 along each ray, so the scale is the planar depth
        assert len(u) > 3000
        assert np.allclose(depth[v, u], planar, rtol=1e-4, atol=1e-5)
        ray_length = planar * np.linalg.norm(rays, axis=1)
        assert not np.allclose(depth[v, u], ray_length, rtol=1e-3)


def _distance_to_polygon_edges(points: np.ndarray, hull: np.ndarray) -> np.ndarray:
    d = np.full(len(points), np.inf)
    for k in range(len(hull)):
        a, b = hull[k], hull[(k + 1) % len(hull)]
        ab = b - a
        s = np.clip(((points - a) @ ab) / (ab @ ab), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(points - (a + s[:, None] * ab), axis=1))
    return d


def test_masks_agree_with_projected_corners(clutter):
    """Every box's mask lies inside the convex hull of its projected corners, and where nothing
    occludes it the two agree to within half a pixel of the hull's edges."""
    for frame, instances in clutter[2]:
        _, depth, mask = decode(frame)
        cam = frame_camera(frame)
        for inst in instances:
            corners = np.array(inst["corners_camera_m"]).reshape(8, 3)
            px = np.array(inst["corners_px"]).reshape(8, 2)
            assert np.allclose(px, cam.project(corners), atol=1e-9)
            own = mask == inst["object_id"] + 1
            silhouette = geo.silhouette_mask(cam, corners)
            hull = geo.convex_hull_2d(px)
            v, u = np.nonzero(own & ~silhouette)
            assert (_distance_to_polygon_edges(np.stack([u, v], 1).astype(float), hull) < 0.5).all()
            # silhouette pixels (away from its edges) that show something else show something nearer
            v, u = np.nonzero(silhouette & ~own)
            away = _distance_to_polygon_edges(np.stack([u, v], 1).astype(float), hull) > 0.5
            d = depth[v[away], u[away]]
            assert ((d > 0) & (d < corners[:, 2].max())).all()
            assert inst["visible_pixels"] == int(own.sum())
            assert 0.0 <= inst["visible_fraction"] <= 1.0
            if silhouette.sum():
                assert inst["visible_fraction"] == pytest.approx(
                    own.sum() / silhouette.sum(), abs=1e-6
                )


def test_masks_partition_the_image(clutter):
    for frame, instances in clutter[2]:
        _, _, mask = decode(frame)
        ids = set(np.unique(mask).tolist())
        assert ids <= {0} | {i["object_id"] + 1 for i in instances}
        assert sum(i["visible_pixels"] for i in instances) + int((mask == 0).sum()) == mask.size
        for inst in instances:
            own = mask == inst["object_id"] + 1
            if inst["visible_bbox_px"] is None:
                assert not own.any()
                continue
            x0, y0, x1, y1 = inst["visible_bbox_px"]
            assert own[y0:y1, x0:x1].sum() == own.sum()
            assert (
                own[y0, x0:x1].any()
                and own[y1 - 1, x0:x1].any()
                and own[y0:y1, x0].any()
                and own[y0:y1, x1 - 1].any()
            )


def _own_slope(depth: np.ndarray, own: np.ndarray, u: int, v: int) -> float:
    """Largest depth step between neighbouring pixels of the box's own mask in a 5×5 window."""
    ys, xs = slice(max(v - 2, 0), v + 3), slice(max(u - 2, 0), u + 3)
    d, o = depth[ys, xs].astype(float), own[ys, xs]
    steps = [
        np.abs(d[:, 1:] - d[:, :-1])[o[:, 1:] & o[:, :-1]],
        np.abs(d[1:] - d[:-1])[o[1:] & o[:-1]],
    ]
    steps = np.concatenate(steps)
    return float(steps.max()) if steps.size else 0.0


def test_corner_visibility_agrees_with_the_render(clutter):
    """Visible corners: nothing nearer than the corner at its pixel (within the depth slope of two
    pixels), and the box's own mask at or next to it. Occluded by another object: another
    object nearer than the corner at or next to its pixel. Self-occluded: the box's own surface
    in front of the corner at or next to its pixel. Outside: off the image or behind the camera."""
    counts = {VISIBLE: 0, OCCLUDED_BY_OTHER: 0, SELF_OCCLUDED: 0, OUTSIDE_IMAGE: 0, "boundary": 0}
    for frame, instances in clutter[2]:
        _, depth, mask = decode(frame)
        h, w = depth.shape
        for inst in instances:
            corners = np.array(inst["corners_camera_m"]).reshape(8, 3)
            px = np.array(inst["corners_px"]).reshape(8, 2)
            for k in range(8):
                state = inst["corner_visibility"][k]
                counts[state] += 1
                z = corners[k, 2]
                u, v = int(round(px[k, 0])), int(round(px[k, 1]))
                if state == OUTSIDE_IMAGE:
                    assert (
                        z <= 0
                        or not (0 <= u < w and 0 <= v < h)
                        or abs(px[k, 0] - u) > 0.49
                        or abs(px[k, 1] - v) > 0.49
                    )
                    continue
                assert 0 <= u < w and 0 <= v < h
                ys, xs = slice(max(v - 1, 0), v + 2), slice(max(u - 1, 0), u + 2)
                d, m, own = depth[ys, xs], mask[ys, xs], inst["object_id"] + 1
                if state == VISIBLE:
                    # 5 mm plus 1.5 pixels of the steepest depth slope of the box's own surface
                    # around the corner (faces seen at grazing angles change fast per pixel)
                    tol = 0.005 + 1.5 * _own_slope(depth, mask == own, u, v)
                    in_front = depth[v, u] > 0 and depth[v, u] < z - tol
                    if in_front or not (m == own).any():
                        # Only at an occlusion boundary, where no pixel centre near the corner sees
                        # it: the corner is a vertex of its own silhouette next to a face seen
                        # edge-on, or it peeks out from behind another box by under a pixel.
                        # (A corner hidden behind its own box lies inside its own silhouette.)
                        own_edge = _distance_to_polygon_edges(
                            px[k : k + 1], geo.convex_hull_2d(px)
                        )[0]
                        edges = [
                            _distance_to_polygon_edges(
                                px[k : k + 1],
                                geo.convex_hull_2d(np.array(o["corners_px"]).reshape(8, 2)),
                            )[0]
                            for o in instances
                            if o is not inst
                        ]
                        other_in_front = in_front and mask[v, u] != own
                        assert (own_edge < 1e-6 and not other_in_front) or min(edges) < 1.0, (
                            inst["object_id"],
                            k,
                        )
                        counts["boundary"] += 1
                elif state == OCCLUDED_BY_OTHER:  # another object (box or support) is in front
                    assert ((m != own) & (d > 0) & (d < z)).any(), (inst["object_id"], k, state)
                else:  # the box's own faces are in front
                    assert ((m == own) & (d < z - 0.005)).any(), (inst["object_id"], k, state)
    assert counts[VISIBLE] > 20 and counts[SELF_OCCLUDED] > 5 and counts[OCCLUDED_BY_OTHER] >= 1, (
        counts
    )
    assert counts["boundary"] <= 0.1 * counts[VISIBLE], counts


def test_pose_matches_the_objects_rows(clutter):
    _, objects, renders = clutter
    for frame, instances in renders:
        cam = frame_camera(frame)
        for o, inst in zip(objects, instances, strict=True):
            world_box = geo.pose_matrix(o["world_box_quat_wxyz"], o["world_box_translation_m"])
            camera_box = geo.pose_matrix(
                inst["camera_box_quat_wxyz"], inst["camera_box_translation_m"]
            )
            assert np.allclose(cam.world_camera @ camera_box, world_box, atol=1e-9)
            assert np.allclose(
                np.array(inst["corners_camera_m"]).reshape(8, 3),
                geo.transform(camera_box, geo.box_corners(o["size_m"])),
                atol=1e-9,
            )
            if o["has_label"]:
                assert (
                    inst["label_keypoints_camera_m"] is not None
                    and len(inst["label_keypoints_px"]) == 8
                )
            else:
                assert (
                    inst["label_keypoints_camera_m"] is None and inst["label_keypoints_px"] is None
                )


def test_rerender_is_identical(session, clutter):
    scene, objects, renders = clutter
    session.load(scene, objects)
    frame, instances = session.render(1)
    first_frame, first_instances = renders[1]
    assert instances == first_instances
    for key in (
        "depth_m_f32le",
        "instance_mask_png",
        "render_seed",
        "render_settings",
        "fx",
        "world_camera_quat_wxyz",
    ):
        assert frame[key] == first_frame[key], key
    a, b = decode(frame)[0].astype(int), decode(first_frame)[0].astype(int)
    assert np.abs(a - b).mean() < 2.0


def test_crop_render_matches_the_full_render(session, clutter):
    scene, objects, renders = clutter
    session.load(scene, objects)
    full, full_instances = renders[0]
    x0, y0, x1, y1 = 30, 40, 94, 90
    frame, instances = session.render(0, crop=(x0, y0, x1, y1))
    assert (frame["width"], frame["height"]) == (x1 - x0, y1 - y0)
    assert (frame["cx"], frame["cy"]) == (full["cx"] - x0, full["cy"] - y0)
    assert json.loads(frame["render_settings"])["crop"] == [x0, y0, x1, y1]
    rgb, depth, mask = decode(frame)
    full_rgb, full_depth, full_mask = decode(full)
    assert rgb.shape == (y1 - y0, x1 - x0, 3)
    assert np.array_equal(mask, full_mask[y0:y1, x0:x1])
    assert np.allclose(depth, full_depth[y0:y1, x0:x1], atol=1e-6)
    for a, b in zip(instances, full_instances, strict=True):
        assert np.allclose(
            np.array(a["corners_px"]).reshape(8, 2),
            np.array(b["corners_px"]).reshape(8, 2) - [x0, y0],
        )
        assert a["corners_camera_m"] == b["corners_camera_m"]


def test_a_scaled_render_is_the_same_view_smaller(session, clutter):
    scene, objects, renders = clutter
    session.load(scene, objects)
    full, full_instances = renders[0]
    frame, instances = session.render(0, width=full["width"] // 2)
    assert (frame["width"], frame["height"]) == (full["width"] // 2, full["height"] // 2)
    assert frame["fx"] == pytest.approx(full["fx"] / 2)
    assert json.loads(frame["render_settings"])["scaled_from"] == [full["width"], full["height"]]
    for a, b in zip(instances, full_instances, strict=True):
        px, full_px = (np.array(i["corners_px"]).reshape(8, 2) for i in (a, b))
        assert np.allclose(px, (full_px - 0.5) / 2, atol=1e-6)
        assert a["corners_camera_m"] == b["corners_camera_m"]
    # at or above the recipe's width: the recipe's frame
    same, _ = session.render(0, width=full["width"])
    assert json.loads(same["render_settings"])["scaled_from"] is None
    assert (same["width"], same["fx"]) == (full["width"], full["fx"])
    with pytest.raises(Exception, match="width, or crop"):
        session.render(0, width=10, crop=(0, 0, 4, 4))


def test_a_crop_whose_edges_float32_cannot_hold_renders_its_exact_size(session):
    # Blender keeps the border in float32 and truncates border × size: at 480 rows the edge at
    # 250 (and 63, 125–127, 252, 254) used to come back a pixel short, the render a row too tall
    text = recipe_text("clutter", 640, 480, frames=1, samples=1, denoise=False)
    scene, objects = synthetic_scene(0, text, 2, seed=4)
    session.load(scene, objects)
    for x0, y0, x1, y1 in [(200, 220, 212, 230), (320, 226, 336, 254), (0, 354, 8, 417)]:
        frame, _ = session.render(0, crop=(x0, y0, x1, y1))
        assert (frame["width"], frame["height"]) == (x1 - x0, y1 - y0)


def test_changed_pose_moves_only_that_box(session, clutter):
    scene, objects, renders = clutter
    session.load(scene, objects)
    o = objects[1]
    moved = geo.pose_matrix(o["world_box_quat_wxyz"], o["world_box_translation_m"])
    moved[:3, 3] += [0.0, 0.0, 0.05]
    frame, instances = session.render(0, poses={1: moved})
    cam = frame_camera(frame)
    camera_box = geo.pose_matrix(
        instances[1]["camera_box_quat_wxyz"], instances[1]["camera_box_translation_m"]
    )
    assert np.allclose(cam.world_camera @ camera_box, moved, atol=1e-9)
    assert frame["world_camera_translation_m"] == renders[0][0]["world_camera_translation_m"]
    assert instances[0]["corners_camera_m"] == renders[0][1][0]["corners_camera_m"]
    assert "1" in json.loads(frame["render_settings"])["pose_overrides"]
    # and back: without the override the original rendering returns
    again, _ = session.render(0)
    assert again["instance_mask_png"] == renders[0][0]["instance_mask_png"]


def test_sensor_depth_channel(session, clutter):
    scene, objects, _ = clutter
    session.load(scene, objects)
    frame, _ = session.render(2, sensor_depth=True)
    _, depth, _ = decode(frame)
    noisy = np.frombuffer(frame["sensor_depth_m_f32le"], "<f4").reshape(depth.shape)
    valid = noisy > 0
    assert 0.5 < valid.mean() < 1.0  # holes at edges, shadows, grazing angles
    assert not (valid & (depth == 0)).any()
    assert np.median(np.abs(noisy[valid] - depth[valid])) < 0.01
    assert json.loads(frame["render_settings"])["sensor_depth"]["model"] == "structured_light"


def test_tape_along_long_reaches_the_render(session):
    """One scene, every box taped and labelled, rendered with "random" and with "long": "long"
    moves the tape and labels (the pixels change where "random" drew the short side) and nothing
    else (same depth and masks), and the label keypoints of the ground truth follow the longer
    side of each box's top face."""
    text = (
        recipe_text("tiny", 48, 48)
        .replace("tape_probability = 0.7", "tape_probability = 1.0")
        .replace("label_probability = 0.6", "label_probability = 1.0")
    )
    scene, objects = synthetic_scene(3, text, 3, seed=11, spread_m=0.08)
    long_text = text.replace("[materials]\n", '[materials]\ntape_along = "long"\n')
    renders = {}
    for tape_along, recipe_toml in (("random", text), ("long", long_text)):
        session.load({**scene, "recipe_toml": recipe_toml}, objects)
        renders[tape_along] = session.render(0)
    random_looks = [
        sampling.draw_appearance(o["texture_seed"], o["size_m"], True, True, tape_along="random")
        for o in objects
    ]
    assert any(
        look.tape.axis != int(o["size_m"][1] > o["size_m"][0])
        for look, o in zip(random_looks, objects, strict=True)
    ), "every box drew its long side at random: choose another seed"
    (random_frame, _), (long_frame, long_instances) = renders["random"], renders["long"]
    rgb_random, depth_random, mask_random = decode(random_frame)
    rgb_long, depth_long, mask_long = decode(long_frame)
    assert np.array_equal(depth_random, depth_long) and np.array_equal(mask_random, mask_long)
    assert np.abs(rgb_long.astype(int) - rgb_random.astype(int)).max() > 20
    for instance in long_instances:
        assert np.allclose(label_u_in_box(instance), long_side_unit(instance["size_m"]))


def test_a_box_region_recipe_renders_each_frame_as_the_region_around_one_box(session, clutter):
    """`camera.region = "box"`: frame f is the region around the (f mod n)-th box, the same
    pixels, depth and masks as that region of the whole frame, its intrinsics shifted to it, the
    box whole inside it; `render_settings` record the region, so `crop` re-renders it."""
    scene, objects, renders = clutter
    text = scene["recipe_toml"].replace("[camera]\n", '[camera]\nregion = "box"\n')
    assert parse_render_recipe(text).camera.region == "box"
    session.load({**scene, "recipe_toml": text}, objects)
    object_ids = sorted(int(o["object_id"]) for o in objects)
    for frame_id, (full, _) in enumerate(renders):
        frame, instances = session.render(frame_id)
        x0, y0, x1, y1 = json.loads(frame["render_settings"])["crop"]
        assert (frame["width"], frame["height"]) == (x1 - x0, y1 - y0)
        assert frame["width"] * frame["height"] < CLUTTER_SIZE**2
        assert (frame["cx"], frame["cy"]) == (full["cx"] - x0, full["cy"] - y0)
        rgb, depth, mask = decode(frame)
        _, full_depth, full_mask = decode(full)
        assert np.array_equal(mask, full_mask[y0:y1, x0:x1])
        assert np.allclose(depth, full_depth[y0:y1, x0:x1], atol=1e-6)
        target = object_ids[frame_id % len(object_ids)]
        corners = np.array(instances[object_ids.index(target)]["corners_px"]).reshape(8, 2)
        inside = (corners >= -0.5) & (corners <= [x1 - x0 - 0.5, y1 - y0 - 0.5])
        assert inside.all(), (frame_id, target, corners)
        # the region is 1.75 × the box's projected extent (the default margin), clipped to the image
        extent = (corners.max(axis=0) - corners.min(axis=0)).max()
        assert max(x1 - x0, y1 - y0) <= 1.75 * extent + 6
        again, _ = session.render(frame_id, crop=(x0, y0, x1, y1))
        assert again["rgb_png"] == frame["rgb_png"]
    session.load(scene, objects)  # the shared session as the other tests expect it


@pytest.mark.parametrize("support", ["bin", "pallet"])
def test_other_supports_render(session, support):
    text = (
        recipe_text("tiny")
        .replace('kind = "floor"', f'kind = "{support}"')
        .replace("wall_height_m = 0.0", "wall_height_m = 0.1")
    )
    scene, objects = synthetic_scene(1, text, 2, seed=3)
    session.load(scene, objects)
    frame, instances = session.render(0)
    _, depth, mask = decode(frame)
    assert (depth > 0).all() and len(instances) == 2
    if support == "pallet":  # boxes stand on the pallet's top
        assert min(
            o["world_box_translation_m"][2] - o["size_m"][2] / 2 for o in objects
        ) == pytest.approx(0.144)


def test_rectangular_support_from_drake_to_blender(session, tmp_path):
    """A bin over a 0.6 × 0.4 m region, end to end: the Drake stage settles a scene in it and the
    Blender stage builds the same walls (compared with drake_scenes.plant.support_boxes) and
    renders it."""
    from drake_scenes.plant import support_boxes

    text = (
        with_half_extent(recipe_text("tiny", 48, 48), "[0.3, 0.2]")
        .replace('kind = "floor"', 'kind = "bin"')
        .replace("wall_height_m = 0.0", "wall_height_m = 0.1")
    )
    recipe_path, out = tmp_path / "rect.toml", tmp_path / "out"
    recipe_path.write_text(text)
    result = subprocess.run(
        [sys.executable, "-m", "drake_scenes", "--recipe", recipe_path, "--out", out]
        + ["--num-scenes", "1", "--no-progress"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    rows = {
        t: pq.read_table(boxpose_io.shard_path(out, t, 0, 1)).to_pylist()
        for t in ("scenes", "objects")
    }
    (scene,), objects = rows["scenes"], rows["objects"]
    for o in objects:  # boxes settled inside the rectangle
        assert abs(o["world_box_translation_m"][0]) < 0.3
        assert abs(o["world_box_translation_m"][1]) < 0.2

    session.load(scene, objects)
    assert session.recipe.support.half_extent_m == (0.3, 0.2)
    import bpy

    for name, size, centre in support_boxes(Recipe.from_toml(scene["recipe_toml"]).support):
        if name.startswith("wall"):
            wall = bpy.data.objects[f"support_{name}"]
            assert np.allclose(wall.dimensions, size) and np.allclose(wall.location, centre)
    frame, instances = session.render(0)
    _, depth, _ = decode(frame)
    assert (depth > 0).all() and len(instances) == len(objects)


def test_boxes_off_the_image_and_behind_the_camera(session, clutter):
    scene, objects, renders = clutter
    session.load(scene, objects)
    cam = frame_camera(renders[0][0])
    far = np.eye(4)
    far[:3, 3] = [5.0, 5.0, 0.1]  # on the floor, far outside the view
    behind = cam.world_camera.copy()
    behind[:3, 3] = (
        cam.world_camera[:3, 3] - 0.5 * cam.world_camera[:3, 2]
    )  # half a metre behind the camera
    frame, instances = session.render(0, poses={0: far, 1: behind})
    _, _, mask = decode(frame)
    for oid in (0, 1):
        inst = instances[oid]
        assert inst["corner_visibility"] == [OUTSIDE_IMAGE] * 8
        assert (
            inst["visible_pixels"] == 0
            and inst["visible_bbox_px"] is None
            and inst["visible_fraction"] == 0.0
        )
        assert not (mask == oid + 1).any()
        assert np.isfinite(inst["corners_px"]).all()
