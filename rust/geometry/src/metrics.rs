//! Pose error metrics, one function per metric, each defined in its doc comment (in the manner of
//! bop_toolkit's `pose_error.py`). A pose maps box-frame points into the camera frame; `estimate`
//! is the fitted pose and `truth` the ground truth. Distances are in metres.

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

use crate::box_model::{BoxModel, CORNER_COUNT, cube_corner_permutations};
use crate::error::{GeometryError, Result, ensure_finite, ensure_finite_points};

/// The paper's counterexample threshold on [`paper_error`] for its unit box; for other boxes it
/// applies to [`normalized_paper_error`].
pub const PAPER_ERROR_THRESHOLD: f64 = 0.005;

/// [`paper_error`] / (d² / 3), d the box's diagonal: a unit cube's d²/3 is 1, and the error of a
/// box scaled by s grows by s², so the paper's [`PAPER_ERROR_THRESHOLD`] keeps its meaning for
/// any box.
pub fn normalized_paper_error(paper_error: f64, diagonal_m: f64) -> f64 {
    paper_error / (diagonal_m * diagonal_m / 3.0)
}

/// The paper's error (its section III-E, step 7):
///
/// error = (1/8) Σ_{i=0}^{7} ‖R·m_{c_i} + t − s_i‖²
///
/// with (R, t) = `estimate`, m_{c_i} the model's corners and s_i the ground-truth corner nearest
/// to the transformed corner R·m_{c_i} + t. A mean squared distance, in m² (the paper fits a unit
/// box and calls an error above 0.005 a counterexample). Nearest-neighbour matching makes it blind
/// to the box's symmetries; it is not a distance between poses (two transformed corners may share
/// one ground-truth corner).
pub fn paper_error(
    model: &BoxModel,
    estimate: &Isometry3<f64>,
    truth_corners: &[Point3<f64>],
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_finite_points("ground-truth corners", truth_corners)?;
    if truth_corners.is_empty() {
        return Err(GeometryError::TooFewPoints {
            what: "ground-truth corners",
            needed: 1,
            got: 0,
        });
    }
    let sum: f64 = model
        .corners()
        .iter()
        .map(|m| {
            let placed = estimate * m;
            truth_corners
                .iter()
                .map(|s| (placed - s).norm_squared())
                .fold(f64::INFINITY, f64::min)
        })
        .sum();
    Ok(sum / CORNER_COUNT as f64)
}

/// Grid spacing of [`surface_points`] as a fraction of the box's diameter: every face is sampled
/// at spacing ≤ diameter / 50 along each of its edges.
pub const SURFACE_SPACING_PER_DIAMETER: f64 = 1.0 / 50.0;

/// The box's surface sample, standing in for BOP's `models_eval` (meshes resampled to roughly
/// uniform vertex density):
///
/// with h = [`SURFACE_SPACING_PER_DIAMETER`] · diameter, side i of length d_i is cut into
/// n_i = max(1, ⌈d_i / h⌉) equal cells of length δ_i = d_i / n_i ≤ h. Each face x_k = ±d_k/2 carries
/// the centres of its n_b × n_c cells, (x_b, x_c) = (−d_b/2 + (i + ½)·δ_b, −d_c/2 + (j + ½)·δ_c),
/// so each face is covered at density ≈ 1/h² and no point is shared between faces. Faces are
/// listed x, y, z axis in turn, − before +, then i-major. The set is mapped onto itself by every
/// rotation of the box (sides of exactly equal length get equal cell counts). A 0.3 × 0.2 × 0.1
/// box gets 4118 points, a cube 5046; never more than 6 · 51² points.
pub fn surface_points(model: &BoxModel) -> Vec<Point3<f64>> {
    let grid = SurfaceGrid::new(model);
    let mut points = Vec::new();
    for k in 0..3 {
        let (b, c) = ((k + 1) % 3, (k + 2) % 3);
        for sign in [-1.0, 1.0] {
            for i in 0..grid.cells[b] {
                for j in 0..grid.cells[c] {
                    let mut x = Vector3::zeros();
                    x[k] = sign * grid.half[k];
                    x[b] = grid.centre(b, i);
                    x[c] = grid.centre(c, j);
                    points.push(Point3::from(x));
                }
            }
        }
    }
    points
}

/// The cell grid behind [`surface_points`].
struct SurfaceGrid {
    half: Vector3<f64>,
    step: Vector3<f64>,
    cells: [usize; 3],
}

impl SurfaceGrid {
    fn new(model: &BoxModel) -> Self {
        let size = model.size();
        let spacing = SURFACE_SPACING_PER_DIAMETER * model.diameter();
        let cells: [usize; 3] =
            std::array::from_fn(|i| ((size[i] / spacing).ceil() as usize).max(1));
        Self {
            half: size * 0.5,
            step: Vector3::from_fn(|i, _| size[i] / cells[i] as f64),
            cells,
        }
    }

    fn centre(&self, axis: usize, i: usize) -> f64 {
        -self.half[axis] + (i as f64 + 0.5) * self.step[axis]
    }

    /// Squared distance from `x` to the nearest grid centre along `axis`: the centre of the cell
    /// that contains x (clamped to the first or last cell).
    fn along_sq(&self, axis: usize, x: f64) -> f64 {
        let cell = ((x + self.half[axis]) / self.step[axis]).floor();
        let i = if cell.is_nan() || cell < 0.0 {
            0
        } else {
            (cell as usize).min(self.cells[axis] - 1)
        };
        let d = x - self.centre(axis, i);
        d * d
    }

    /// Distance from `q` (in the box's frame) to the nearest point of [`surface_points`]. On the
    /// faces x_k = ±d_k/2 the squared distance separates into (q_k ∓ d_k/2)² plus one term per
    /// in-face axis, each minimised on its own; the nearer of the two faces is |q_k| − d_k/2 away.
    /// O(1) per query instead of a scan over all points.
    fn nearest_distance(&self, q: &Vector3<f64>) -> f64 {
        let along = [
            self.along_sq(0, q.x),
            self.along_sq(1, q.y),
            self.along_sq(2, q.z),
        ];
        (0..3)
            .map(|k| {
                let normal = q[k].abs() - self.half[k];
                normal * normal + along[(k + 1) % 3] + along[(k + 2) % 3]
            })
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    }
}

/// ADD-S, as bop_toolkit's `pose_error.adi` (Hinterstoisser et al. 2012, for objects with
/// indistinguishable views):
///
/// e_ADD-S = (1/|P|) Σ_{x ∈ P} min_{y ∈ P} ‖truth·x − estimate·y‖
///
/// with P = [`surface_points`] of the box: every ground-truth-placed surface point is matched to
/// the nearest estimate-placed one (as `adi`'s KD-tree query of `pts_gt` in `pts_est`). The nearest
/// point is found exactly in O(1) per point from the grid's structure, so a call costs O(|P|).
/// Nearest-point matching makes it blind to the box's symmetries (a symmetric pose scores 0) and
/// at most the translation for a pure translation; it is not a distance between poses.
pub fn add_s(model: &BoxModel, estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Result<f64> {
    add_s_between(model, estimate, model, truth)
}

/// [`add_s`] between two boxes of possibly different sizes: the truth's points are
/// [`surface_points`] of `true_box` under `truth`, the estimate's points those of `estimated_box`
/// under `estimate` (each box sampled at its own spacing). How a fit that also estimates the size
/// is scored: a wrong size counts.
pub fn add_s_between(
    estimated_box: &BoxModel,
    estimate: &Isometry3<f64>,
    true_box: &BoxModel,
    truth: &Isometry3<f64>,
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    let grid = SurfaceGrid::new(estimated_box);
    // Truth points in the estimated box's frame: distances are unchanged by the common isometry.
    let relative = estimate.inverse() * truth;
    let points = surface_points(true_box);
    let sum: f64 = points
        .iter()
        .map(|x| grid.nearest_distance(&(relative * x).coords))
        .sum();
    Ok(sum / points.len() as f64)
}

/// ADD-S over the 8 corners only:
///
/// e = (1/8) Σ_{x₁ ∈ corners} min_{x₂ ∈ corners} ‖estimate·x₁ − truth·x₂‖
///
/// The points the pipeline detects, which the box's symmetries permute. Not the BOP definition
/// (see [`add_s`]): it differs from it by up to several centimetres on random poses.
pub fn add_s_corners(
    model: &BoxModel,
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    let corners = model.corners();
    let truth_corners: Vec<_> = corners.iter().map(|x| truth * x).collect();
    let sum: f64 = corners
        .iter()
        .map(|x| {
            let placed = estimate * x;
            truth_corners
                .iter()
                .map(|y| (placed - y).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .sum();
    Ok(sum / CORNER_COUNT as f64)
}

/// Maximum symmetry-aware surface distance (BOP, Hodaň et al. 2020):
///
/// e_MSSD = min_{S ∈ G} max_{x ∈ V} ‖estimate·x − truth·S·x‖
///
/// with G the box's rotation group ([`BoxModel::symmetries`]) and V its corners. For a box this
/// equals the maximum over its whole surface: the distance is a convex function of x, so its
/// maximum over the box is reached at a vertex.
pub fn mssd(model: &BoxModel, estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    Ok(min_over_symmetries_of_max_over_corners(model, |x, s_x| {
        (estimate * x - truth * s_x).norm()
    }))
}

/// min_{S ∈ G} max_{x ∈ V} distance(x, S·x) over the box's rotation group G and corners V (box
/// frame): the form of [`mssd`] and [`mspd`].
fn min_over_symmetries_of_max_over_corners(
    model: &BoxModel,
    distance: impl Fn(&Point3<f64>, &Point3<f64>) -> f64,
) -> f64 {
    let corners = model.corners();
    model
        .symmetries()
        .iter()
        .map(|s| {
            corners
                .iter()
                .map(|x| distance(x, &(s.rotation * x)))
                .fold(0.0, f64::max)
        })
        .fold(f64::INFINITY, f64::min)
}

/// Maximum symmetry-aware projection distance (BOP, Hodaň et al. 2020), in pixels:
///
/// e_MSPD = min_{S ∈ G} max_{x ∈ V} ‖π(estimate·x) − π(truth·S·x)‖
///
/// with π the pinhole projection of `intrinsics` [fx, fy, cx, cy] (π(p) = (fx·p_x/p_z + cx,
/// fy·p_y/p_z + cy)), G the box's rotation group ([`BoxModel::symmetries`]) and V its corners: the
/// vertices bop_toolkit takes the maximum over, which for an exported box are its corners. Both
/// poses must put the box in front of the camera for the distance to mean anything.
pub fn mspd(
    model: &BoxModel,
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
    intrinsics: [f64; 4],
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    ensure_finite("intrinsics", &intrinsics)?;
    let [fx, fy, cx, cy] = intrinsics;
    let project = |p: Point3<f64>| [fx * p.x / p.z + cx, fy * p.y / p.z + cy];
    Ok(min_over_symmetries_of_max_over_corners(model, |x, s_x| {
        let [u, v] = project(estimate * x);
        let [u_true, v_true] = project(truth * s_x);
        (u - u_true).hypot(v - v_true)
    }))
}

/// Corner MSSD modulo the cube's rotations: how far the fitted corners really are from the true
/// ones, whatever corner each is called.
///
/// e = min_{π ∈ C} max_{i} ‖estimate·c^E_i − truth·c^B_{π(i)}‖
///
/// with c^E the corners of `estimated_box`, c^B those of `true_box` and C the 24 proper rotations
/// of the cube acting on corner labels ([`cube_corner_permutations`]). For a box with exact
/// symmetries, every π of its own group is in C, so e ≤ [`mssd`], with equality when the best π is
/// one of them; a quarter turn of a box with an a × b face costs the corners' real displacement
/// (|a − b|/√2 for the turn about the face's normal), so the error grows with how distinguishable
/// the sides are instead of jumping to ≈ d/2 as MSSD's does. It is symmetric in its two poses,
/// non-negative, and zero exactly when the two boxes have the same corner set. For a fit that
/// estimates the size (`estimated_box` ≠ `true_box`) a wrong size counts.
pub fn cube_mssd(
    estimated_box: &BoxModel,
    estimate: &Isometry3<f64>,
    true_box: &BoxModel,
    truth: &Isometry3<f64>,
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    let placed: Vec<Point3<f64>> = estimated_box
        .corners()
        .iter()
        .map(|c| estimate * c)
        .collect();
    let true_corners: Vec<Point3<f64>> = true_box.corners().iter().map(|c| truth * c).collect();
    Ok(cube_corner_permutations()
        .iter()
        .map(|pi| {
            placed
                .iter()
                .enumerate()
                .map(|(i, c)| (c - true_corners[pi[i]]).norm())
                .fold(0.0, f64::max)
        })
        .fold(f64::INFINITY, f64::min))
}

/// The thresholds of BOP's average recall of MSSD (Hodaň et al. 2020): 0.05, 0.10, …, 0.50 of the
/// object's diameter.
pub const AR_MSSD_THRESHOLDS: [f64; 10] = [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5];

/// BOP's average recall of an error over [`AR_MSSD_THRESHOLDS`]:
///
/// AR = (1/|Θ|) Σ_{θ ∈ Θ} (1/n) · #{k : e_k < θ}
///
/// with `errors_over_diameter` the n errors divided by each object's diameter; a fit that returned
/// no pose is passed as +∞ (a miss at every threshold). 0 for no errors.
pub fn average_recall(errors_over_diameter: &[f64]) -> f64 {
    average_recall_at(errors_over_diameter, &AR_MSSD_THRESHOLDS)
}

/// The thresholds of BOP's average recall of MSPD (Hodaň et al. 2020): 5, 10, …, 50 pixels at an
/// image width of 640, scaled with the width.
pub const AR_MSPD_THRESHOLDS_PX: [f64; 10] =
    [5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0];

/// The average recall of `errors` over `thresholds`: (1/|Θ|) Σ_{θ ∈ Θ} (1/n) · #{k : e_k < θ}
/// (a missing pose passed as +∞); 0 for no errors.
pub fn average_recall_at(errors: &[f64], thresholds: &[f64]) -> f64 {
    if errors.is_empty() || thresholds.is_empty() {
        return 0.0;
    }
    let n = errors.len() as f64;
    thresholds
        .iter()
        .map(|&theta| errors.iter().filter(|&&e| e < theta).count() as f64 / n)
        .sum::<f64>()
        / thresholds.len() as f64
}

/// Rotation error modulo the box's symmetries, in degrees:
///
/// e_R = min_{S ∈ G} angle(R̂ᵀ · R · S)
///
/// with R̂, R the rotations of `estimate` and `truth`, G the box's rotation group and angle(Q) =
/// arccos((tr Q − 1)/2) ∈ [0°, 180°].
pub fn rotation_error_deg(
    model: &BoxModel,
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    let relative = estimate.rotation.inverse() * truth.rotation;
    Ok(model
        .symmetries()
        .iter()
        .map(|s| {
            // 2·atan2(‖q_v‖, |q_w|) is the same angle as the arccos form, without arccos's loss
            // of precision near 0°.
            let q = relative * UnitQuaternion::from_rotation_matrix(&s.rotation);
            (2.0 * q.imag().norm().atan2(q.scalar().abs())).to_degrees()
        })
        .fold(f64::INFINITY, f64::min))
}

/// Translation error: e_t = ‖t̂ − t‖, the distance between the estimated and true box centres.
/// The box's symmetries are rotations about its centre, so taking the minimum over them (as for
/// [`rotation_error_deg`]) changes nothing.
pub fn translation_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Result<f64> {
    ensure_pose("estimate", estimate)?;
    ensure_pose("truth", truth)?;
    Ok((estimate.translation.vector - truth.translation.vector).norm())
}

/// Intersection over union of two oriented boxes:
///
/// IoU = vol(A ∩ B) / (vol(A) + vol(B) − vol(A ∩ B))
///
/// computed exactly. A ∩ B is a convex polyhedron whose faces are the faces of A clipped by B's six
/// half-spaces and the faces of B clipped by A's (Sutherland–Hodgman); its volume follows from the
/// divergence theorem, vol = (1/3) Σ_faces (n·x) · area, with n the outward normal and x any point
/// of the face. A face of B lying in the plane of a face of A with the same outward normal is the
/// same face of the intersection and is counted once.
pub fn iou_3d(
    box_a: &BoxModel,
    pose_a: &Isometry3<f64>,
    box_b: &BoxModel,
    pose_b: &Isometry3<f64>,
) -> Result<f64> {
    ensure_pose("pose_a", pose_a)?;
    ensure_pose("pose_b", pose_b)?;
    // Work in A's frame: A is axis-aligned at the origin, which keeps the arithmetic well scaled.
    let b_in_a = pose_a.inverse() * pose_b;
    let faces_a = faces(box_a, &Isometry3::identity());
    let faces_b = faces(box_b, &b_in_a);
    let tolerance =
        1e-12 * (box_a.diameter() + box_b.diameter() + b_in_a.translation.vector.norm());

    let mut volume = 0.0;
    for face in &faces_a {
        volume += face.clipped_volume_term(&faces_b, tolerance);
    }
    for face in &faces_b {
        let shared = faces_a.iter().any(|a| {
            a.normal.dot(&face.normal) > 1.0 - 1e-12 && (a.offset - face.offset).abs() <= tolerance
        });
        if !shared {
            volume += face.clipped_volume_term(&faces_a, tolerance);
        }
    }
    let intersection = (volume / 3.0).clamp(0.0, box_a.volume().min(box_b.volume()));
    Ok(intersection / (box_a.volume() + box_b.volume() - intersection))
}

/// A face of a box: its corners in cyclic order and its plane n·x = offset (n outward).
struct Face {
    polygon: Vec<Vector3<f64>>,
    normal: Vector3<f64>,
    offset: f64,
}

impl Face {
    /// (n·x) · area of this face clipped to the inside of all `planes`.
    fn clipped_volume_term(&self, planes: &[Face], tolerance: f64) -> f64 {
        let mut polygon = self.polygon.clone();
        for plane in planes {
            polygon = clip(&polygon, &plane.normal, plane.offset, tolerance);
            if polygon.len() < 3 {
                return 0.0;
            }
        }
        let origin = polygon[0];
        let doubled_area: Vector3<f64> = polygon
            .windows(2)
            .skip(1)
            .map(|w| (w[0] - origin).cross(&(w[1] - origin)))
            .sum();
        self.offset * 0.5 * doubled_area.norm()
    }
}

fn faces(model: &BoxModel, pose: &Isometry3<f64>) -> Vec<Face> {
    let half = model.size() * 0.5;
    let mut faces = Vec::with_capacity(6);
    for axis in 0..3 {
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        for sign in [-1.0, 1.0] {
            let corner = |sb: f64, sc: f64| {
                let mut local = Vector3::zeros();
                local[axis] = sign * half[axis];
                local[b] = sb * half[b];
                local[c] = sc * half[c];
                pose * Point3::from(local)
            };
            let polygon: Vec<Vector3<f64>> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .map(|&(sb, sc)| corner(sb, sc).coords)
                .collect();
            let normal = pose.rotation * (Vector3::ith(axis, sign));
            let offset = normal.dot(&polygon[0]);
            faces.push(Face {
                polygon,
                normal,
                offset,
            });
        }
    }
    faces
}

/// Sutherland–Hodgman: the part of a convex polygon where n·x ≤ offset (within `tolerance`).
fn clip(
    polygon: &[Vector3<f64>],
    normal: &Vector3<f64>,
    offset: f64,
    tolerance: f64,
) -> Vec<Vector3<f64>> {
    let mut out = Vec::with_capacity(polygon.len() + 2);
    for (i, current) in polygon.iter().enumerate() {
        let next = &polygon[(i + 1) % polygon.len()];
        let (dc, dn) = (normal.dot(current) - offset, normal.dot(next) - offset);
        let (inside_c, inside_n) = (dc <= tolerance, dn <= tolerance);
        if inside_c {
            out.push(*current);
        }
        // A crossing that repeats a kept vertex only adds a zero-area sliver.
        if inside_c != inside_n {
            out.push(current + (next - current) * (dc / (dc - dn)));
        }
    }
    out
}

fn ensure_pose(what: &'static str, pose: &Isometry3<f64>) -> Result<()> {
    ensure_finite(
        what,
        pose.translation
            .vector
            .iter()
            .chain(pose.rotation.coords.iter()),
    )
}

/// Area under the ROC curve of a fit's confidence as a predictor of its failure, from
/// (wrong, confidence) pairs (low confidence predicting a wrong fit): the probability that a wrong
/// fit has lower confidence than a right one, ties counting half (Mann–Whitney U). `None` when
/// either class is empty.
pub fn failure_auroc(outcomes: &[(bool, f64)]) -> Option<f64> {
    let wrong: Vec<f64> = outcomes.iter().filter(|o| o.0).map(|o| o.1).collect();
    let right: Vec<f64> = outcomes.iter().filter(|o| !o.0).map(|o| o.1).collect();
    if wrong.is_empty() || right.is_empty() {
        return None;
    }
    let mut sorted_right = right.clone();
    sorted_right.sort_by(f64::total_cmp);
    let mut sum = 0.0;
    for w in &wrong {
        let above = sorted_right.partition_point(|r| r <= w);
        let at_or_above = sorted_right.partition_point(|r| r < w);
        // right fits with confidence strictly above w count 1, equal ones ½
        sum += (sorted_right.len() - above) as f64 + 0.5 * (above - at_or_above) as f64;
    }
    Some(sum / (wrong.len() * right.len()) as f64)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    use super::{failure_auroc, mspd};
    use crate::box_model::BoxModel;

    #[test]
    fn mspd_is_the_largest_corner_shift_in_the_image_modulo_the_symmetries() {
        let model = BoxModel::new(Vector3::new(0.2, 0.1, 0.06)).unwrap();
        let k = [600.0, 500.0, 320.0, 240.0];
        let truth = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 1.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 0.5),
        );
        assert_eq!(mspd(&model, &truth, &truth, k).unwrap(), 0.0);
        // a half turn about the box's own x axis is one of its symmetries: no error
        let flipped =
            truth * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        assert!(mspd(&model, &flipped, &truth, k).unwrap() < 1e-9);
        // a shift of 1 cm along the camera's x axis moves every corner by fx·0.01/z pixels: the
        // largest for the nearest corner
        let shifted = Translation3::new(0.01, 0.0, 0.0) * truth;
        let nearest_z = model
            .corners()
            .iter()
            .map(|c| (truth * c).z)
            .fold(f64::INFINITY, f64::min);
        let error = mspd(&model, &shifted, &truth, k).unwrap();
        assert!((error - 600.0 * 0.01 / nearest_z).abs() < 1e-9, "{error}");
        assert!(mspd(&model, &shifted, &truth, [f64::NAN, 1.0, 0.0, 0.0]).is_err());
    }

    #[test]
    fn auroc_of_confidence_as_a_failure_predictor() {
        // every failure less confident than every right fit: 1; the reverse: 0
        assert_eq!(
            failure_auroc(&[(true, 0.1), (true, 0.2), (false, 0.8), (false, 0.9)]),
            Some(1.0)
        );
        assert_eq!(failure_auroc(&[(true, 0.9), (false, 0.1)]), Some(0.0));
        // all tied: chance
        assert_eq!(
            failure_auroc(&[(true, 0.5), (false, 0.5), (false, 0.5)]),
            Some(0.5)
        );
        // one of the two failures below the right fit, one tied with it: (1 + ½) / 2
        assert_eq!(
            failure_auroc(&[(true, 0.2), (true, 0.7), (false, 0.7)]),
            Some(0.75)
        );
        assert_eq!(failure_auroc(&[(false, 0.2), (false, 0.7)]), None);
    }
}
