"""Scene rows without Drake: boxes resting on the support, for tests, benchmarks and demos.

`synthetic_scene` returns a `scenes` row and its `objects` rows with every contract column
filled. Boxes stand upright on the support's top with a random yaw, apart from each other
(rejection sampling on bounding circles), optionally with one box stacked on another, so that
some corners are occluded by other boxes.
"""

from __future__ import annotations

import json
import math
import platform

import numpy as np

from blender_scripts import geometry as geo
from blender_scripts.recipe import parse_render_recipe
from boxpose_io import PALLET_HEIGHT_M


def _yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def synthetic_scene(
    scene_id: int,
    recipe_toml: str,
    num_boxes: int,
    seed: int,
    stack: bool = False,
    spread_m: float | None = None,
) -> tuple[dict, list[dict]]:
    recipe = parse_render_recipe(recipe_toml)
    rng = np.random.default_rng(seed)
    top = PALLET_HEIGHT_M if recipe.support.kind == "pallet" else 0.0
    hx, hy = recipe.support.half_extent_m
    spread = spread_m if spread_m is not None else 0.6 * min(hx, hy)
    sizes, placed = [], []
    for _ in range(num_boxes):
        size = rng.uniform([0.08, 0.06, 0.05], [0.18, 0.14, 0.12])
        for _attempt in range(500):
            xy = rng.uniform(-spread, spread, 2)
            radius = 0.5 * float(np.hypot(size[0], size[1]))
            if all(np.linalg.norm(xy - p[0]) > radius + p[1] + 0.005 for p in placed):
                break
            size = size * 0.99  # crowded: shrink until it fits
        placed.append((xy, radius))
        sizes.append(size)
    objects = []
    for k, (size, (xy, _r)) in enumerate(zip(sizes, placed, strict=True)):
        yaw = float(rng.uniform(0, 2 * math.pi))
        z = top + size[2] / 2
        if stack and k == num_boxes - 1 and num_boxes > 1:  # last box on top of the first one
            xy = placed[0][0] + rng.uniform(-0.01, 0.01, 2)
            z = top + sizes[0][2] + size[2] / 2
        quat = _yaw_quat(yaw)
        t = [float(xy[0]), float(xy[1]), float(z)]
        objects.append(
            {
                "scene_id": int(scene_id),
                "object_id": k,
                "size_m": [float(s) for s in size],
                "world_box_quat_wxyz": quat,
                "world_box_translation_m": t,
                "initial_world_box_quat_wxyz": quat,
                "initial_world_box_translation_m": [t[0], t[1], t[2] + 0.05],
                "mass_kg": float(np.prod(size) * 150.0),
                "friction": 0.7,
                "base_color_rgb": [
                    float(c)
                    for c in np.clip(
                        np.array([0.45, 0.30, 0.16]) * rng.uniform(0.7, 1.2)
                        + rng.uniform(-0.03, 0.03, 3),
                        0,
                        1,
                    )
                ],
                "roughness": float(rng.uniform(*recipe.materials.roughness)),
                "texture_seed": int(rng.integers(0, 2**62)),
                "has_tape": bool(rng.random() < recipe.materials.tape_probability),
                "has_label": bool(rng.random() < recipe.materials.label_probability),
            }
        )
    scene = {
        "scene_id": int(scene_id),
        "seed": int(seed),
        "recipe": recipe.name,
        "recipe_toml": recipe_toml,
        "tool_versions": json.dumps(
            {"python": platform.python_version(), "generator": "blender_scripts.synthetic"}
        ),
        "physics_backend": "none",
        "support": recipe.support.kind,
        "num_objects": num_boxes,
        "solver": "none",
        "solver_status": "synthetic",
        "solve_attempts": 0,
        "settle_time_s": 0.0,
        "max_linear_speed_mps": 0.0,
        "max_angular_speed_radps": 0.0,
        "min_signed_distance_m": 0.0,
        "stable": True,
    }
    return scene, objects


def box_world_corners(obj: dict) -> np.ndarray:
    return geo.transform(
        geo.pose_matrix(obj["world_box_quat_wxyz"], obj["world_box_translation_m"]),
        geo.box_corners(obj["size_m"]),
    )
