"""Type stub of `boxpose.boxpose`, the compiled geometry core on numpy arrays
(rust/python/src/lib.rs), which `import boxpose` re-exports.

tests/test_packaging.py fails when a function's name, parameters, their kinds or defaults here
disagree with the compiled module's; the types follow the Rust extraction rules:

- point sets, poses and coordinates are float64 ndarrays, heatmaps (D, H, W) float32 ndarrays;
  an integer or float array of another dtype (float32 from torch or images, int64) or a nested
  list of numbers is converted (a copy), while booleans, complex numbers, strings and objects
  raise TypeError and a wrong shape ValueError, each naming the argument and what it must be
  (`_Real`); a pose is a 4 × 4 rigid transform;
- masks are boolean (H, W) arrays; numbers are converted only when every one is 0 or 1;
- sizes and the small fixed-length parameters are any sequence of floats of that length
  (list, tuple or 1-d array).
"""

from collections.abc import Sequence
from typing import Any, Literal, TypedDict

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "box_corners",
    "nms",
    "render_target_heatmap",
    "back_project",
    "kabsch",
    "umeyama",
    "paper_exact_search",
    "fast_exact_search",
    "robust_fit",
    "fit_pose_and_size",
    "paper_error",
    "add_s",
    "mssd",
    "cube_mssd",
    "rotation_error_deg",
    "translation_error",
    "iou_3d",
    "mask_iou",
    "average_precision",
]

_F64 = NDArray[np.float64]
_F32 = NDArray[np.float32]
# An array argument: an integer or float ndarray or nested lists of numbers, converted to float64
# (float32 for heatmaps, scores and depth images) when it is not that already.
_Real = NDArray[np.floating[Any]] | NDArray[np.integer[Any]] | Sequence[Any]
_Mask = NDArray[np.bool_] | NDArray[np.integer[Any]] | Sequence[Any]
# (dx, dy, dz) in metres; any length-3 sequence of floats.
_Size = Sequence[float] | NDArray[np.floating[Any]]
_Params = Sequence[float] | NDArray[np.floating[Any]]

class _CorrespondenceFit(TypedDict):
    pose: _F64  # 4 × 4, maps box-frame points into the camera frame
    peaks: list[int]  # indices into `points` of the peaks used, highest score first
    corners: list[int]  # corners[k]: the box corner matched to points[peaks[k]]
    sum_squared_error: float  # m²

class _Confidence(TypedDict):
    confidence: float  # in [0, 1)
    margin_nats: float  # to the best different pose; inf when there is none
    confidence_inliers: int
    noise_scale_m: float
    mirror_ambiguous: bool

class _RobustFit(_Confidence):
    method: Literal["adaptive", "fixed_threshold"]
    pose: _F64
    inliers: list[bool]
    nearest_corners: list[int]
    residuals: list[float]
    inlier_count: int
    inlier_rms: float
    cost: float  # nats for "adaptive", Σ min(r², τ²) for "fixed_threshold"

class _SizedFit(_Confidence):
    method: Literal["robust", "least_squares"]
    size: list[float]  # (dx, dy, dz), metres
    pose: _F64
    nearest_corners: list[int]
    residuals: list[float]
    inliers: list[bool]
    inlier_count: int
    inlier_rms: float

def box_corners(size: _Size) -> _F64:
    """The 8 corners (8, 3) of a box of `size` in its own frame, in boxpose corner order."""

def nms(
    heatmap: _Real, count: int = 8, sigma: float = 2.0, refine_radius: int = 0
) -> tuple[_F64, _F32]:
    """Peaks of a (D, H, W) heatmap: (coords (N, 3) as (z_bin, v, u), scores (N,))."""

def render_target_heatmap(shape: tuple[int, int, int], centres: _Real, sigma: float) -> _F32:
    """A (D, H, W) training target: a 3D Gaussian at each (z_bin, v, u) centre, max-combined.

    At most 2^30 voxels. Each Gaussian reaches 3 `sigma` voxels, so many centres or a wide
    `sigma` take time in proportion: the call releases the GIL and answers Ctrl-C between parts
    of about 8 million voxel updates.
    """

def back_project(coords: _Real, intrinsics: _Params, crop: _Params, depth_bins: _Params) -> _F64:
    """Camera-frame points (N, 3) of voxel coordinates (N, 3) as (z_bin, v, u) in a crop.

    `intrinsics` = (fx, fy, cx, cy), `crop` = (x0, y0, sx, sy), `depth_bins` = (z_ref, z_min,
    bin_size).
    """

def kabsch(source: _Real, target: _Real) -> _F64:
    """Least-squares rigid transform (4 × 4) mapping `source` onto `target`."""

def umeyama(source: _Real, target: _Real) -> tuple[float, _F64]:
    """Least-squares similarity transform: (scale, 4 × 4 rigid part)."""

def paper_exact_search(size: _Size, points: _Real, scores: _Real, m: int = 5) -> _CorrespondenceFit:
    """The paper's search over every assignment of the `m` best points (3 ≤ m ≤ 8) to the 8
    corners."""

def fast_exact_search(size: _Size, points: _Real, scores: _Real, m: int = 5) -> _CorrespondenceFit:
    """Same optimum as `paper_exact_search`, by symmetry reduction and branch-and-bound."""

def robust_fit(
    size: _Size,
    points: _Real,
    inlier_threshold: float | None = None,
    *,
    method: Literal["adaptive", "fixed_threshold"] = "adaptive",
    depth: _Real | None = None,
    intrinsics: Sequence[float] | None = None,
) -> _RobustFit:
    """Pose of a box of known size that survives up to half the points being outliers;
    with a depth image and its camera's (fx, fy, cx, cy), mirror ties are settled by it.

    At most 60 points (ValueError above): the exhaustive search grows with about the fourth
    power of the count, and a call at the cap takes under a second (see docs/geometry.md); pass
    the highest-scoring peaks. `depth` must be a non-empty (H, W) image in metres, `fx` and
    `fy` finite and positive, `cx` and `cy` finite (ValueError otherwise)."""

def fit_pose_and_size(
    points: _Real, *, method: Literal["robust", "least_squares"] = "robust"
) -> _SizedFit:
    """Pose and box size together, for boxes of unknown size.

    At most 40 points (ValueError above): the search over right angles and triangles of points
    grows faster still with the count, and a call at the cap takes under a second."""

def paper_error(size: _Size, estimate: _Real, truth_corners: _Real) -> float:
    """The paper's error (m²) of a pose against the ground-truth corners, exactly 8: shape
    (8, 3) (ValueError otherwise)."""

def add_s(size: _Size, estimate: _Real, truth: _Real) -> float:
    """ADD-S as bop_toolkit's `adi` (metres)."""

def mssd(size: _Size, estimate: _Real, truth: _Real) -> float:
    """MSSD: maximum corner distance, minimised over the box's symmetry group (metres)."""

def cube_mssd(estimated_size: _Size, estimate: _Real, true_size: _Size, truth: _Real) -> float:
    """Corner MSSD modulo the cube's 24 rotations (metres): the largest distance between the
    estimated box's corners and the true box's under the corner labelling that matches them best,
    so a quarter turn of a nearly square box costs what its corners really move. The primary
    correctness metric; `estimated_size` is the fitted size for a fit that estimates it, else the
    true size."""

def rotation_error_deg(size: _Size, estimate: _Real, truth: _Real) -> float:
    """Rotation error in degrees, minimised over the box's symmetry group."""

def translation_error(estimate: _Real, truth: _Real) -> float:
    """Distance between the two box centres (metres)."""

def iou_3d(size_a: _Size, pose_a: _Real, size_b: _Size, pose_b: _Real) -> float:
    """Intersection over union of two oriented boxes."""

def mask_iou(a: _Mask, b: _Mask) -> float:
    """Intersection over union of two boolean masks of one image, as COCO's mask IoU (numbers
    only when all are 0 or 1: pass `labels == k` for a label image)."""

def average_precision(images: list[tuple[_Real, _Real]], threshold: float) -> float:
    """COCO's average precision of one category at IoU `threshold`, as pycocotools computes it:
    per image (scores (D,) float32, ious (D, G)). NaN when no image has a true instance."""
