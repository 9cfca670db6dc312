"""Rendering sessions: load a scene (its `scenes` row and `objects` rows) into Blender once, then
render any of its frames, at any sample count, optionally a crop region or with changed box
poses, and get `frames` / `instances` rows back.

This is the API the dataset worker (`blender_scripts.worker`) and the Rust crate `boxpose-render`
(through pyo3, `render_batches`) use. The frame's camera and lights are drawn from the frame's
render seed, which derives from the scene seed and frame_id, so a frame re-renders exactly from
the rows alone.
"""

from __future__ import annotations

import io
import json
import time

import numpy as np
import pyarrow as pa
from PIL import Image

from blender_scripts import VERSION, geometry as geo, sampling, sensor
from blender_scripts.groundtruth import BoxState, instance_row
from blender_scripts.recipe import RenderRecipe, parse_render_recipe

_SENSOR_TAG = 0x53454E53  # "SENS"


class RenderInputError(ValueError):
    """Scene and object rows that do not fit together; the message names the scene and object."""


def check_scene_objects(
    scenes: list[dict], objects: list[dict], where: str = ""
) -> dict[int, list[dict]]:
    """Groups object rows by scene, checking that every object's scene exists and that every scene
    has exactly its `num_objects` objects with ids 0..n−1. Returns {scene_id: objects sorted}."""
    suffix = f" in {where}" if where else ""
    by_scene: dict[int, list[dict]] = {int(s["scene_id"]): [] for s in scenes}
    if len(by_scene) != len(scenes):
        raise RenderInputError(f"duplicate scene_id in scenes{suffix}")
    for o in objects:
        sid = int(o["scene_id"])
        if sid not in by_scene:
            raise RenderInputError(
                f"objects row (scene_id={sid}, object_id={o['object_id']}){suffix} "
                f"references scene {sid}, which is not in the scenes table"
            )
        by_scene[sid].append(o)
    for s in scenes:
        sid = int(s["scene_id"])
        rows = sorted(by_scene[sid], key=lambda o: int(o["object_id"]))
        ids = [int(o["object_id"]) for o in rows]
        n = int(s["num_objects"])
        if ids != list(range(n)):
            missing = sorted(set(range(n)) - set(ids))
            extra = sorted(set(ids) - set(range(n)))
            raise RenderInputError(
                f"scene {sid}{suffix} declares num_objects={n} but objects holds object_ids {ids}"
                + (f"; missing {missing}" if missing else "")
                + (f"; unexpected {extra}" if extra else "")
            )
        by_scene[sid] = rows
    return by_scene


def _png(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def _pose_override(value) -> np.ndarray:
    """A pose override as a 4×4 matrix, or (quat_wxyz, translation)."""
    if isinstance(value, np.ndarray) and value.shape == (4, 4):
        return value
    quat, translation = value
    return geo.pose_matrix(quat, translation)


class Session:
    """One Blender scene, re-rendered on demand. Create one per process (bpy is process-global)."""

    def __init__(self, threads: int = 0):
        import bpy  # noqa: F401  (fails here, clearly, when bpy is missing)

        from blender_scripts.scene import BlenderScene

        self.blender = BlenderScene(threads)
        self.scene_row: dict | None = None
        self.objects: list[dict] = []
        self.recipe: RenderRecipe | None = None
        self.loads = 0

    # -- loading --------------------------------------------------------------------------

    def load(self, scene_row: dict, object_rows: list[dict]) -> None:
        """Builds the Blender scene of one `scenes` row and its `objects` rows."""
        objects = check_scene_objects([scene_row], object_rows)[int(scene_row["scene_id"])]
        self.recipe = parse_render_recipe(
            scene_row["recipe_toml"], source=f"of scene {scene_row['scene_id']}"
        )
        if scene_row["support"] != self.recipe.support.kind:
            raise RenderInputError(
                f"scene {scene_row['scene_id']}: support '{scene_row['support']}' differs from "
                f"its recipe's '{self.recipe.support.kind}'"
            )
        self.scene_row = dict(scene_row)
        self.objects = objects
        self.world_boxes = {
            int(o["object_id"]): geo.pose_matrix(
                o["world_box_quat_wxyz"], o["world_box_translation_m"]
            )
            for o in objects
        }
        self.appearances = {
            int(o["object_id"]): sampling.draw_appearance(
                o["texture_seed"],
                o["size_m"],
                bool(o["has_tape"]),
                bool(o["has_label"]),
                tape_along=self.recipe.materials.tape_along,
            )
            for o in objects
        }
        self.support_look = sampling.draw_support_appearance(
            int(scene_row["seed"]), self.recipe.support.kind
        )
        boxes = [
            {
                "object_id": int(o["object_id"]),
                "size": o["size_m"],
                "world_box": self.world_boxes[int(o["object_id"])],
                "base_color": o["base_color_rgb"],
                "roughness": o["roughness"],
                "appearance": self.appearances[int(o["object_id"])],
            }
            for o in objects
        ]
        self.blender.build(self.recipe.support, self.support_look, boxes)
        self.loads += 1

    def load_batches(
        self,
        scenes: pa.RecordBatch | pa.Table,
        objects: pa.RecordBatch | pa.Table,
        scene_id: int | None = None,
    ) -> None:
        """`load` from Arrow data: `scenes` holds the scene (the first row, or `scene_id`),
        `objects` at least its objects (others are ignored)."""
        scene_rows = scenes.to_pylist()
        if scene_id is not None:
            scene_rows = [s for s in scene_rows if int(s["scene_id"]) == int(scene_id)]
        if not scene_rows:
            raise RenderInputError(
                f"scene {scene_id} is not in the scenes data"
                if scene_id is not None
                else "no scenes row given"
            )
        scene_row = scene_rows[0]
        sid = int(scene_row["scene_id"])
        self.load(scene_row, [o for o in objects.to_pylist() if int(o["scene_id"]) == sid])

    # -- rendering ------------------------------------------------------------------------

    def frame_draw(self, frame_id: int) -> tuple[int, geo.Camera, dict, dict]:
        """(render_seed, camera, camera draw, lighting) of a frame of the loaded scene. The look-at
        point derives from the settled poses of the objects rows (all boxes' centroid, or the
        recipe's `camera.look_at_object`), never from pose overrides."""
        seed = sampling.render_seed(int(self.scene_row["seed"]), frame_id)
        rng = np.random.default_rng(seed)
        aim = self.recipe.camera.look_at_object
        if aim is not None and aim not in self.world_boxes:
            raise RenderInputError(
                f"scene {self.scene_row['scene_id']}: camera.look_at_object = {aim} "
                "is not one of its object_ids"
            )
        centres = np.array(
            [m[:3, 3] for oid, m in self.world_boxes.items() if aim is None or oid == aim]
        )
        camera, draw = sampling.draw_camera(self.recipe.camera, centres, rng)
        lighting = sampling.draw_lighting(self.recipe.lighting, np.asarray(draw["look_at_m"]), rng)
        return seed, camera, draw, lighting

    def render(
        self,
        frame_id: int = 0,
        samples: int | None = None,
        denoise: bool | None = None,
        crop: tuple[int, int, int, int] | None = None,
        poses: dict | None = None,
        sensor_depth: bool | None = None,
        crop_object: tuple[int, float] | None = None,
        width: int | None = None,
    ) -> tuple[dict, list[dict]]:
        """Renders one frame of the loaded scene: its `frames` row and its `instances` rows.

        samples / denoise / sensor_depth default to the recipe's [render] values. `crop` =
        (x0, y0, x1, y1), max exclusive, renders only that region: the frame is then that
        region, with the principal point shifted by (x0, y0). `poses` = {object_id: 4×4
        T_world_box or (quat_wxyz, translation)} moves boxes for this render only.
        `crop_object` = (object_id, margin) renders only the region around that box: the square
        of side max(margin, 1) × the longer side of its projected corners' bounding box, centred
        on that box, plus 2 pixels (the search's ground-truth crops; the frame's
        `render_settings` record the region, so `crop` re-renders it exactly). Without either, a
        recipe with `camera.region = "box"` renders frame f as the region around the scene's
        (f mod box count)-th box in object_id order, with its `camera.region_margin`. `width`
        renders the whole frame smaller: `width` pixels across, the height and focal lengths
        scaled alike (`Camera.scaled`; the search's frame for a segmenter that reads a smaller
        image); at or above the recipe's width it changes nothing. It excludes `crop` and
        `crop_object`; the frame's `render_settings` record the recipe's size as `scaled_from`."""
        if self.scene_row is None:
            raise RenderInputError("no scene loaded")
        spec = self.recipe.render
        samples = spec.samples if samples is None else int(samples)
        denoise = spec.denoise if denoise is None else bool(denoise)
        sensor_depth = spec.sensor_depth if sensor_depth is None else bool(sensor_depth)
        poses = {int(k): _pose_override(v) for k, v in (poses or {}).items()}
        unknown = sorted(set(poses) - set(self.world_boxes))
        if unknown:
            raise RenderInputError(f"scene {self.scene_row['scene_id']} has no object_id {unknown}")

        seed, full_camera, camera_draw, lighting = self.frame_draw(frame_id)
        world_boxes = {oid: poses.get(oid, m) for oid, m in self.world_boxes.items()}
        if width is not None:
            if crop is not None or crop_object is not None:
                raise RenderInputError("give width, or crop / crop_object, not both")
            if isinstance(width, bool) or int(width) != width or width < 1:
                raise RenderInputError(f"width {width!r} must be a positive integer")
        elif crop is None and crop_object is None and self.recipe.camera.region == "box":
            object_ids = sorted(self.world_boxes)
            target = object_ids[int(frame_id) % len(object_ids)]
            crop_object = (target, self.recipe.camera.region_margin)
        if crop_object is not None:
            if crop is not None:
                raise RenderInputError("give crop or crop_object, not both")
            crop = self._region_around(full_camera, world_boxes, *crop_object)
        if crop is not None:
            # an argument error (one line), not a failure inside Blender (a traceback)
            x0, y0, x1, y1 = (int(v) for v in crop)
            w, h = full_camera.width, full_camera.height
            if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
                raise RenderInputError(
                    f"crop {tuple(crop)} is not a non-empty region of the {w}×{h} image"
                )
        recipe_size = [full_camera.width, full_camera.height]
        scaled = width is not None and int(width) < full_camera.width
        if scaled:
            full_camera = full_camera.scaled(int(width))
        camera = full_camera if crop is None else full_camera.crop(*crop)
        b = self.blender
        for oid, m in world_boxes.items():
            b.set_box_pose(oid, m)
        b.set_camera(full_camera)
        b.set_lighting(lighting)
        start = time.perf_counter()
        out = b.render(
            samples, denoise, seed, spec.max_bounces, spec.view_transform, spec.exposure, crop
        )

        b.update()
        sid = int(self.scene_row["scene_id"])
        instances = []
        for o in self.objects:
            oid = int(o["object_id"])
            box = BoxState(oid, tuple(o["size_m"]), world_boxes[oid], self.appearances[oid])
            instances.append(
                instance_row(
                    sid, frame_id, camera, box, out.index, b.ray_cast, self.recipe.contact_m
                )
            )

        sensor_bytes, sensor_settings = None, None
        if sensor_depth:
            model = sensor.SensorModel()
            sensor_seed = sampling.derive_seed(seed, _SENSOR_TAG)
            noisy = sensor.simulate(
                out.depth,
                camera.fx,
                camera.fy,
                camera.cx,
                camera.cy,
                np.random.default_rng(sensor_seed),
                model,
            )
            sensor_bytes = noisy.astype("<f4").tobytes()
            sensor_settings = {"model": "structured_light", "seed": sensor_seed, **model.as_dict()}

        import bpy

        settings = {
            "format": 1,
            "blender_scripts": VERSION,
            **b.settings(),
            "cycles_seed": seed,
            "max_bounces": spec.max_bounces,
            "view_transform": spec.view_transform,
            "look": "None",
            "exposure": spec.exposure,
            "image_size": [full_camera.width, full_camera.height],
            "crop": list(crop) if crop is not None else None,
            "scaled_from": recipe_size if scaled else None,
            "camera": camera_draw,
            "lighting": lighting,
            "support": {"kind": self.recipe.support.kind, **self.support_look},
            "pose_overrides": {
                str(k): dict(zip(("quat_wxyz", "translation_m"), geo.pose_parts(v), strict=True))
                for k, v in sorted(poses.items())
            },
            "sensor_depth": sensor_settings,
            "contact_tolerance_m": self.recipe.contact_m,
        }
        quat, translation = geo.pose_parts(camera.world_camera)
        frame = {
            "scene_id": sid,
            "frame_id": int(frame_id),
            "width": camera.width,
            "height": camera.height,
            "fx": camera.fx,
            "fy": camera.fy,
            "cx": camera.cx,
            "cy": camera.cy,
            "world_camera_quat_wxyz": quat,
            "world_camera_translation_m": translation,
            "render_seed": seed,
            "samples": samples,
            "denoise": denoise,
            "blender_version": bpy.app.version_string,
            "render_settings": json.dumps(settings, sort_keys=True),
            "render_time_s": out.seconds,
            "rgb_png": out.rgb_png,
            "depth_m_f32le": out.depth.astype("<f4").tobytes(),
            "instance_mask_png": _png(out.index),
            "sensor_depth_m_f32le": sensor_bytes,
        }
        self.last_timing = {"render_s": out.seconds, "total_s": time.perf_counter() - start}
        return frame, instances

    def _region_around(
        self, camera: geo.Camera, world_boxes: dict, object_id: int, margin: float
    ) -> tuple[int, int, int, int] | None:
        """The pixel region of `render(crop_object=…)`; None (the whole frame) when the box is
        partly behind the camera, or its region leaves nothing of the image."""
        object_id, margin = int(object_id), float(margin)
        if object_id not in world_boxes:
            raise RenderInputError(
                f"scene {self.scene_row['scene_id']} has no object_id {object_id}"
            )
        if not (np.isfinite(margin) and margin >= 0):
            raise RenderInputError(f"crop_object margin {margin} must be finite and non-negative")
        size = next(o["size_m"] for o in self.objects if int(o["object_id"]) == object_id)
        corners = geo.transform(camera.camera_world @ world_boxes[object_id], geo.box_corners(size))
        if (corners[:, 2] <= 0).any():
            return None
        uv = camera.project(corners)
        (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
        half = max(margin, 1.0) * max(u1 - u0, v1 - v0) / 2 + 2.0  # 2 px for the resampling kernel
        (cu, cv) = ((u0 + u1) / 2, (v0 + v1) / 2)
        # pixel i covers [i − 0.5, i + 0.5)
        x0, y0 = max(0, int(np.floor(cu - half + 0.5))), max(0, int(np.floor(cv - half + 0.5)))
        x1, y1 = (
            min(camera.width, int(np.ceil(cu + half + 0.5))),
            min(camera.height, int(np.ceil(cv + half + 0.5))),
        )
        return (x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None

    def render_batches(
        self,
        frame_id: int = 0,
        samples=None,
        denoise=None,
        crop=None,
        poses=None,
        sensor_depth=None,
        crop_object=None,
        width=None,
    ) -> tuple[pa.RecordBatch, pa.RecordBatch]:
        """`render` as Arrow record batches with the contract schemas (for the Rust side)."""
        frame, instances = self.render(
            frame_id, samples, denoise, crop, poses, sensor_depth, crop_object, width
        )
        return _batch("frames", [frame]), _batch("instances", instances)


def _batch(table: str, rows: list[dict]) -> pa.RecordBatch:
    import boxpose_io

    t = boxpose_io.table_from_rows(table, rows).combine_chunks()
    batches = t.to_batches()
    return batches[0] if batches else pa.RecordBatch.from_pylist([], schema=t.schema)
