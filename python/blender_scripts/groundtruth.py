"""Per-box ground truth of one rendered frame: pose in the camera frame, corners (camera frame and
pixels), 4-state corner visibility by ray casting, label keypoints, visible bbox and fraction.

Ray casting goes through a callback (`RayCast`) so that this module needs no bpy: the Blender
scene provides one backed by `scene.ray_cast`, tests can provide their own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blender_scripts import geometry as geo
from blender_scripts.sampling import BoxAppearance

VISIBLE, OCCLUDED_BY_OTHER, SELF_OCCLUDED, OUTSIDE_IMAGE = 0, 1, 2, 3

# A ray cast: (origin, unit direction, max distance) → None, or (hit location, unit surface
# normal, object_id of the box hit or −1 for anything else, e.g. the support).
RayCast = Callable[[np.ndarray, np.ndarray, float], "tuple[np.ndarray, np.ndarray, int] | None"]


@dataclass(frozen=True)
class BoxState:
    """One box as rendered: its objects row values and the pose it was rendered at."""

    object_id: int
    size: tuple[float, float, float]
    world_box: np.ndarray  # 4×4
    appearance: BoxAppearance


# Ray casts stop this far before the corner, so the corner's own faces never count as a hit.
END_EPSILON_M = 1e-4


def corner_visibility(
    camera: geo.Camera,
    box: BoxState,
    corners_world: np.ndarray,
    corners_camera: np.ndarray,
    corners_px: np.ndarray,
    ray_cast: RayCast,
    contact_m: float,
) -> list[int]:
    """Visibility of each corner:

    - outside (3): behind the camera or projecting off the image;
    - otherwise cast a ray from the camera centre to the corner: no hit → visible (0); the first
      hit is the box itself → self-occluded (2: the ray enters the box before reaching the
      corner, i.e. the corner is on a side facing away); the first hit is anything else →
      occluded by another object (1).

    A surface of another object that the corner touches (it lies within `contact_m` of the
    surface's plane, e.g. a bottom corner resting on the floor with a sliver of penetration)
    does not occlude it: the ray continues past such a hit.
    """
    centre = camera.centre
    inside = camera.in_image(corners_px, corners_camera[:, 2])
    out = []
    for k in range(8):
        if not inside[k]:
            out.append(OUTSIDE_IMAGE)
            continue
        target = corners_world[k]
        offset = target - centre
        length = float(np.linalg.norm(offset))
        direction = offset / length
        origin, travelled = centre, 0.0
        state = VISIBLE
        while True:
            remaining = length - END_EPSILON_M - travelled
            hit = ray_cast(origin, direction, remaining) if remaining > 0 else None
            if hit is None:
                break
            location, normal, object_id = hit
            if object_id == box.object_id:
                state = SELF_OCCLUDED
                break
            touching = abs(float(np.dot(normal, target - location))) < contact_m
            if touching and float(np.linalg.norm(target - location)) < 20.0 * contact_m:
                step = location + 1e-5 * direction
                travelled = float(np.dot(step - centre, direction))
                origin = step
                continue
            state = OCCLUDED_BY_OTHER
            break
        out.append(state)
    return out


def instance_row(
    scene_id: int,
    frame_id: int,
    camera: geo.Camera,
    box: BoxState,
    mask: np.ndarray,
    ray_cast: RayCast,
    contact_m: float,
) -> dict:
    """The `instances` row of one box in one frame (mask: the frame's instance mask,
    object_id + 1)."""
    camera_world = camera.camera_world
    camera_box = camera_world @ box.world_box
    corners_box = geo.box_corners(box.size)
    corners_world = geo.transform(box.world_box, corners_box)
    corners_camera = geo.transform(camera_box, corners_box)
    corners_px = camera.project(corners_camera)
    visibility = corner_visibility(
        camera, box, corners_world, corners_camera, corners_px, ray_cast, contact_m
    )

    label_camera = label_px = None
    if box.appearance.label is not None:
        lc = geo.transform(camera_box, box.appearance.label.corners_box(box.size))
        label_camera = lc.reshape(-1).tolist()
        label_px = camera.project(lc).reshape(-1).tolist()

    own = mask == box.object_id + 1
    visible_pixels = int(own.sum())
    bbox = None
    if visible_pixels:
        rows, cols = np.nonzero(own.any(axis=1))[0], np.nonzero(own.any(axis=0))[0]
        bbox = [int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1]
    silhouette = int(geo.silhouette_mask(camera, corners_camera).sum())
    fraction = min(visible_pixels / silhouette, 1.0) if silhouette else 0.0

    quat, translation = geo.pose_parts(camera_box)
    return {
        "scene_id": int(scene_id),
        "frame_id": int(frame_id),
        "object_id": int(box.object_id),
        "size_m": [float(s) for s in box.size],
        "camera_box_quat_wxyz": quat,
        "camera_box_translation_m": translation,
        "corners_camera_m": corners_camera.reshape(-1).tolist(),
        "corners_px": corners_px.reshape(-1).tolist(),
        "corner_visibility": visibility,
        "label_keypoints_camera_m": label_camera,
        "label_keypoints_px": label_px,
        "visible_bbox_px": bbox,
        "visible_pixels": visible_pixels,
        "visible_fraction": float(fraction),
    }
