"""A simulated structured-light depth sensor (recipe `[render] sensor_depth = true`), in numpy.

Starts from the exact planar depth of the render and imitates an active stereo / structured-light
camera whose projector sits `baseline_m` to the right of the camera (along +x):

- projector shadows: pixels that the projector cannot see because a nearer surface lies between
  it and them (a band beside every depth discontinuity, as wide as the disparity jump);
- depth edges: pixels next to a discontinuity return nothing (mixed pixels are rejected);
- grazing angles: surfaces seen at more than `max_incidence_deg` return nothing, and dropout
  becomes likely from `dropout_start_deg` on;
- noise in the disparity domain (`disparity_noise_px`, Gaussian) and sub-pixel quantization of
  disparity (`subpixel_steps`), so the depth error grows with depth² as in real sensors;
- a working range [min_range_m, max_range_m].

Missing pixels are 0, like pixels without a surface in the exact depth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    baseline_m: float = 0.075
    disparity_noise_px: float = 0.07
    subpixel_steps: int = 8
    edge_threshold: float = 0.03  # relative depth jump between neighbours that marks an edge
    edge_dilate_px: int = 1
    max_incidence_deg: float = 78.0
    dropout_start_deg: float = 60.0
    min_range_m: float = 0.2
    max_range_m: float = 4.0

    def as_dict(self) -> dict:
        return asdict(self)


def _normals_cos(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """|cos| of the angle between each pixel's surface normal (from depth gradients) and its ray."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    p = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=-1)
    du = np.zeros_like(p)
    dv = np.zeros_like(p)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1, :] = p[2:, :] - p[:-2, :]
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    ray = p / np.maximum(np.linalg.norm(p, axis=-1, keepdims=True), 1e-12)
    cos = np.abs(np.sum(n * ray, axis=-1)) / np.maximum(norm, 1e-12)
    cos[norm < 1e-12] = 1.0
    return cos


def simulate(
    depth: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    rng: np.random.Generator,
    model: SensorModel = SensorModel(),
) -> np.ndarray:
    """The sensor's depth image (float32, metres, 0 = no return) for an exact planar depth image."""
    z = depth.astype(np.float64)
    valid = z > 0
    h, w = z.shape
    fb = fx * model.baseline_m
    disparity = np.where(valid, fb / np.where(valid, z, 1.0), 0.0)

    # Depth edges: a relative jump to any 4-neighbour, dilated.
    edge = np.zeros_like(valid)
    jump_x = np.abs(z[:, 1:] - z[:, :-1]) > model.edge_threshold * np.minimum(
        z[:, 1:], z[:, :-1]
    ).clip(1e-6)
    jump_y = np.abs(z[1:, :] - z[:-1, :]) > model.edge_threshold * np.minimum(
        z[1:, :], z[:-1, :]
    ).clip(1e-6)
    jump_x |= valid[:, 1:] != valid[:, :-1]
    jump_y |= valid[1:, :] != valid[:-1, :]
    edge[:, 1:] |= jump_x
    edge[:, :-1] |= jump_x
    edge[1:, :] |= jump_y
    edge[:-1, :] |= jump_y
    for _ in range(model.edge_dilate_px):
        grown = edge.copy()
        grown[:, 1:] |= edge[:, :-1]
        grown[:, :-1] |= edge[:, 1:]
        grown[1:, :] |= edge[:-1, :]
        grown[:-1, :] |= edge[1:, :]
        edge = grown

    # Projector shadows: with the projector at +x, pixel u is hidden from it when a pixel u + k
    # (k > 0) is nearer by more than k pixels of disparity.
    shadow = np.zeros_like(valid)
    max_shift = int(np.ceil(disparity.max() - disparity[valid].min())) if valid.any() else 0
    for k in range(1, min(max_shift, w - 1) + 1):
        shadow[:, :-k] |= disparity[:, k:] - disparity[:, :-k] > k

    cos = _normals_cos(z, fx, fy, cx, cy)
    incidence = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    span = max(model.max_incidence_deg - model.dropout_start_deg, 1e-6)
    p_drop = np.clip((incidence - model.dropout_start_deg) / span, 0.0, 1.0) ** 2
    dropout = rng.random(z.shape) < p_drop

    noisy = disparity + rng.normal(0.0, model.disparity_noise_px, z.shape)
    noisy = np.round(noisy * model.subpixel_steps) / model.subpixel_steps
    out = np.where(noisy > 0, fb / np.where(noisy > 0, noisy, 1.0), 0.0)
    keep = valid & ~edge & ~shadow & ~dropout & (incidence < model.max_incidence_deg)
    keep &= (out >= model.min_range_m) & (out <= model.max_range_m)
    return np.where(keep, out, 0.0).astype(np.float32)
