"""A plain NumPy baseline for `boxpose search --sut`: a box's pose from the principal axes of the
depth points of its mask, no network at all.

    boxpose search single_box --sut python:examples.sut.pca_baseline:perceive --out results/pca

The target's visible pixels (the ground-truth crop's mask: run with `--crops gt`) are
back-projected through the camera. Their principal axes, longest spread first, are taken as the
box's axes, longest side first; each axis is turned to point away from the camera, and the
centre is placed half a side behind the nearest points along each axis (the visible faces are
the near ones). What it cannot do is the point of a baseline: a quarter turn between two nearly
equal sides, and the spread of a partly hidden box, fool it.
"""

from __future__ import annotations

import numpy as np

from boxpose_io.sut import FitFailed, Request

#: Fewest depth points the fit needs (three faces' worth of a few pixels).
MIN_POINTS = 20


def back_project(request: Request) -> np.ndarray:
    """The mask's pixels with a depth, as camera-frame points (N × 3, metres)."""
    if request.mask is None:
        raise FitFailed("the PCA baseline needs the target's mask: run the search with --crops gt")
    v, u = np.nonzero(request.mask & (request.depth > 0))
    z = request.depth[v, u].astype(float)
    k = request.camera_matrix
    x = (u - k[0, 2]) * z / k[0, 0]
    y = (v - k[1, 2]) * z / k[1, 1]
    return np.column_stack([x, y, z])


def perceive(request: Request) -> dict | None:
    points = back_project(request)
    if len(points) < MIN_POINTS:
        raise FitFailed(f"{len(points)} depth points on the mask, fewer than {MIN_POINTS}")
    centroid = points.mean(axis=0)
    # principal axes, largest variance first
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    spread_axes = vt
    size = request.box_size_m
    # the box's axes by length, longest first, take the spread axes in that order
    by_length = np.argsort(-size)
    rotation = np.zeros((3, 3))
    for rank, box_axis in enumerate(by_length):
        axis = spread_axes[rank]
        if axis @ centroid < 0:  # away from the camera
            axis = -axis
        rotation[:, box_axis] = axis
    if np.linalg.det(rotation) < 0:  # a right-handed frame: flip the shortest side's axis
        rotation[:, by_length[2]] *= -1
    # the nearest points along each axis lie on the visible (near) face: the centre is half a
    # side behind them
    along = (points - centroid) @ rotation
    near = np.percentile(along, 2, axis=0)
    centre = centroid + rotation @ (near + size / 2)
    return {"rotation": rotation, "translation_m": centre}
