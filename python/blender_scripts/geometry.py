"""Camera and box geometry in numpy (no bpy): poses, the pinhole model, corners, silhouettes.

Conventions (docs/dataset.md, docs/design.md): metres; `T_a_b` is a 4×4 matrix mapping points in
frame b into frame a; quaternions are (w, x, y, z); the camera frame is OpenCV (x right, y down,
z forward); pixel coordinates put the centre of the top-left pixel at (0, 0); box corner i has
sign pattern bit0 → x, bit1 → y, bit2 → z (0 = −, 1 = +).

Blender's camera looks down its −z axis with y up. `blender_camera_matrix` is the one and only
place where that convention meets OpenCV's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from boxpose_io.rotations import matrix_to_quat, quat_to_matrix

# Corner i = (±dx/2, ±dy/2, ±dz/2) with bit0 → x, bit1 → y, bit2 → z.
CORNER_SIGNS = np.array(
    [[1 if (i >> k) & 1 else -1 for k in range(3)] for i in range(8)], dtype=np.float64
)
# The 12 edges of a box as pairs of corner indices (corners differing in exactly one bit).
BOX_EDGES = [(i, i | (1 << k)) for i in range(8) for k in range(3) if not (i >> k) & 1]
# Label corners on the +z face, same bit pattern in the label's own (u, v) axes: bit0 → u, bit1 → v.
LABEL_CORNER_SIGNS = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Rotations and poses


def pose_matrix(quat_wxyz, translation) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(quat_wxyz)
    t[:3, 3] = translation
    return t


def pose_parts(t: np.ndarray) -> tuple[list[float], list[float]]:
    """(quat_wxyz, translation) of a rigid 4×4 matrix, as plain lists for Arrow rows."""
    return matrix_to_quat(t[:3, :3]).tolist(), np.asarray(t[:3, 3], dtype=np.float64).tolist()


def invert(t: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def transform(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    return points @ t[:3, :3].T + t[:3, 3]


# ---------------------------------------------------------------------------------------------
# Camera


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size, intrinsics (pixels) and pose T_world_camera (OpenCV axes)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_camera: np.ndarray  # 4×4

    @staticmethod
    def from_hfov(width: int, height: int, hfov_rad: float, world_camera: np.ndarray) -> Camera:
        """Square pixels, principal point at the image centre: fx = fy = (W/2)/tan(hfov/2),
        cx = (W−1)/2, cy = (H−1)/2 (the top-left pixel's centre is (0, 0))."""
        f = 0.5 * width / math.tan(0.5 * hfov_rad)
        return Camera(width, height, f, f, 0.5 * (width - 1), 0.5 * (height - 1), world_camera)

    def crop(self, x0: int, y0: int, x1: int, y1: int) -> Camera:
        """The camera of the pixel region [x0, x1) × [y0, y1): same pose, principal point
        shifted."""
        return Camera(
            x1 - x0, y1 - y0, self.fx, self.fy, self.cx - x0, self.cy - y0, self.world_camera
        )

    def scaled(self, width: int) -> Camera:
        """The same view at `width` pixels across: height and focal lengths scaled by
        width / self.width (the height rounded), principal point at the new image's centre (a
        frame rendered smaller, as a network that reads a smaller image sees it)."""
        k = width / self.width
        height = max(1, round(self.height * k))
        return Camera(
            width,
            height,
            self.fx * k,
            self.fy * k,
            0.5 * (width - 1),
            0.5 * (height - 1),
            self.world_camera,
        )

    @property
    def camera_world(self) -> np.ndarray:
        return invert(self.world_camera)

    @property
    def centre(self) -> np.ndarray:
        return self.world_camera[:3, 3].copy()

    def project(self, points_camera: np.ndarray) -> np.ndarray:
        """Pixel coordinates (u, v) of camera-frame points. Points at or behind the camera
        plane give finite but meaningless values (they are flagged outside by the caller)."""
        p = np.atleast_2d(np.asarray(points_camera, dtype=np.float64))
        z = np.where(np.abs(p[:, 2]) < 1e-12, 1e-12, p[:, 2])
        return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)

    def in_image(self, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Whether projected points fall on the image (pixel areas, i.e. [−0.5, W−0.5)) in front of
        the camera."""
        u, v = uv[:, 0], uv[:, 1]
        return (
            (z > 0) & (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)
        )


def look_at(centre, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_camera (OpenCV axes) of a camera at `centre` looking at `target`, image-up
    towards world `up`."""
    centre, target, up = (np.asarray(v, dtype=np.float64) for v in (centre, target, up))
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along `up`: any image-right will do
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    t = np.eye(4)
    t[:3, 0], t[:3, 1], t[:3, 2], t[:3, 3] = x, y, z, centre
    return t


# OpenCV camera axes expressed in Blender camera axes: x → x, y → −y, z → −z (its own inverse).
_CV_TO_BLENDER_AXES = np.diag([1.0, -1.0, -1.0, 1.0])


def blender_camera_matrix(world_camera_opencv: np.ndarray) -> np.ndarray:
    """THE conversion between camera conventions: Blender's camera object matrix_world (camera
    looks down −z, y up) of a camera whose pose T_world_camera is given with OpenCV axes."""
    return np.asarray(world_camera_opencv, dtype=np.float64) @ _CV_TO_BLENDER_AXES


def blender_lens(camera: Camera, sensor_width_mm: float = 36.0) -> float:
    """Focal length (mm) for Blender with sensor_fit HORIZONTAL over `sensor_width_mm` giving
    exactly `camera.fx`. Blender's principal point is the image centre, i.e. (W−1)/2 in our
    pixel-centre convention, so no lens shift is needed when cx, cy are at the centre."""
    return camera.fx * sensor_width_mm / camera.width


# ---------------------------------------------------------------------------------------------
# Boxes


def box_corners(size) -> np.ndarray:
    """The 8 corners (8×3) in the box frame, in corner order."""
    return CORNER_SIGNS * (0.5 * np.asarray(size, dtype=np.float64))


def clip_box_to_near_plane(corners_camera: np.ndarray, near: float) -> np.ndarray:
    """Vertices of the box (given by its 8 camera-frame corners) clipped to z >= near: the kept
    corners plus the crossings of the 12 edges with the plane."""
    keep = [p for p in corners_camera if p[2] >= near]
    for i, j in BOX_EDGES:
        a, b = corners_camera[i], corners_camera[j]
        if (a[2] - near) * (b[2] - near) < 0:
            s = (near - a[2]) / (b[2] - a[2])
            keep.append(a + s * (b - a))
    return np.array(keep).reshape(-1, 3)


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (Andrew's monotone chain) of 2D points; may be degenerate."""
    pts = sorted(set(map(tuple, np.round(np.asarray(points, dtype=np.float64), 12))))
    if len(pts) <= 2:
        return np.array(pts).reshape(-1, 2)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def silhouette_mask(camera: Camera, corners_camera: np.ndarray, near: float = 1e-3) -> np.ndarray:
    """Pixels (H×W bool) whose centres see the box were nothing in front of it: the projected
    convex hull of the box clipped to the near plane. A box projects to a convex polygon."""
    mask = np.zeros((camera.height, camera.width), dtype=bool)
    verts = clip_box_to_near_plane(np.asarray(corners_camera, dtype=np.float64), near)
    if len(verts) < 3:
        return mask
    hull = convex_hull_2d(camera.project(verts))
    if len(hull) < 3:
        return mask
    x0 = max(int(math.floor(hull[:, 0].min())), 0)
    x1 = min(int(math.ceil(hull[:, 0].max())) + 1, camera.width)
    y0 = max(int(math.floor(hull[:, 1].min())), 0)
    y1 = min(int(math.ceil(hull[:, 1].max())) + 1, camera.height)
    if x0 >= x1 or y0 >= y1:
        return mask
    u, v = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    inside = np.ones(u.shape, dtype=bool)
    for k in range(len(hull)):
        (ax, ay), (bx, by) = hull[k], hull[(k + 1) % len(hull)]
        inside &= (bx - ax) * (v - ay) - (by - ay) * (u - ax) >= 0
    mask[y0:y1, x0:x1] = inside
    return mask
