//! The paper's stated next step: box pose and anisotropic size (dx, dy, dz) together, for boxes of
//! unknown size, from unordered corner detections.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::adaptive::{self, CostModel, FitConfidence, Placed, Refined, Separation};
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
        Self {
            truncation: f64::INFINITY,
            max_iterations: 50,
        }
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
/// assignment recovers from. Outliers far away skew principal axes, so every right angle between
/// three points (a corner and two edge neighbours) gives further starts. The 12 starts of least
/// cost are run; from each it alternates: match every point to its nearest
/// corner; fit rotation and translation to the inliers ([`kabsch`]); then, per axis, solve half
/// the side and the centre offset in closed form (a two-parameter linear least-squares problem in
/// the box frame). Inliers are the points within a cutoff that starts at twice the median residual
/// and tightens to `params.truncation` as the fit improves (graduated truncation, so that a start
/// far from the answer is not left without inliers). The start with the least cost wins.
///
/// Needs at least 4 points that do not all lie in one plane.
pub fn fit_pose_and_size(points: &[Point3<f64>], params: &SizeFitParams) -> Result<SizedBoxFit> {
    ensure_finite_points("points", points)?;
    if params.truncation.is_nan() || params.truncation <= 0.0 {
        return Err(GeometryError::InvalidParameter {
            name: "truncation",
            reason: "must be positive (or infinite)",
        });
    }
    if points.len() < 4 {
        return Err(GeometryError::TooFewPoints {
            what: "pose and size fit",
            needed: 4,
            got: points.len(),
        });
    }
    let centroid = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
    let scatter: Matrix3<f64> = points
        .iter()
        .map(|p| (p.coords - centroid) * (p.coords - centroid).transpose())
        .sum();
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
    let mut starts = Vec::new();
    for &rx in &TURNS {
        for &ry in &TURNS {
            for &rz in &TURNS {
                let rotation = principal
                    * Rotation3::from_euler_angles(
                        rx.to_radians(),
                        ry.to_radians(),
                        rz.to_radians(),
                    );
                let half_size = points
                    .iter()
                    .map(|p| (rotation.inverse() * (p.coords - centroid)).abs())
                    .sum::<Vector3<f64>>()
                    / points.len() as f64;
                starts.push(Start {
                    rotation,
                    centre: centroid,
                    half_size,
                });
            }
        }
    }
    starts.extend(right_angle_starts(points));

    // Alternating from every start costs far more than scoring it: run only the most promising.
    const STARTS_RUN: usize = 12;
    let mut scored: Vec<(f64, Start)> = starts
        .into_iter()
        .map(|start| (start.cost(points, params.truncation), start))
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.truncate(STARTS_RUN);

    let mut best: Option<Alternation> = None;
    for (_, start) in scored {
        let Some(fit) = Alternation::run(points, start, params) else {
            continue;
        };
        if best.as_ref().is_none_or(|b| fit.cost < b.cost) {
            best = Some(fit);
        }
    }
    let best = best.ok_or(GeometryError::Degenerate(
        "no start reached a box with positive sides",
    ))?;
    best.into_result(points, params.truncation)
}

/// One start of the alternation and where it ended.
struct Alternation {
    rotation: Rotation3<f64>,
    centre: Vector3<f64>,
    half_size: Vector3<f64>,
    cost: f64,
}

/// An initial box: frame, centre and half sides.
#[derive(Debug, Clone, Copy)]
struct Start {
    rotation: Rotation3<f64>,
    centre: Vector3<f64>,
    half_size: Vector3<f64>,
}

impl Start {
    /// The truncated cost of the start as it is, with the truncation widened to twice the median
    /// residual as in the alternation's first round.
    fn cost(&self, points: &[Point3<f64>], truncation: f64) -> f64 {
        let state = Alternation {
            rotation: self.rotation,
            centre: self.centre,
            half_size: self.half_size,
            cost: 0.0,
        };
        let (_, residuals) = state.nearest_corners(points);
        truncated_cost(&residuals, truncation.max(2.0 * median(&residuals)))
    }
}

/// Starts that do not depend on the points' principal axes, which outliers far from the box
/// dominate: every point `a` with two others `b`, `c` such that b − a ⟂ c − a (within about 8°)
/// may be a corner with two edge neighbours. That gives two axes and two sides; the third axis is
/// their normal, and the third side the median distance of the other points from the face's plane
/// (those off it), with the box on either side of the face: two starts per right angle.
fn right_angle_starts(points: &[Point3<f64>]) -> Vec<Start> {
    let mut starts = Vec::new();
    for (ia, a) in points.iter().enumerate() {
        for (ib, b) in points.iter().enumerate().filter(|&(ib, _)| ib != ia) {
            for (ic, c) in points
                .iter()
                .enumerate()
                .skip(ib + 1)
                .filter(|&(ic, _)| ic != ia)
            {
                let (edge_b, edge_c) = (b - a, c - a);
                let (len_b, len_c) = (edge_b.norm(), edge_c.norm());
                if len_b == 0.0
                    || len_c == 0.0
                    || (edge_b.dot(&edge_c) / (len_b * len_c)).abs() > 0.15
                {
                    continue;
                }
                let x = edge_b / len_b;
                let y = (edge_c - x * x.dot(&edge_c)).normalize();
                let z = x.cross(&y);
                let face_centre = a.coords + 0.5 * (edge_b + edge_c);
                let tolerance = 0.05 * len_b.min(len_c);
                let off_face: Vec<f64> = points
                    .iter()
                    .enumerate()
                    .filter(|&(i, _)| i != ia && i != ib && i != ic)
                    .map(|(_, p)| z.dot(&(p.coords - face_centre)).abs())
                    .filter(|&d| d > tolerance)
                    .collect();
                if off_face.is_empty() {
                    continue;
                }
                let depth = median(&off_face);
                let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
                let half_size = Vector3::new(0.5 * len_b, 0.5 * len_c, 0.5 * depth);
                for side in [-0.5, 0.5] {
                    starts.push(Start {
                        rotation,
                        centre: face_centre + z * (side * depth),
                        half_size,
                    });
                }
            }
        }
    }
    starts
}

impl Alternation {
    fn run(points: &[Point3<f64>], start: Start, params: &SizeFitParams) -> Option<Self> {
        let Start {
            rotation,
            centre,
            half_size,
        } = start;
        let mut state = Self {
            rotation,
            centre,
            half_size,
            cost: f64::INFINITY,
        };
        let mut previous = (Vec::new(), Vec::new());
        for _ in 0..params.max_iterations {
            let (assignment, residuals) = state.nearest_corners(points);
            // Graduated truncation: a start far from the answer has every residual above the
            // final truncation, so the cutoff starts at twice the median residual and tightens
            // with it down to the truncation asked for.
            let cutoff = params.truncation.max(2.0 * median(&residuals));
            let inliers: Vec<usize> = (0..points.len())
                .filter(|&i| residuals[i] < cutoff)
                .collect();
            let cost = truncated_cost(&residuals, cutoff);
            let settled = (&assignment, &inliers) == (&previous.0, &previous.1)
                && cost >= state.cost * (1.0 - 1e-12);
            state.cost = cost;
            if settled || inliers.len() < 4 {
                break;
            }
            let sources: Vec<Point3<f64>> = inliers
                .iter()
                .map(|&i| state.corner(assignment[i]))
                .collect();
            let targets: Vec<Point3<f64>> = inliers.iter().map(|&i| points[i]).collect();
            let pose = kabsch(&sources, &targets).ok()?;
            state.rotation = pose.rotation.to_rotation_matrix();
            state.centre = pose.translation.vector;
            state.solve_size_and_centre(&inliers, &assignment, points);
            previous = (assignment, inliers);
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
    fn solve_size_and_centre(
        &mut self,
        inliers: &[usize],
        assignment: &[usize],
        points: &[Point3<f64>],
    ) {
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
        let sse: f64 = residuals
            .iter()
            .zip(&inliers)
            .filter(|(_, b)| **b)
            .map(|(r, _)| r * r)
            .sum();
        Ok(SizedBoxFit {
            model: BoxModel::new(self.half_size * 2.0)?,
            pose: Isometry3::from_parts(
                Translation3::from(self.centre),
                UnitQuaternion::from_rotation_matrix(&self.rotation),
            ),
            nearest_corners,
            residuals,
            inliers,
            inlier_rms: if count > 0 {
                (sse / count as f64).sqrt()
            } else {
                f64::INFINITY
            },
            cost: self.cost,
        })
    }
}

fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[sorted.len() / 2]
}

fn truncated_cost(residuals: &[f64], truncation: f64) -> f64 {
    residuals
        .iter()
        .map(|&r| (r * r).min(truncation * truncation))
        .sum()
}

/// Settings of [`robust_size_fit`]; as for [`crate::robust::AdaptiveParams`], nothing here
/// thresholds residuals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobustSizeParams {
    /// Hypothesis gate: three peaks are taken as a corner and its two edge neighbours when the
    /// cosine of the angle between the edges is below this.
    pub right_angle_cosine: f64,
    /// How many of the best mutually different hypotheses are refined and compared.
    pub refine_top: usize,
    /// Upper bound on refinement rounds per hypothesis.
    pub max_refinements: usize,
}

impl Default for RobustSizeParams {
    fn default() -> Self {
        Self {
            right_angle_cosine: 0.25,
            refine_top: 6,
            max_refinements: 20,
        }
    }
}

/// The result of [`robust_size_fit`].
#[derive(Debug, Clone, PartialEq)]
pub struct RobustSizedFit {
    /// The box with the estimated side lengths (axis order as the fitted frame gives it).
    pub model: BoxModel,
    /// Maps box-frame points into the camera frame.
    pub pose: Isometry3<f64>,
    /// Per input point: the nearest corner of the fitted box.
    pub nearest_corners: Vec<usize>,
    /// Per input point: its distance (metres) to that corner.
    pub residuals: Vec<f64>,
    /// Per input point: whether the cost counts it as an inlier.
    pub inliers: Vec<bool>,
    pub inlier_count: usize,
    /// The cost that chose this box (nats; see [`crate::adaptive`]).
    pub cost: f64,
    /// Margin to the best different box, inliers, noise scale, mirror ambiguity.
    pub confidence: FitConfidence,
}

impl RobustSizedFit {
    /// Root mean square of the inliers' residuals, metres.
    pub fn inlier_rms(&self) -> f64 {
        crate::robust::inlier_rms(&self.residuals, &self.inliers)
    }
}

/// Pose and side lengths of a box of unknown size from unordered corner peaks, some of which may
/// be outliers, by the hypothesis-and-score design of [`crate::robust::adaptive_fit`].
///
/// Minimal sets fix the rotation and the sides they span:
/// - a peak with two others at a right angle from it (cosine below
///   [`RobustSizeParams::right_angle_cosine`]) is a corner with its two edge neighbours: two axes
///   and two sides; each further peak off that face gives the third side (and the side of the
///   face the box lies on);
/// - any three peaks forming an acute triangle may be three corners pairwise joined by face
///   diagonals: the triangle's sides fix all three box sides (X² = (d₁₂² + d₁₃² − d₂₃²)/2, …) and
///   the frame, up to the mirror image through the triangle's plane (both are tried).
///
/// Every 4-corner subset of a box that is not coplanar contains one of these, so 4 inliers not in
/// one plane suffice. Each hypothesis is scored by the noise-adaptive cost (9 parameters), the
/// best [`RobustSizeParams::refine_top`] that differ by more than a tenth of their diameter are
/// refined (nearest-corner assignment of the cost's inliers, [`kabsch`], closed-form sides and
/// centre, while the cost decreases), and the best wins. Deterministic; needs at least 4 points
/// not in one plane.
pub fn robust_size_fit(
    points: &[Point3<f64>],
    params: &RobustSizeParams,
) -> Result<RobustSizedFit> {
    let search = SizeSearch::new(points, params)?;
    let refined = search.refined_candidates();
    let separation = Separation::Corners {
        threshold: 0.1
            * refined
                .iter()
                .map(|r| r.placed.diameter())
                .fold(f64::INFINITY, f64::min),
    };
    let (best, confidence) = adaptive::choose(refined, points, separation)
        .ok_or(GeometryError::Degenerate("no box hypothesis"))?;
    let inlier_set = best.inlier_indices();
    let mut inliers = vec![false; points.len()];
    for &i in &inlier_set {
        inliers[i] = true;
    }
    Ok(RobustSizedFit {
        model: BoxModel::new(best.placed.half * 2.0)?,
        pose: Isometry3::from_parts(
            Translation3::from(best.placed.centre),
            UnitQuaternion::from_rotation_matrix(&best.placed.rotation),
        ),
        nearest_corners: best.nearest.iter().map(|n| n.0).collect(),
        residuals: best.nearest.iter().map(|n| n.1.sqrt()).collect(),
        inliers,
        inlier_count: inlier_set.len(),
        cost: best.cost,
        confidence,
    })
}

/// The confidence of any box (size and pose, from any fit) on `points`: its cost under the
/// noise-adaptive model against the best refined hypothesis of [`robust_size_fit`]'s search that
/// differs from it by more than a tenth of its diameter.
pub fn assess_sized_box(
    points: &[Point3<f64>],
    model: &BoxModel,
    pose: &Isometry3<f64>,
) -> Result<FitConfidence> {
    let search = SizeSearch::new(points, &RobustSizeParams::default())?;
    let refined = search.refined_candidates();
    let placed = Placed {
        rotation: pose.rotation.to_rotation_matrix(),
        centre: pose.translation.vector,
        half: model.size() * 0.5,
    };
    let given = Refined::new(placed, points, &search.cost_model);
    let runner_up = Separation::Corners {
        threshold: 0.1 * model.diameter(),
    }
    .runner_up_cost(&given.placed, &refined);
    Ok(adaptive::confidence_of(
        &given,
        runner_up - given.profile.cost,
        points,
    ))
}

struct SizeSearch<'a> {
    points: &'a [Point3<f64>],
    params: RobustSizeParams,
    cost_model: CostModel,
    /// The largest distance between two points: no side may exceed it by much.
    extent: f64,
}

impl<'a> SizeSearch<'a> {
    fn new(points: &'a [Point3<f64>], params: &RobustSizeParams) -> Result<Self> {
        ensure_finite_points("points", points)?;
        if !(params.right_angle_cosine > 0.0 && params.right_angle_cosine < 1.0) {
            return Err(GeometryError::InvalidParameter {
                name: "right_angle_cosine",
                reason: "must be in (0, 1)",
            });
        }
        if params.refine_top == 0 {
            return Err(GeometryError::InvalidParameter {
                name: "refine_top",
                reason: "must be at least 1",
            });
        }
        if points.len() < 4 {
            return Err(GeometryError::TooFewPoints {
                what: "robust pose and size fit",
                needed: 4,
                got: points.len(),
            });
        }
        let extent = points
            .iter()
            .flat_map(|a| points.iter().map(move |b| (a - b).norm()))
            .fold(0.0, f64::max);
        if extent == 0.0 {
            return Err(GeometryError::Degenerate("coincident points"));
        }
        if adaptive::coplanar(points, 1e-10 * extent) {
            return Err(GeometryError::Degenerate("coplanar points"));
        }
        Ok(Self {
            points,
            params: *params,
            cost_model: CostModel::new(points, 9),
            extent,
        })
    }

    fn hypotheses(&self) -> Vec<(f64, Placed)> {
        let points = self.points;
        let n = points.len();
        let min_side = 1e-3 * self.extent;
        let max_side = 1.5 * self.extent;
        let plausible = |half: &Vector3<f64>| {
            half.iter()
                .all(|&h| 2.0 * h >= min_side && 2.0 * h <= max_side)
        };
        let mut scratch = Vec::with_capacity(n);
        let mut hypotheses = Vec::new();
        let mut push = |placed: Placed, hypotheses: &mut Vec<(f64, Placed)>| {
            if plausible(&placed.half) {
                let profile = placed.cost(points, &self.cost_model, &mut scratch);
                hypotheses.push((profile.cost, placed));
            }
        };
        // A corner with its two edge neighbours, and a fourth peak for the depth.
        for a in 0..n {
            for b in (0..n).filter(|&b| b != a) {
                for c in (b + 1..n).filter(|&c| c != a) {
                    let (u, v) = (points[b] - points[a], points[c] - points[a]);
                    let (lu, lv) = (u.norm(), v.norm());
                    if lu == 0.0
                        || lv == 0.0
                        || (u.dot(&v) / (lu * lv)).abs() > self.params.right_angle_cosine
                    {
                        continue;
                    }
                    let x = u / lu;
                    let y = (v - x * x.dot(&v)).normalize();
                    let z = x.cross(&y);
                    let rotation =
                        Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
                    let (side_x, side_y) = (lu, y.dot(&v));
                    for q in (0..n).filter(|&q| q != a && q != b && q != c) {
                        let depth = z.dot(&(points[q] - points[a]));
                        let half = Vector3::new(0.5 * side_x, 0.5 * side_y, 0.5 * depth.abs());
                        let centre = points[a].coords + x * half.x + y * half.y + z * (0.5 * depth);
                        push(
                            Placed {
                                rotation,
                                centre,
                                half,
                            },
                            &mut hypotheses,
                        );
                    }
                }
            }
        }
        // Three corners pairwise joined by face diagonals, in both orientations.
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    for (p, q, r) in [(a, b, c), (a, c, b)] {
                        let (ab, ac, bc) = (
                            (points[q] - points[p]).norm_squared(),
                            (points[r] - points[p]).norm_squared(),
                            (points[r] - points[q]).norm_squared(),
                        );
                        let sides_sq = Vector3::new(
                            0.5 * (ab + ac - bc),
                            0.5 * (ab + bc - ac),
                            0.5 * (ac + bc - ab),
                        );
                        if sides_sq.min() <= 0.0 {
                            break;
                        }
                        let s = sides_sq.map(f64::sqrt);
                        // In the box frame with corner p at the origin: q = (X, Y, 0), r = (X, 0, Z).
                        let local = [
                            Point3::origin(),
                            Point3::new(s.x, s.y, 0.0),
                            Point3::new(s.x, 0.0, s.z),
                        ];
                        let Some(rotation) = crate::robust::triad(
                            [&local[0], &local[1], &local[2]],
                            [&points[p], &points[q], &points[r]],
                        ) else {
                            break;
                        };
                        let local_mean = (local[1].coords + local[2].coords) / 3.0;
                        let target_mean =
                            (points[p].coords + points[q].coords + points[r].coords) / 3.0;
                        let origin = target_mean - rotation * local_mean;
                        let centre = origin + rotation * (s * 0.5);
                        push(
                            Placed {
                                rotation,
                                centre,
                                half: s * 0.5,
                            },
                            &mut hypotheses,
                        );
                    }
                }
            }
        }
        adaptive::sort_by_cost(hypotheses)
    }

    fn refined_candidates(&self) -> Vec<Refined> {
        let hypotheses = self.hypotheses();
        // Distinct by a tenth of the best hypothesis's diameter.
        let separation = Separation::Corners {
            threshold: hypotheses.first().map_or(0.0, |h| 0.1 * h.1.diameter()),
        };
        adaptive::distinct(&hypotheses, separation, self.params.refine_top)
            .into_iter()
            .map(|placed| self.refine(placed))
            .collect()
    }

    fn refine(&self, placed: Placed) -> Refined {
        let mut best = Refined::new(placed, self.points, &self.cost_model);
        for _ in 0..self.params.max_refinements {
            let inliers = best.inlier_indices();
            let assignment: Vec<usize> = best.nearest.iter().map(|n| n.0).collect();
            let mut state = Alternation {
                rotation: best.placed.rotation,
                centre: best.placed.centre,
                half_size: best.placed.half,
                cost: best.cost,
            };
            let sources: Vec<Point3<f64>> = inliers
                .iter()
                .map(|&i| state.corner(assignment[i]))
                .collect();
            let targets: Vec<Point3<f64>> = inliers.iter().map(|&i| self.points[i]).collect();
            let Ok(pose) = kabsch(&sources, &targets) else {
                break;
            };
            state.rotation = pose.rotation.to_rotation_matrix();
            state.centre = pose.translation.vector;
            state.solve_size_and_centre(&inliers, &assignment, self.points);
            if !state.half_size.iter().all(|&h| h > 0.0 && h.is_finite()) {
                break;
            }
            let next = Refined::new(
                Placed {
                    rotation: state.rotation,
                    centre: state.centre,
                    half: state.half_size,
                },
                self.points,
                &self.cost_model,
            );
            if next.cost >= best.cost {
                break;
            }
            best = next;
        }
        best
    }
}
