//! A box pose that survives outlying peaks: the paper's search fits `m` = 5 of the 8 peaks and
//! fails as soon as one of them is an outlier (its two counterexamples with four NMS outliers).
//! Here every minimal hypothesis (3 peaks ↔ 3 corners whose pairwise distances agree) is tried
//! deterministically, scored by a truncated least-squares cost over all peaks, and the best one is
//! refined on its inliers.

use nalgebra::{Isometry3, Point3};

use crate::align::{kabsch, quaternion_kabsch};
use crate::box_model::{BoxModel, CORNER_COUNT};
use crate::correspondence::ensure_spread_in_two_directions;
use crate::error::{GeometryError, Result, ensure_finite_points};

/// Settings of [`robust_fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobustParams {
    /// A peak within this distance (metres) of its nearest fitted corner is an inlier; squared
    /// residuals are truncated at its square.
    pub inlier_threshold: f64,
    /// Upper bound on refinement rounds (re-assign inliers, re-fit), which usually settle in 2–3.
    pub max_refinements: usize,
}

impl RobustParams {
    /// A threshold of a quarter of the box's shortest side: above the noise of a useful detector,
    /// and below half the smallest corner spacing, so that no peak is an inlier of two corners.
    pub fn for_box(model: &BoxModel) -> Self {
        Self {
            inlier_threshold: 0.25 * model.size().min(),
            max_refinements: 20,
        }
    }
}

/// The result of [`robust_fit`], with what is needed to judge how far to trust it.
#[derive(Debug, Clone, PartialEq)]
pub struct RobustFit {
    /// Maps box-frame points into the camera frame.
    pub pose: Isometry3<f64>,
    /// Per input point: whether it lies within the inlier threshold of a fitted corner.
    pub inliers: Vec<bool>,
    /// Per input point: the model corner nearest to it under the fitted pose.
    pub nearest_corners: Vec<usize>,
    /// Per input point: its distance (metres) to that corner.
    pub residuals: Vec<f64>,
    /// How many points are inliers (at least 3).
    pub inlier_count: usize,
    /// Root mean square of the inliers' residuals (metres).
    pub inlier_rms: f64,
    /// Σ min(residual², threshold²) over all points: the cost that chose this pose.
    pub truncated_cost: f64,
}

/// Pose of a box of known size from unordered corner detections, up to half of which (4 of 8) may
/// be outliers.
///
/// Every triple of points is matched with every triple of corners whose pairwise distances agree
/// within twice the inlier threshold (corner triples related by a box symmetry give the same pose
/// and are tried once). Each hypothesis is fitted with [`kabsch`] and scored by the truncated cost
/// Σ min(r², τ²), r the distance of each point to its nearest fitted corner. The best one is then
/// refined: each inlier is matched to its nearest corner and the pose re-fitted on those pairs,
/// while the cost decreases. Exhaustive and deterministic; needs at least 3 points spanning a plane.
///
/// Four inliers in one plane (a face, or a diagonal section) fit the box and its mirror image
/// through that plane equally well: the result is then one of the two, and only the outliers'
/// positions, if any fall near a corner of one of them, can tell them apart.
pub fn robust_fit(
    model: &BoxModel,
    points: &[Point3<f64>],
    params: &RobustParams,
) -> Result<RobustFit> {
    ensure_finite_points("points", points)?;
    if !(params.inlier_threshold.is_finite() && params.inlier_threshold > 0.0) {
        return Err(GeometryError::InvalidParameter {
            name: "inlier_threshold",
            reason: "must be finite and positive",
        });
    }
    if points.len() < 3 {
        return Err(GeometryError::TooFewPoints {
            what: "robust fit",
            needed: 3,
            got: points.len(),
        });
    }
    ensure_spread_in_two_directions(points)?;

    let corners = model.corners();
    let threshold = params.inlier_threshold;
    let corner_triples = canonical_corner_triples(model);
    let distance = |a: &Point3<f64>, b: &Point3<f64>| (a - b).norm();
    let agrees = |a: &Point3<f64>, b: &Point3<f64>, c: usize, d: usize| {
        (distance(a, b) - distance(&corners[c], &corners[d])).abs() <= 2.0 * threshold
    };

    // Scoring dominates: hypotheses are only costed, with an early exit once the running cost
    // exceeds the best one's, and the winner alone is scored in full.
    let mut best: Option<(f64, Isometry3<f64>)> = None;
    let n = points.len();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let (p, q, r) = (&points[i], &points[j], &points[k]);
                for &[a, b, c] in &corner_triples {
                    if !(agrees(p, q, a, b) && agrees(p, r, a, c) && agrees(q, r, b, c)) {
                        continue;
                    }
                    // A collinear point triple determines no pose: skip the hypothesis.
                    let Ok(pose) =
                        quaternion_kabsch(&[corners[a], corners[b], corners[c]], &[*p, *q, *r])
                    else {
                        continue;
                    };
                    let bound = best.as_ref().map_or(f64::INFINITY, |(cost, _)| *cost);
                    let cost = truncated_cost_below(&pose, &corners, points, threshold, bound);
                    if cost < bound {
                        best = Some((cost, pose));
                    }
                }
            }
        }
    }
    let (_, pose) = best.ok_or(GeometryError::NoConsensus { needed: 3 })?;
    let mut best = Scored::new(pose, &corners, points, threshold);

    for _ in 0..params.max_refinements {
        let (sources, targets): (Vec<_>, Vec<_>) = (0..n)
            .filter(|&i| best.inliers[i])
            .map(|i| (corners[best.nearest_corners[i]], points[i]))
            .unzip();
        // Fewer than 3 inliers, or inliers on a line, leave nothing to refine.
        let Ok(pose) = kabsch(&sources, &targets) else {
            break;
        };
        let refined = Scored::new(pose, &corners, points, threshold);
        if !refined.is_better_than(&best) {
            break;
        }
        best = refined;
    }

    let inlier_count = best.inliers.iter().filter(|&&b| b).count();
    if inlier_count < 3 {
        return Err(GeometryError::NoConsensus { needed: 3 });
    }
    let inlier_sse: f64 = best
        .residuals
        .iter()
        .zip(&best.inliers)
        .filter(|(_, inlier)| **inlier)
        .map(|(r, _)| r * r)
        .sum();
    Ok(RobustFit {
        pose: best.pose,
        inliers: best.inliers,
        nearest_corners: best.nearest_corners,
        residuals: best.residuals,
        inlier_count,
        inlier_rms: (inlier_sse / inlier_count as f64).sqrt(),
        truncated_cost: best.cost,
    })
}

/// Σ min(r², τ²) over the points under `pose`, or any value ≥ `bound` as soon as the running sum
/// reaches it.
fn truncated_cost_below(
    pose: &Isometry3<f64>,
    corners: &[Point3<f64>; CORNER_COUNT],
    points: &[Point3<f64>],
    threshold: f64,
    bound: f64,
) -> f64 {
    let placed: [Point3<f64>; CORNER_COUNT] = std::array::from_fn(|c| pose * corners[c]);
    let cap = threshold * threshold;
    let mut cost = 0.0;
    for p in points {
        cost += placed
            .iter()
            .map(|c| (c - p).norm_squared())
            .fold(cap, f64::min);
        if cost >= bound {
            break;
        }
    }
    cost
}

/// A pose with its per-point nearest corners, residuals and truncated cost.
struct Scored {
    pose: Isometry3<f64>,
    nearest_corners: Vec<usize>,
    residuals: Vec<f64>,
    inliers: Vec<bool>,
    cost: f64,
}

impl Scored {
    fn new(
        pose: Isometry3<f64>,
        corners: &[Point3<f64>; CORNER_COUNT],
        points: &[Point3<f64>],
        threshold: f64,
    ) -> Self {
        let placed: [Point3<f64>; CORNER_COUNT] = std::array::from_fn(|c| pose * corners[c]);
        let (nearest_corners, residuals): (Vec<usize>, Vec<f64>) = points
            .iter()
            .map(|p| {
                let (corner, squared) = placed
                    .iter()
                    .map(|c| (c - p).norm_squared())
                    .enumerate()
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("a box has corners");
                (corner, squared.sqrt())
            })
            .unzip();
        let inliers: Vec<bool> = residuals.iter().map(|&r| r < threshold).collect();
        let cost = residuals
            .iter()
            .map(|&r| (r * r).min(threshold * threshold))
            .sum();
        Self {
            pose,
            nearest_corners,
            residuals,
            inliers,
            cost,
        }
    }

    /// Lower truncated cost wins; strict, so that refinement stops once it stops gaining.
    fn is_better_than(&self, other: &Scored) -> bool {
        self.cost < other.cost
    }
}

/// Ordered triples of distinct corners, one per orbit of the box's symmetry group (the
/// lexicographically smallest), since symmetric triples yield symmetric poses of equal cost.
fn canonical_corner_triples(model: &BoxModel) -> Vec<[usize; 3]> {
    let symmetries = model.symmetries();
    let mut triples = Vec::new();
    for a in 0..CORNER_COUNT {
        for b in (0..CORNER_COUNT).filter(|&b| b != a) {
            for c in (0..CORNER_COUNT).filter(|&c| c != a && c != b) {
                let triple = [a, b, c];
                let smallest = symmetries
                    .iter()
                    .all(|g| triple.map(|x| g.corner_permutation[x]) >= triple);
                if smallest {
                    triples.push(triple);
                }
            }
        }
    }
    triples
}
