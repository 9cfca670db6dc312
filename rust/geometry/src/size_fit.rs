//! The paper's stated next step: box pose and anisotropic size (dx, dy, dz) together, for boxes of
//! unknown size, from unordered corner detections.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::align::kabsch;
use crate::box_model::{BoxModel, CORNER_COUNT, corner_signs};
use crate::error::{GeometryError, Result, ensure_finite_points};

/// Settings of [`fit_pose_and_size`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeFitParams {
    /// Points farther than this (metres) from their nearest fitted corner are left out of the fit
    /// and cost `truncation²`; `f64::INFINITY` makes it a plain least-squares fit.
    pub truncation: f64,
    /// Upper bound on alternation rounds per start.
    pub max_iterations: usize,
}

impl Default for SizeFitParams {
    fn default() -> Self {
        Self { truncation: f64::INFINITY, max_iterations: 50 }
    }
}

/// A box of estimated size and its pose.
#[derive(Debug, Clone, PartialEq)]
pub struct SizedBoxFit {
    /// The box with the estimated side lengths. Its axes are the fitted frame's axes: the order
    /// of the sides is the one that frame gives and carries no meaning of its own.
    pub model: BoxModel,
    /// Maps box-frame points into the camera frame.
    pub pose: Isometry3<f64>,
    /// Per input point: the nearest corner of the fitted box.
    pub nearest_corners: Vec<usize>,
    /// Per input point: its distance (metres) to that corner.
    pub residuals: Vec<f64>,
    /// Per input point: whether its residual is below the truncation.
    pub inliers: Vec<bool>,
    /// Root mean square of the inliers' residuals (metres).
    pub inlier_rms: f64,
    /// Σ min(residual², truncation²) over all points.
    pub cost: f64,
}

/// Rotation, translation and side lengths of the box whose corners best fit `points`
/// (Σ over points of the squared distance to the nearest corner, truncated as in `params`).
///
/// Scaling ICP with a closed-form size step. It starts from the principal axes of the points (for
/// the 8 corners of a box with distinct sides they are its edges, and the mean |coordinate| along
/// each is half a side) and, since principal axes are arbitrary when two or three sides are about
/// equal or corners are missing, also from that frame turned by every combination of −30°, 0 and
/// +30° about its three axes: 27 deterministic starts, a spacing that the nearest-corner
/// assignment recovers from. From each start it alternates: match every point to its nearest
/// corner; fit rotation and translation to the inliers ([`kabsch`]); then, per axis, solve half
/// the side and the centre offset in closed form (a two-parameter linear least-squares problem in
/// the box frame). The start with the least cost wins.
///
/// Needs at least 4 points that do not all lie in one plane.
pub fn fit_pose_and_size(points: &[Point3<f64>], params: &SizeFitParams) -> Result<SizedBoxFit> {
    ensure_finite_points("points", points)?;
    if !(params.truncation > 0.0) || params.truncation.is_nan() {
        return Err(GeometryError::InvalidParameter { name: "truncation", reason: "must be positive (or infinite)" });
    }
    if points.len() < 4 {
        return Err(GeometryError::TooFewPoints { what: "pose and size fit", needed: 4, got: points.len() });
    }
    let centroid = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
    let scatter: Matrix3<f64> =
        points.iter().map(|p| (p.coords - centroid) * (p.coords - centroid).transpose()).sum();
    let eigen = scatter.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if largest <= 0.0 {
        return Err(GeometryError::Degenerate("coincident points"));
    }
    // A box needs extent along all three axes; squared lengths, so 1e-20 is a 1e-10 thickness.
    if eigen.eigenvalues.min() <= 1e-20 * largest {
        return Err(GeometryError::Degenerate("coplanar points"));
    }
    let mut axes = eigen.eigenvectors;
    if axes.determinant() < 0.0 {
        axes.column_mut(2).neg_mut();
    }
    let principal = Rotation3::from_matrix_unchecked(axes);

    const TURNS: [f64; 3] = [-30.0, 0.0, 30.0];
    let mut best: Option<Alternation> = None;
    for &rx in &TURNS {
        for &ry in &TURNS {
            for &rz in &TURNS {
                let turn = Rotation3::from_euler_angles(rx.to_radians(), ry.to_radians(), rz.to_radians());
                let Some(fit) = Alternation::run(points, principal * turn, centroid, params) else { continue };
                if best.as_ref().is_none_or(|b| fit.cost < b.cost) {
                    best = Some(fit);
                }
            }
        }
    }
    let best = best.ok_or(GeometryError::Degenerate("no start reached a box with positive sides"))?;
    best.into_result(points, params.truncation)
}

/// One start of the alternation and where it ended.
struct Alternation {
    rotation: Rotation3<f64>,
    centre: Vector3<f64>,
    half_size: Vector3<f64>,
    cost: f64,
}

impl Alternation {
    fn run(points: &[Point3<f64>], rotation: Rotation3<f64>, centre: Vector3<f64>, params: &SizeFitParams) -> Option<Self> {
        let local = |p: &Point3<f64>| rotation.inverse() * (p.coords - centre);
        let half_size = points.iter().map(|p| local(p).abs()).sum::<Vector3<f64>>() / points.len() as f64;
        let mut state = Self { rotation, centre, half_size, cost: f64::INFINITY };
        let mut previous_assignment = Vec::new();
        for _ in 0..params.max_iterations {
            let (assignment, residuals) = state.nearest_corners(points);
            let inliers: Vec<usize> = (0..points.len()).filter(|&i| residuals[i] < params.truncation).collect();
            let cost = truncated_cost(&residuals, params.truncation);
            let settled = assignment == previous_assignment && cost >= state.cost * (1.0 - 1e-12);
            state.cost = cost;
            if settled || inliers.len() < 4 {
                break;
            }
            let sources: Vec<Point3<f64>> = inliers.iter().map(|&i| state.corner(assignment[i])).collect();
            let targets: Vec<Point3<f64>> = inliers.iter().map(|&i| points[i]).collect();
            let pose = kabsch(&sources, &targets).ok()?;
            state.rotation = pose.rotation.to_rotation_matrix();
            state.centre = pose.translation.vector;
            state.solve_size_and_centre(&inliers, &assignment, points);
            previous_assignment = assignment;
        }
        let (_, residuals) = state.nearest_corners(points);
        state.cost = truncated_cost(&residuals, params.truncation);
        let positive = state.half_size.iter().all(|&h| h > 0.0);
        (positive && state.cost.is_finite()).then_some(state)
    }

    fn corner(&self, index: usize) -> Point3<f64> {
        Point3::from(corner_signs(index).component_mul(&self.half_size))
    }

    fn nearest_corners(&self, points: &[Point3<f64>]) -> (Vec<usize>, Vec<f64>) {
        let placed: [Vector3<f64>; CORNER_COUNT] =
            std::array::from_fn(|c| self.rotation * self.corner(c).coords + self.centre);
        points
            .iter()
            .map(|p| {
                let (corner, squared) = placed
                    .iter()
                    .map(|c| (c - p.coords).norm_squared())
                    .enumerate()
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("a box has corners");
                (corner, squared.sqrt())
            })
            .unzip()
    }

    /// With the rotation fixed, each box axis a decouples: minimise Σ_k (s_ka·h_a + c_a − q_ka)²
    /// over the half side h_a and the centre offset c_a, where q are the points in the rotated
    /// frame and s_k the sign pattern of point k's corner. When all points sit on one side of an
    /// axis that side is undetermined, and is kept.
    fn solve_size_and_centre(&mut self, inliers: &[usize], assignment: &[usize], points: &[Point3<f64>]) {
        let n = inliers.len() as f64;
        let frame_centre = self.rotation.inverse() * self.centre;
        let mut new_centre = frame_centre;
        for axis in 0..3 {
            let (mut sum_s, mut sum_q, mut sum_sq) = (0.0, 0.0, 0.0);
            for &i in inliers {
                let s = corner_signs(assignment[i])[axis];
                let q = (self.rotation.inverse() * points[i].coords)[axis];
                sum_s += s;
                sum_q += q;
                sum_sq += s * q;
            }
            let determinant = n * n - sum_s * sum_s;
            if determinant > 0.5 {
                let half = (n * sum_sq - sum_s * sum_q) / determinant;
                if half > 0.0 {
                    self.half_size[axis] = half;
                    new_centre[axis] = (sum_q - sum_s * half) / n;
                }
            } else {
                new_centre[axis] = (sum_q - sum_s * self.half_size[axis]) / n;
            }
        }
        self.centre = self.rotation * new_centre;
    }

    fn into_result(self, points: &[Point3<f64>], truncation: f64) -> Result<SizedBoxFit> {
        let (nearest_corners, residuals) = self.nearest_corners(points);
        let inliers: Vec<bool> = residuals.iter().map(|&r| r < truncation).collect();
        let count = inliers.iter().filter(|&&b| b).count();
        let sse: f64 = residuals.iter().zip(&inliers).filter(|(_, b)| **b).map(|(r, _)| r * r).sum();
        Ok(SizedBoxFit {
            model: BoxModel::new(self.half_size * 2.0)?,
            pose: Isometry3::from_parts(
                Translation3::from(self.centre),
                UnitQuaternion::from_rotation_matrix(&self.rotation),
            ),
            nearest_corners,
            residuals,
            inliers,
            inlier_rms: if count > 0 { (sse / count as f64).sqrt() } else { f64::INFINITY },
            cost: self.cost,
        })
    }
}

fn truncated_cost(residuals: &[f64], truncation: f64) -> f64 {
    residuals.iter().map(|&r| (r * r).min(truncation * truncation)).sum()
}
