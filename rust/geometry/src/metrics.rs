//! Pose error metrics, one function per metric, each defined in its doc comment (in the manner of
//! bop_toolkit's `pose_error.py`). A pose maps box-frame points into the camera frame; `estimate`
//! is the fitted pose and `truth` the ground truth. Distances are in metres.

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

use crate::box_model::{BoxModel, CORNER_COUNT};
use crate::error::{GeometryError, Result, ensure_finite, ensure_finite_points};

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

/// ADD-S over the 8 corners (Hinterstoisser et al. 2012, for symmetric objects):
///
/// e_ADD-S = (1/8) Σ_{x₁ ∈ corners} min_{x₂ ∈ corners} ‖estimate·x₁ − truth·x₂‖
///
/// The model points are the box's corners, not a surface sample: they are the points the pipeline
/// detects, and the box's symmetries permute them.
pub fn add_s(model: &BoxModel, estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Result<f64> {
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
    let corners = model.corners();
    Ok(model
        .symmetries()
        .iter()
        .map(|s| {
            corners
                .iter()
                .map(|x| (estimate * x - truth * (s.rotation * x)).norm())
                .fold(0.0, f64::max)
        })
        .fold(f64::INFINITY, f64::min))
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
