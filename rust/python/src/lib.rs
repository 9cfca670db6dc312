//! `import boxpose`: the geometry core on numpy arrays.
//!
//! Conventions: metres; points are (N, 3) float64 arrays in the camera frame; a pose is a 4 × 4
//! homogeneous matrix mapping box-frame points into the camera frame; a box is given by its size
//! (dx, dy, dz). Heatmaps are (D, H, W) float32 arrays over (z-bin, v, u). An array argument of
//! another integer or float dtype, or a nested list of numbers, is converted ([`real_array`]);
//! booleans, complex numbers, strings and objects raise `TypeError` naming the argument and what
//! it must be. Invalid input (a wrong shape, NaN, too few or degenerate points, too many points
//! for a fit, empty heatmaps) raises `ValueError` with the reason.

use boxpose_geometry::adaptive::FitConfidence;
use boxpose_geometry::align::nearest_rotation;
use boxpose_geometry::depth::DepthView;
use boxpose_geometry::heatmap::{
    self, CropTransform, DepthBins, HeatmapDims, NmsParams, PinholeIntrinsics, VoxelCoord,
    VoxelGrid,
};
use boxpose_geometry::{
    BoxModel, GeometryError, align, correspondence, detection, metrics, pipeline, robust, size_fit,
};
use nalgebra::{
    Isometry3, Matrix3, Matrix4, Point3, RowVector4, Translation3, UnitQuaternion, Vector3,
};
use numpy::ndarray::{Dimension, Ix1, Ix2, Ix3};
use numpy::{
    Element, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayDescrMethods, PyReadonlyArray,
    PyReadonlyArray2, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// `nms`'s result: peak positions (count × 3, voxel units) and their scores.
type PeaksAndScores<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f32>>);

fn value_error(e: GeometryError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A shape as Python prints it: `(24,)`, `(5, 2)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [length] => format!("({length},)"),
        _ => {
            let sides: Vec<String> = shape.iter().map(usize::to_string).collect();
            format!("({})", sides.join(", "))
        }
    }
}

/// What an array argument of element type `T` must be, for the error messages.
fn array_description<T: Element>(py: Python<'_>, shape: &str) -> String {
    format!(
        "a {} ndarray of shape {shape} (integer or float arrays and nested lists of numbers are \
         converted)",
        numpy::dtype::<T>(py)
    )
}

/// `value` as a numpy array (`numpy.asarray`: an array as it is) whose dtype kind is one of
/// `kinds` (numpy's letters: b bool, i/u integers, f floats); any other dtype is a `TypeError`
/// and a ragged list a `ValueError`, each naming `what` and saying what it must be (`expected`).
fn numpy_array<'py>(
    value: &Bound<'py, PyAny>,
    what: &str,
    expected: &str,
    kinds: &[u8],
) -> PyResult<Bound<'py, PyUntypedArray>> {
    let type_name = value.get_type().name()?;
    let array = value
        .py()
        .import("numpy")?
        .call_method1("asarray", (value,))
        .map_err(|e| {
            PyValueError::new_err(format!(
                "{what} must be {expected}, got a {type_name} that numpy cannot read as one \
                 array ({e})"
            ))
        })?
        .cast_into::<PyUntypedArray>()?;
    let dtype = array.dtype();
    if !kinds.contains(&dtype.kind()) {
        let source = if value.is_instance_of::<PyUntypedArray>() {
            String::new()
        } else {
            format!("a {type_name} read as ")
        };
        return Err(PyTypeError::new_err(format!(
            "{what} must be {expected}, got {source}a {dtype} array of shape {}",
            shape_text(array.shape())
        )));
    }
    Ok(array)
}

/// `value` as a `T` array of `D`'s dimensions: a `T` array as it is (no copy), any other integer
/// or float array or nested list of numbers converted (a copy), since lists and float32 arrays
/// (from torch, from images) are what users pass first. Booleans, complex numbers, strings and
/// objects are refused: converting them would be a guess.
fn real_array<'py, T: Element, D: Dimension>(
    value: &Bound<'py, PyAny>,
    what: &str,
    shape: &str,
) -> PyResult<PyReadonlyArray<'py, T, D>> {
    if let Ok(array) = value.extract::<PyReadonlyArray<'py, T, D>>() {
        return Ok(array);
    }
    let expected = array_description::<T>(value.py(), shape);
    let array = numpy_array(value, what, &expected, b"iuf")?;
    array
        .call_method1("astype", (numpy::dtype::<T>(value.py()),))?
        .extract()
        .map_err(|_| {
            PyValueError::new_err(format!(
                "{what} must be {expected}, got shape {}",
                shape_text(array.shape())
            ))
        })
}

fn points(value: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Point3<f64>>> {
    let array = real_array::<f64, Ix2>(value, what, "(N, 3)")?;
    let view = array.as_array();
    if view.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "{what} must be {}, got shape {}",
            array_description::<f64>(value.py(), "(N, 3)"),
            shape_text(view.shape())
        )));
    }
    Ok(view
        .rows()
        .into_iter()
        .map(|r| Point3::new(r[0], r[1], r[2]))
        .collect())
}

/// The most points `robust_fit` takes. Its search tries every triple of points against every
/// triple of corners and scores each hypothesis on every point, so its time grows with about the
/// fourth power of the count, fastest for peaks crowded at the corners, where most triples match
/// (measured on a loaded 2-core machine: 60 such points 0.8 s, 100 points 5.7 s; 400 spread
/// points took 157 s). At this cap a call is bounded, and a Ctrl-C, which Python raises when the
/// call returns, is answered within that time. A box has 8 corners: the highest-scoring peaks
/// hold them.
const MAX_KNOWN_SIZE_FIT_POINTS: usize = 60;

/// The most points `fit_pose_and_size` takes: its search also fits the sides, from every right
/// angle and acute triangle of points, and grows faster still (measured as above: 40 points
/// 0.4 s, 80 spread points took 12 s).
const MAX_SIZE_FIT_POINTS: usize = 40;

/// Refuses more than `max` points for `fit`, saying why and what to pass instead.
fn ensure_at_most(points: &[Point3<f64>], max: usize, fit: &str) -> PyResult<()> {
    if points.len() > max {
        return Err(PyValueError::new_err(format!(
            "points: {fit} takes at most {max} points (its exhaustive search grows with about the \
             fourth power of the count), got {}; pass the highest-scoring peaks, e.g. \
             points[np.argsort(scores)[-{max}:]]",
            points.len()
        )));
    }
    Ok(())
}

/// Refuses a camera no depth image can come from: the focal lengths (pixels) must be finite
/// and positive and the principal point finite, else the depth check silently does nothing.
fn ensure_camera(intrinsics: [f64; 4]) -> PyResult<()> {
    let [fx, fy, cx, cy] = intrinsics;
    if !(fx.is_finite() && fx > 0.0 && fy.is_finite() && fy > 0.0) {
        return Err(PyValueError::new_err(format!(
            "intrinsics (fx, fy, cx, cy): the focal lengths fx = {fx} and fy = {fy} must be \
             finite and positive (pixels)"
        )));
    }
    if !(cx.is_finite() && cy.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "intrinsics (fx, fy, cx, cy): the principal point cx = {cx}, cy = {cy} must be finite \
             (pixels)"
        )));
    }
    Ok(())
}

fn box_model(size: [f64; 3]) -> PyResult<BoxModel> {
    BoxModel::new(Vector3::from(size)).map_err(value_error)
}

fn isometry(matrix: &PyReadonlyArray2<f64>, what: &str) -> PyResult<Isometry3<f64>> {
    let view = matrix.as_array();
    if view.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "{what} must be a 4 × 4 matrix, got shape {}",
            shape_text(view.shape())
        )));
    }
    let m = Matrix4::from_fn(|r, c| view[[r, c]]);
    if m.iter().any(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{what} has non-finite entries"
        )));
    }
    // A rigid transform or nothing: a scaled or sheared "pose" would be silently re-interpreted,
    // and nalgebra's iterative projection never returns on entries of 1e200.
    let block = m.fixed_view::<3, 3>(0, 0).into_owned();
    let orthonormality = (block.transpose() * block - Matrix3::identity())
        .abs()
        .max();
    let bottom = (m.fixed_view::<1, 4>(3, 0) - RowVector4::new(0.0, 0.0, 0.0, 1.0))
        .abs()
        .max();
    if !(orthonormality <= RIGID_TOLERANCE
        && bottom <= RIGID_TOLERANCE
        && block.determinant() > 0.0)
    {
        return Err(PyValueError::new_err(format!(
            "{what} is not a rigid transform: its 3 × 3 block must be a rotation (|RᵀR − I| = \
             {orthonormality:.1e}, det = {:.3e}) and its last row [0, 0, 0, 1], within \
             {RIGID_TOLERANCE:.0e}",
            block.determinant()
        )));
    }
    let rotation = nearest_rotation(&block)
        .ok_or_else(|| PyValueError::new_err(format!("{what} has no nearest rotation")))?;
    Ok(Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rotation),
    ))
}

/// How far a pose's rotation block may be from orthonormal (float32 round trips stay ~1e-7).
const RIGID_TOLERANCE: f64 = 1e-5;

/// A pose argument as a float64 4 × 4 array, converted as [`real_array`] converts.
fn pose_matrix<'py>(value: &Bound<'py, PyAny>, what: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    real_array(value, what, "(4, 4)")
}

/// A pose argument as a rigid transform ([`pose_matrix`], then [`isometry`]).
fn pose(value: &Bound<'_, PyAny>, what: &str) -> PyResult<Isometry3<f64>> {
    isometry(&pose_matrix(value, what)?, what)
}

fn matrix<'py>(py: Python<'py>, pose: &Isometry3<f64>) -> Bound<'py, PyArray2<f64>> {
    let m = pose.to_homogeneous();
    numpy::ndarray::Array2::from_shape_fn((4, 4), |(r, c)| m[(r, c)]).into_pyarray(py)
}

fn points_array<'py>(py: Python<'py>, points: &[Point3<f64>]) -> Bound<'py, PyArray2<f64>> {
    numpy::ndarray::Array2::from_shape_fn((points.len(), 3), |(i, k)| points[i][k]).into_pyarray(py)
}

/// The 8 corners of a box of `size` in its own frame, (8, 3), in boxpose corner order
/// (bit 0 → x, bit 1 → y, bit 2 → z; 0 = −, 1 = +).
#[pyfunction]
fn box_corners<'py>(py: Python<'py>, size: [f64; 3]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    Ok(points_array(py, &box_model(size)?.corners()))
}

/// Peaks of a (D, H, W) heatmap by the paper's NMS: take the arg-max voxel, subtract a Gaussian
/// of width `sigma` voxels centred there, repeat `count` times. `refine_radius` > 0 adds a local
/// soft-argmax. Returns (coords (N, 3) as (z_bin, v, u), scores (N,)).
#[pyfunction]
#[pyo3(signature = (heatmap, count = 8, sigma = 2.0, refine_radius = 0))]
fn nms<'py>(
    py: Python<'py>,
    heatmap: &Bound<'py, PyAny>,
    count: usize,
    sigma: f64,
    refine_radius: usize,
) -> PyResult<PeaksAndScores<'py>> {
    let heatmap = real_array::<f32, Ix3>(heatmap, "heatmap", "(D, H, W)")?;
    let view = heatmap.as_array();
    let (depth, height, width) = view.dim();
    let volume: Vec<f32> = view.iter().copied().collect();
    let dims = HeatmapDims {
        depth,
        height,
        width,
    };
    let params = NmsParams {
        count,
        sigma,
        refine_radius,
    };
    let peaks = py
        .detach(|| heatmap::non_maximum_suppression(&volume, dims, &params))
        .map_err(value_error)?;
    let coords = numpy::ndarray::Array2::from_shape_fn((peaks.len(), 3), |(i, k)| {
        let c = peaks[i].coord;
        [c.z_bin, c.v, c.u][k]
    });
    let scores: Vec<f32> = peaks.iter().map(|p| p.score).collect();
    Ok((coords.into_pyarray(py), scores.into_pyarray(py)))
}

/// A (D, H, W) float32 training target: a 3D Gaussian (peak 1, `sigma` voxels) at each centre
/// given as (z_bin, v, u), max-combined. The centres are drawn in parts of about
/// [`TARGET_WORK_PER_PART`] voxel updates, without the GIL, with a Ctrl-C check between parts:
/// many centres or a wide `sigma` cost time in proportion, and stay interruptible.
#[pyfunction]
fn render_target_heatmap<'py>(
    py: Python<'py>,
    shape: (usize, usize, usize),
    centres: &Bound<'py, PyAny>,
    sigma: f64,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let centres: Vec<VoxelCoord> = points(centres, "centres")?
        .iter()
        .map(|p| VoxelCoord {
            z_bin: p[0],
            v: p[1],
            u: p[2],
        })
        .collect();
    let dims = HeatmapDims {
        depth: shape.0,
        height: shape.1,
        width: shape.2,
    };
    let mut volume = vec![0.0f32; dims.voxel_count().map_err(value_error)?];
    // an empty first part checks sigma and the centres before any work
    heatmap::add_targets(&mut volume, dims, &[], sigma).map_err(value_error)?;
    let mut rest = centres.as_slice();
    while !rest.is_empty() {
        let mut work = 0;
        let part = rest
            .iter()
            .take_while(|c| {
                work += heatmap::target_support_voxels(dims, c, sigma);
                work <= TARGET_WORK_PER_PART
            })
            .count()
            .max(1);
        let (now, later) = rest.split_at(part);
        py.detach(|| heatmap::add_targets(&mut volume, dims, now, sigma))
            .map_err(value_error)?;
        py.check_signals()?;
        rest = later;
    }
    let array = numpy::ndarray::Array3::from_shape_vec(shape, volume)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(array.into_pyarray(py))
}

/// Voxel updates `render_target_heatmap` does between two Ctrl-C checks (about 0.1 s on one
/// core). One centre is never split, so a single Gaussian as wide as the volume (at most 2^30
/// voxels) is the longest uninterruptible step.
const TARGET_WORK_PER_PART: usize = 1 << 23;

fn voxel_grid(intrinsics: [f64; 4], crop: [f64; 4], depth_bins: [f64; 3]) -> VoxelGrid {
    VoxelGrid {
        intrinsics: PinholeIntrinsics {
            fx: intrinsics[0],
            fy: intrinsics[1],
            cx: intrinsics[2],
            cy: intrinsics[3],
        },
        crop: CropTransform {
            x0: crop[0],
            y0: crop[1],
            sx: crop[2],
            sy: crop[3],
        },
        depth: DepthBins {
            z_ref: depth_bins[0],
            z_min: depth_bins[1],
            bin_size: depth_bins[2],
        },
    }
}

/// Camera-frame points (N, 3) of voxel coordinates (N, 3) as (z_bin, v, u) in a crop.
/// `intrinsics` = (fx, fy, cx, cy) of the full image; `crop` = (x0, y0, sx, sy) maps crop pixels
/// to image pixels; `depth_bins` = (z_ref, z_min, bin_size) in metres.
#[pyfunction]
fn back_project<'py>(
    py: Python<'py>,
    coords: &Bound<'py, PyAny>,
    intrinsics: [f64; 4],
    crop: [f64; 4],
    depth_bins: [f64; 3],
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let grid = voxel_grid(intrinsics, crop, depth_bins);
    let out = points(coords, "coords")?
        .iter()
        .map(|p| {
            grid.back_project(&VoxelCoord {
                z_bin: p[0],
                v: p[1],
                u: p[2],
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(value_error)?;
    Ok(points_array(py, &out))
}

/// Least-squares rigid transform (4 × 4, proper rotation) mapping `source` onto `target`.
#[pyfunction]
fn kabsch<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let pose = align::kabsch(&points(source, "source")?, &points(target, "target")?)
        .map_err(value_error)?;
    Ok(matrix(py, &pose))
}

/// Least-squares similarity transform: returns (scale, 4 × 4 rigid part) with
/// target ≈ scale · R · source + t.
#[pyfunction]
fn umeyama<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
) -> PyResult<(f64, Bound<'py, PyArray2<f64>>)> {
    let similarity = align::umeyama(&points(source, "source")?, &points(target, "target")?)
        .map_err(value_error)?;
    Ok((similarity.scaling(), matrix(py, &similarity.isometry)))
}

fn correspondence_dict<'py>(
    py: Python<'py>,
    fit: &correspondence::CorrespondenceFit,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("pose", matrix(py, &fit.pose))?;
    dict.set_item("peaks", fit.peaks.clone())?;
    dict.set_item("corners", fit.corners.clone())?;
    dict.set_item("sum_squared_error", fit.sum_squared_error)?;
    Ok(dict)
}

type Search = fn(
    &BoxModel,
    &[Point3<f64>],
    &[f64],
    usize,
) -> boxpose_geometry::Result<correspondence::CorrespondenceFit>;

fn search<'py>(
    py: Python<'py>,
    run: Search,
    size: [f64; 3],
    points_: &Bound<'py, PyAny>,
    scores: &Bound<'py, PyAny>,
    m: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let model = box_model(size)?;
    let pts = points(points_, "points")?;
    let scores = real_array::<f64, Ix1>(scores, "scores", "(N,)")?
        .as_array()
        .to_vec();
    let fit = py
        .detach(|| run(&model, &pts, &scores, m))
        .map_err(value_error)?;
    correspondence_dict(py, &fit)
}

/// The paper's search: the `m` highest-scoring points tried against every ordered assignment
/// to the 8 corners (6720 for m = 5), each fitted with Kabsch; the least-squares best wins.
/// Returns {"pose", "peaks", "corners", "sum_squared_error"}.
#[pyfunction]
#[pyo3(signature = (size, points, scores, m = 5))]
fn paper_exact_search<'py>(
    py: Python<'py>,
    size: [f64; 3],
    points: &Bound<'py, PyAny>,
    scores: &Bound<'py, PyAny>,
    m: usize,
) -> PyResult<Bound<'py, PyDict>> {
    search(
        py,
        correspondence::paper_exact_search,
        size,
        points,
        scores,
        m,
    )
}

/// Same optimum as `paper_exact_search`, found with symmetry reduction and branch-and-bound.
#[pyfunction]
#[pyo3(signature = (size, points, scores, m = 5))]
fn fast_exact_search<'py>(
    py: Python<'py>,
    size: [f64; 3],
    points: &Bound<'py, PyAny>,
    scores: &Bound<'py, PyAny>,
    m: usize,
) -> PyResult<Bound<'py, PyDict>> {
    search(
        py,
        correspondence::fast_exact_search,
        size,
        points,
        scores,
        m,
    )
}

fn confidence_items(dict: &Bound<'_, PyDict>, c: &FitConfidence) -> PyResult<()> {
    dict.set_item("confidence", c.confidence)?;
    dict.set_item("margin_nats", c.margin_nats)?;
    dict.set_item("confidence_inliers", c.inliers)?;
    dict.set_item("noise_scale_m", c.noise_scale_m)?;
    dict.set_item("mirror_ambiguous", c.mirror_ambiguous)?;
    Ok(())
}

/// Pose of a box of known size that survives up to half the points being outliers.
///
/// `method="adaptive"` (default): every minimal hypothesis scored by the noise-adaptive cost (no
/// threshold in box units; `robust::adaptive_fit`). `method="fixed_threshold"`: the former fit,
/// truncated least squares at `inlier_threshold` (default a quarter of the shortest side;
/// `robust::robust_fit`), for comparison.
///
/// Returns {"method", "pose", "inliers", "nearest_corners", "residuals", "inlier_count",
/// "inlier_rms", "cost" (nats for "adaptive", Σ min(r², τ²) for "fixed_threshold"), and the
/// confidence: "confidence" in [0, 1], "margin_nats" (to the best different pose; inf, and a
/// confidence of 1, when there is none), "confidence_inliers", "noise_scale_m",
/// "mirror_ambiguous"}. The fixed-threshold fit's confidence is the noise-adaptive assessment of
/// its pose (`robust::assess_pose`).
///
/// With `depth` (an H × W float32 depth image in metres, 0 where none, as the dataset's `depth`
/// column) and `intrinsics` (fx, fy, cx, cy of the camera whose frame the points are in), the
/// adaptive fit settles mirror ties with it (`pipeline::Fitted::resolve_mirror`):
/// "mirror_ambiguous" is then what is left after the depth image's say.
///
/// At most [`MAX_KNOWN_SIZE_FIT_POINTS`] points (either method).
#[pyfunction]
#[pyo3(signature = (size, points, inlier_threshold = None, *, method = "adaptive", depth = None, intrinsics = None))]
fn robust_fit<'py>(
    py: Python<'py>,
    size: [f64; 3],
    points: &Bound<'py, PyAny>,
    inlier_threshold: Option<f64>,
    method: &str,
    depth: Option<&Bound<'py, PyAny>>,
    intrinsics: Option<[f64; 4]>,
) -> PyResult<Bound<'py, PyDict>> {
    let model = box_model(size)?;
    let pts = self::points(points, "points")?;
    ensure_at_most(&pts, MAX_KNOWN_SIZE_FIT_POINTS, "robust_fit")?;
    let depth_image = match (depth, intrinsics) {
        (None, None) => None,
        (Some(depth), Some(intrinsics)) if method == "adaptive" => {
            let depth = real_array::<f32, Ix2>(depth, "depth", "(H, W)")?;
            let view = depth.as_array();
            let (height, width) = view.dim();
            if height == 0 || width == 0 {
                return Err(PyValueError::new_err(format!(
                    "depth must be a non-empty (H, W) image in metres, got shape {}",
                    shape_text(view.shape())
                )));
            }
            ensure_camera(intrinsics)?;
            Some((
                width,
                height,
                intrinsics,
                view.iter().copied().collect::<Vec<f32>>(),
            ))
        }
        (Some(_), Some(_)) => {
            return Err(PyValueError::new_err(
                "depth applies to method=\"adaptive\" only",
            ));
        }
        _ => {
            return Err(PyValueError::new_err(
                "depth and intrinsics go together: pass both or neither",
            ));
        }
    };
    let dict = PyDict::new(py);
    dict.set_item("method", method)?;
    match method {
        "adaptive" => {
            if inlier_threshold.is_some() {
                return Err(PyValueError::new_err(
                    "inlier_threshold applies to method=\"fixed_threshold\" only",
                ));
            }
            let fit = py
                .detach(|| -> boxpose_geometry::Result<_> {
                    let mut fit =
                        robust::adaptive_fit(&model, &pts, &robust::AdaptiveParams::default())?;
                    if let Some((width, height, intrinsics, depth_m)) = &depth_image {
                        let mut fitted = pipeline::Fitted::from_adaptive(&model, &fit);
                        let view = DepthView {
                            width: *width,
                            height: *height,
                            intrinsics: *intrinsics,
                            depth_m,
                        };
                        fitted.resolve_mirror(&pts, &view);
                        fit.pose = fitted.pose;
                        fit.confidence = fitted.own_confidence.unwrap_or(fit.confidence);
                    }
                    Ok(fit)
                })
                .map_err(value_error)?;
            dict.set_item("pose", matrix(py, &fit.pose))?;
            dict.set_item("inlier_rms", fit.inlier_rms())?;
            dict.set_item("inliers", fit.inliers)?;
            dict.set_item("nearest_corners", fit.nearest_corners)?;
            dict.set_item("residuals", fit.residuals)?;
            dict.set_item("inlier_count", fit.inlier_count)?;
            dict.set_item("cost", fit.cost)?;
            confidence_items(&dict, &fit.confidence)?;
        }
        "fixed_threshold" => {
            let mut params = robust::RobustParams::for_box(&model);
            if let Some(threshold) = inlier_threshold {
                params.inlier_threshold = threshold;
            }
            let (fit, confidence) = py
                .detach(|| -> boxpose_geometry::Result<_> {
                    let fit = robust::robust_fit(&model, &pts, &params)?;
                    let confidence = robust::assess_pose(&model, &pts, &fit.pose)?;
                    Ok((fit, confidence))
                })
                .map_err(value_error)?;
            dict.set_item("pose", matrix(py, &fit.pose))?;
            dict.set_item("inliers", fit.inliers)?;
            dict.set_item("nearest_corners", fit.nearest_corners)?;
            dict.set_item("residuals", fit.residuals)?;
            dict.set_item("inlier_count", fit.inlier_count)?;
            dict.set_item("inlier_rms", fit.inlier_rms)?;
            dict.set_item("cost", fit.truncated_cost)?;
            confidence_items(&dict, &confidence)?;
        }
        other => {
            return Err(PyValueError::new_err(format!(
                "method must be \"adaptive\" or \"fixed_threshold\", got {other:?}"
            )));
        }
    }
    Ok(dict)
}

/// What either size fit of `fit_pose_and_size` hands to the dict it returns.
struct SizedFit {
    model: BoxModel,
    pose: Isometry3<f64>,
    nearest_corners: Vec<usize>,
    rms: f64,
    residuals: Vec<f64>,
    inliers: Vec<bool>,
    confidence: FitConfidence,
}

/// Pose and box size together, for boxes of unknown size.
///
/// `method="robust"` (default): minimal hypotheses scored by the noise-adaptive cost, survives
/// outlier points (`size_fit::robust_size_fit`). `method="least_squares"`: the former
/// least-squares scaling ICP (`size_fit::fit_pose_and_size`), for comparison; every point is its
/// inlier.
///
/// Returns {"method", "size", "pose", "nearest_corners", "residuals", "inliers", "inlier_count",
/// "inlier_rms", and the confidence fields of `robust_fit`}; the least-squares fit's confidence
/// is the noise-adaptive assessment of its box (`size_fit::assess_sized_box`).
///
/// At most [`MAX_SIZE_FIT_POINTS`] points (either method).
#[pyfunction]
#[pyo3(signature = (points, *, method = "robust"))]
fn fit_pose_and_size<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    method: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let pts = self::points(points, "points")?;
    ensure_at_most(&pts, MAX_SIZE_FIT_POINTS, "fit_pose_and_size")?;
    let fit = match method {
        "robust" => py
            .detach(|| -> boxpose_geometry::Result<_> {
                let f = size_fit::robust_size_fit(&pts, &size_fit::RobustSizeParams::default())?;
                Ok(SizedFit {
                    rms: f.inlier_rms(),
                    model: f.model,
                    pose: f.pose,
                    nearest_corners: f.nearest_corners,
                    residuals: f.residuals,
                    inliers: f.inliers,
                    confidence: f.confidence,
                })
            })
            .map_err(value_error)?,
        "least_squares" => py
            .detach(|| -> boxpose_geometry::Result<_> {
                let f = size_fit::fit_pose_and_size(&pts, &size_fit::SizeFitParams::default())?;
                let confidence = size_fit::assess_sized_box(&pts, &f.model, &f.pose)?;
                Ok(SizedFit {
                    model: f.model,
                    pose: f.pose,
                    nearest_corners: f.nearest_corners,
                    rms: f.inlier_rms,
                    residuals: f.residuals,
                    inliers: f.inliers,
                    confidence,
                })
            })
            .map_err(value_error)?,
        other => {
            return Err(PyValueError::new_err(format!(
                "method must be \"robust\" or \"least_squares\", got {other:?}"
            )));
        }
    };
    let SizedFit {
        model,
        pose,
        nearest_corners,
        rms,
        residuals,
        inliers,
        confidence,
    } = fit;
    let dict = PyDict::new(py);
    dict.set_item("method", method)?;
    let size = model.size();
    dict.set_item("size", [size.x, size.y, size.z])?;
    dict.set_item("pose", matrix(py, &pose))?;
    dict.set_item("nearest_corners", nearest_corners)?;
    dict.set_item("residuals", residuals)?;
    dict.set_item("inlier_count", inliers.iter().filter(|b| **b).count())?;
    dict.set_item("inliers", inliers)?;
    dict.set_item("inlier_rms", rms)?;
    confidence_items(&dict, &confidence)?;
    Ok(dict)
}

/// The paper's error: (1/8) Σ_i ‖R m_{c_i} + t − s_i‖², s_i the ground-truth corner nearest to
/// each transformed model corner. `truth_corners` is (8, 3).
#[pyfunction]
fn paper_error(
    size: [f64; 3],
    estimate: &Bound<'_, PyAny>,
    truth_corners: &Bound<'_, PyAny>,
) -> PyResult<f64> {
    let truth = points(truth_corners, "truth_corners")?;
    // Any other count is a mistake (a subset, a stacked batch): the nearest-corner error against
    // it would still be a number.
    if truth.len() != 8 {
        return Err(PyValueError::new_err(format!(
            "truth_corners must be the box's 8 ground-truth corners, shape (8, 3), got shape ({}, \
             3)",
            truth.len()
        )));
    }
    metrics::paper_error(&box_model(size)?, &pose(estimate, "estimate")?, &truth)
        .map_err(value_error)
}

type PoseMetric = fn(&BoxModel, &Isometry3<f64>, &Isometry3<f64>) -> boxpose_geometry::Result<f64>;

fn pose_metric(
    metric: PoseMetric,
    size: [f64; 3],
    estimate: PyReadonlyArray2<f64>,
    truth: PyReadonlyArray2<f64>,
) -> PyResult<f64> {
    metric(
        &box_model(size)?,
        &isometry(&estimate, "estimate")?,
        &isometry(&truth, "truth")?,
    )
    .map_err(value_error)
}

/// ADD-S as bop_toolkit's `adi`: mean distance from each true-placed point of the box's surface
/// sample to the nearest estimate-placed one (metres; see `metrics::add_s` for the sample).
#[pyfunction]
fn add_s(size: [f64; 3], estimate: &Bound<'_, PyAny>, truth: &Bound<'_, PyAny>) -> PyResult<f64> {
    pose_metric(
        metrics::add_s,
        size,
        pose_matrix(estimate, "estimate")?,
        pose_matrix(truth, "truth")?,
    )
}

/// MSSD: maximum corner distance, minimised over the box's symmetry group (metres, as in BOP).
#[pyfunction]
fn mssd(size: [f64; 3], estimate: &Bound<'_, PyAny>, truth: &Bound<'_, PyAny>) -> PyResult<f64> {
    pose_metric(
        metrics::mssd,
        size,
        pose_matrix(estimate, "estimate")?,
        pose_matrix(truth, "truth")?,
    )
}

/// Corner MSSD modulo the cube's 24 rotations (metres): the largest distance between the
/// estimated box's corners and the true box's under the corner labelling that matches them best,
/// so a quarter turn of a nearly square box costs what its corners really move. The primary
/// correctness metric; `estimated_size` is the fitted size for a fit that estimates it, else the
/// true size.
#[pyfunction]
fn cube_mssd(
    estimated_size: [f64; 3],
    estimate: &Bound<'_, PyAny>,
    true_size: [f64; 3],
    truth: &Bound<'_, PyAny>,
) -> PyResult<f64> {
    metrics::cube_mssd(
        &box_model(estimated_size)?,
        &pose(estimate, "estimate")?,
        &box_model(true_size)?,
        &pose(truth, "truth")?,
    )
    .map_err(value_error)
}

/// Rotation error in degrees, minimised over the box's symmetry group.
#[pyfunction]
fn rotation_error_deg(
    size: [f64; 3],
    estimate: &Bound<'_, PyAny>,
    truth: &Bound<'_, PyAny>,
) -> PyResult<f64> {
    pose_metric(
        metrics::rotation_error_deg,
        size,
        pose_matrix(estimate, "estimate")?,
        pose_matrix(truth, "truth")?,
    )
}

/// Distance between the two box centres (metres).
#[pyfunction]
fn translation_error(estimate: &Bound<'_, PyAny>, truth: &Bound<'_, PyAny>) -> PyResult<f64> {
    metrics::translation_error(&pose(estimate, "estimate")?, &pose(truth, "truth")?)
        .map_err(value_error)
}

/// Intersection over union of two oriented boxes.
#[pyfunction]
fn iou_3d(
    size_a: [f64; 3],
    pose_a: &Bound<'_, PyAny>,
    size_b: [f64; 3],
    pose_b: &Bound<'_, PyAny>,
) -> PyResult<f64> {
    metrics::iou_3d(
        &box_model(size_a)?,
        &pose(pose_a, "pose_a")?,
        &box_model(size_b)?,
        &pose(pose_b, "pose_b")?,
    )
    .map_err(value_error)
}

/// A mask argument: a boolean (H, W) array, or numbers that are all 0 or 1 (a uint8 mask read
/// from an image), as its shape and its pixels in row-major order. Other numbers are refused: a
/// label image or a 0/255 mask read as "nonzero" could silently be the wrong mask.
fn mask(value: &Bound<'_, PyAny>, what: &str) -> PyResult<(Vec<usize>, Vec<bool>)> {
    let flat = |m: PyReadonlyArray2<bool>| {
        let view = m.as_array();
        (view.shape().to_vec(), view.iter().copied().collect())
    };
    if let Ok(m) = value.extract::<PyReadonlyArray2<bool>>() {
        return Ok(flat(m));
    }
    let expected = "a bool ndarray of shape (H, W) (integer or float arrays and lists of 0 and 1 \
                    are converted)";
    let array = numpy_array(value, what, expected, b"biuf")?;
    let wrong_shape = || {
        PyValueError::new_err(format!(
            "{what} must be {expected}, got shape {}",
            shape_text(array.shape())
        ))
    };
    if array.dtype().kind() == b'b' {
        return array.extract().map(flat).map_err(|_| wrong_shape());
    }
    let numbers: PyReadonlyArray2<f64> = array
        .call_method1("astype", (numpy::dtype::<f64>(value.py()),))?
        .extract()
        .map_err(|_| wrong_shape())?;
    let view = numbers.as_array();
    if let Some(other) = view.iter().find(|v| **v != 0.0 && **v != 1.0) {
        return Err(PyValueError::new_err(format!(
            "{what} must be {expected}, got the value {other}: pass `{what} != 0` for every \
             nonzero pixel, or `{what} == label` for one instance of a label image"
        )));
    }
    Ok((
        view.shape().to_vec(),
        view.iter().map(|v| *v == 1.0).collect(),
    ))
}

/// Intersection over union of two boolean masks of one image, as COCO's mask IoU.
#[pyfunction]
fn mask_iou(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<f64> {
    let ((a_shape, a), (b_shape, b)) = (mask(a, "a")?, mask(b, "b")?);
    if a_shape != b_shape {
        return Err(PyValueError::new_err(format!(
            "masks of different shapes {} and {}",
            shape_text(&a_shape),
            shape_text(&b_shape)
        )));
    }
    Ok(detection::mask_iou(&a, &b))
}

/// COCO's average precision of one category at IoU `threshold`, as pycocotools computes it:
/// `images` holds per image (scores (D,) float32, ious (D, G)), `ious[d, g]` the IoU of detection
/// d with true instance g. NaN when no image has a true instance.
#[pyfunction]
fn average_precision(
    py: Python<'_>,
    images: Vec<(Bound<'_, PyAny>, Bound<'_, PyAny>)>,
    threshold: f64,
) -> PyResult<f64> {
    if !(0.0..=1.0).contains(&threshold) {
        return Err(PyValueError::new_err(format!(
            "threshold {threshold} is not in [0, 1]"
        )));
    }
    let mut converted = Vec::with_capacity(images.len());
    for (index, (scores, ious)) in images.iter().enumerate() {
        let scores = real_array::<f32, Ix1>(scores, &format!("image {index}: scores"), "(D,)")?;
        let ious = real_array::<f64, Ix2>(ious, &format!("image {index}: ious"), "(D, G)")?;
        let (scores, ious) = (scores.as_array(), ious.as_array());
        let (rows, true_count) = ious.dim();
        if rows != scores.len() {
            return Err(PyValueError::new_err(format!(
                "image {index}: {} scores for {rows} rows of IoUs",
                scores.len()
            )));
        }
        if scores.iter().any(|s| !s.is_finite()) || ious.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Err(PyValueError::new_err(format!(
                "image {index}: scores must be finite and IoUs in [0, 1]"
            )));
        }
        converted.push(detection::ImageDetections {
            scores: scores.to_vec(),
            ious: ious.rows().into_iter().map(|r| r.to_vec()).collect(),
            true_count,
        });
    }
    Ok(py.detach(|| detection::average_precision(&converted, threshold)))
}

#[pymodule]
fn boxpose(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(box_corners, m)?)?;
    m.add_function(wrap_pyfunction!(nms, m)?)?;
    m.add_function(wrap_pyfunction!(render_target_heatmap, m)?)?;
    m.add_function(wrap_pyfunction!(back_project, m)?)?;
    m.add_function(wrap_pyfunction!(kabsch, m)?)?;
    m.add_function(wrap_pyfunction!(umeyama, m)?)?;
    m.add_function(wrap_pyfunction!(paper_exact_search, m)?)?;
    m.add_function(wrap_pyfunction!(fast_exact_search, m)?)?;
    m.add_function(wrap_pyfunction!(robust_fit, m)?)?;
    m.add_function(wrap_pyfunction!(fit_pose_and_size, m)?)?;
    m.add_function(wrap_pyfunction!(paper_error, m)?)?;
    m.add_function(wrap_pyfunction!(add_s, m)?)?;
    m.add_function(wrap_pyfunction!(mssd, m)?)?;
    m.add_function(wrap_pyfunction!(cube_mssd, m)?)?;
    m.add_function(wrap_pyfunction!(rotation_error_deg, m)?)?;
    m.add_function(wrap_pyfunction!(translation_error, m)?)?;
    m.add_function(wrap_pyfunction!(iou_3d, m)?)?;
    m.add_function(wrap_pyfunction!(mask_iou, m)?)?;
    m.add_function(wrap_pyfunction!(average_precision, m)?)?;
    Ok(())
}
