//! A box pose that survives outlying peaks: the paper's search fits `m` = 5 of the 8 peaks and
//! fails as soon as one of them is an outlier (its two counterexamples with four NMS outliers).
//! Here every minimal hypothesis (3 peaks ↔ 3 corners whose pairwise distances agree) is tried
//! deterministically, scored by a truncated least-squares cost over all peaks, and the best one is
//! refined on its inliers.

use std::sync::OnceLock;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::adaptive::{self, CostModel, FitConfidence, Placed, Refined, Separation};
use crate::align::{kabsch, quaternion_kabsch};
use crate::box_model::{BoxModel, CORNER_COUNT, ShapeClass};
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

/// Settings of [`adaptive_fit`]. None of them is a threshold on the residuals: the cost
/// ([`crate::adaptive`]) estimates the peaks' noise per hypothesis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptiveParams {
    /// Hypothesis gate: 3 peaks are matched with 3 corners only if their pairwise distances agree
    /// within this (metres). It decides which hypotheses are tried, not how they are scored, and
    /// may be generous; `None` is half the shortest side or 4 cm, whichever is larger.
    pub pair_tolerance: Option<f64>,
    /// How many of the best mutually different hypotheses are refined and compared.
    pub refine_top: usize,
    /// Upper bound on refinement rounds per hypothesis.
    pub max_refinements: usize,
}

impl Default for AdaptiveParams {
    fn default() -> Self {
        Self {
            pair_tolerance: None,
            refine_top: 6,
            max_refinements: 10,
        }
    }
}

/// The result of [`adaptive_fit`].
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveFit {
    /// Maps box-frame points into the camera frame.
    pub pose: Isometry3<f64>,
    /// Per input point: whether the cost counts it as an inlier.
    pub inliers: Vec<bool>,
    /// Per input point: the model corner nearest to it under the fitted pose.
    pub nearest_corners: Vec<usize>,
    /// Per input point: its distance (metres) to that corner.
    pub residuals: Vec<f64>,
    /// How many points are inliers (at least 3, at least 4 when there are 4 points or more).
    pub inlier_count: usize,
    /// The cost that chose this pose (nats; see [`crate::adaptive`]).
    pub cost: f64,
    /// Margin to the best different pose, inliers, noise scale, mirror ambiguity.
    pub confidence: FitConfidence,
}

impl AdaptiveFit {
    /// Root mean square of the inliers' residuals, metres.
    pub fn inlier_rms(&self) -> f64 {
        inlier_rms(&self.residuals, &self.inliers)
    }
}

/// Root mean square of the residuals whose point is an inlier (0 when there is none).
pub fn inlier_rms(residuals: &[f64], inliers: &[bool]) -> f64 {
    let (sum, count) = residuals
        .iter()
        .zip(inliers)
        .filter(|(_, inlier)| **inlier)
        .fold((0.0, 0usize), |(sum, count), (r, _)| {
            (sum + r * r, count + 1)
        });
    (sum / count.max(1) as f64).sqrt()
}

/// Pose of a box of known size from unordered corner peaks, up to half of which may be outliers,
/// with no threshold in box units: every triple of peaks is matched with every triple of corners
/// whose pairwise distances agree within [`AdaptiveParams::pair_tolerance`] (symmetric corner
/// triples once), each hypothesis is scored by the noise-adaptive cost of [`crate::adaptive`]
/// (a profile likelihood over the inlier count and the noise scale), the best
/// [`AdaptiveParams::refine_top`] hypotheses that differ by more than a tenth of the box's
/// diameter are refined (re-assign the cost's inliers to their nearest corners, re-fit with
/// [`kabsch`], while the cost decreases), and the best refined pose wins. Exhaustive and
/// deterministic; needs at least 3 points spanning a plane.
///
/// Four inliers in one plane fit the box and its mirror image alike. The cost then adds a small
/// prior ([`crate::adaptive`]: one nat per inlier matched to a corner the box hides from the
/// camera at the origin), which prefers the pose whose inliers the camera sees; when that does not
/// separate them either, [`FitConfidence::mirror_ambiguous`] is set.
pub fn adaptive_fit(
    model: &BoxModel,
    points: &[Point3<f64>],
    params: &AdaptiveParams,
) -> Result<AdaptiveFit> {
    let search = KnownSizeSearch::new(model, points, params)?;
    let refined = search.refined_candidates();
    let (best, confidence) = adaptive::choose(refined, points, search.separation())
        .ok_or(GeometryError::NoConsensus { needed: 3 })?;
    let inlier_set = best.inlier_indices();
    let mut inliers = vec![false; points.len()];
    for &i in &inlier_set {
        inliers[i] = true;
    }
    Ok(AdaptiveFit {
        pose: isometry_of(&best.placed),
        inliers,
        nearest_corners: best.nearest.iter().map(|n| n.0).collect(),
        residuals: best.nearest.iter().map(|n| n.1.sqrt()).collect(),
        inlier_count: inlier_set.len(),
        cost: best.cost,
        confidence,
    })
}

/// The poses [`adaptive_fit`] chose among: its best mutually different hypotheses, each refined,
/// cheapest first. The first is the fit's pose; the others are what a second witness (the depth
/// image: [`crate::depth_refine::choose_with_depth`]) may prefer when the peaks do not fix the
/// pose (an occluded box with four of its corners seen).
pub fn adaptive_candidates(
    model: &BoxModel,
    points: &[Point3<f64>],
    params: &AdaptiveParams,
) -> Result<Vec<Isometry3<f64>>> {
    let search = KnownSizeSearch::new(model, points, params)?;
    let mut refined = search.refined_candidates();
    refined.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    Ok(refined.iter().map(|r| isometry_of(&r.placed)).collect())
}

/// The confidence of any pose of a box of known size on `points` (from any fit): its cost under
/// the noise-adaptive model against the best refined hypothesis of [`adaptive_fit`]'s search that
/// differs from it by more than a tenth of the diameter. Negative margin (confidence 0) when the
/// search found a better different pose.
pub fn assess_pose(
    model: &BoxModel,
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
) -> Result<FitConfidence> {
    let search = KnownSizeSearch::new(model, points, &AdaptiveParams::default())?;
    let refined = search.refined_candidates();
    let given = Refined::new(placed_of(model, pose), points, &search.cost_model);
    let runner_up = search.separation().runner_up_cost(&given.placed, &refined);
    Ok(adaptive::confidence_of(
        &given,
        runner_up - given.profile.cost,
        points,
    ))
}

struct KnownSizeSearch<'a> {
    model: &'a BoxModel,
    points: &'a [Point3<f64>],
    params: AdaptiveParams,
    cost_model: CostModel,
}

impl<'a> KnownSizeSearch<'a> {
    fn new(
        model: &'a BoxModel,
        points: &'a [Point3<f64>],
        params: &AdaptiveParams,
    ) -> Result<Self> {
        ensure_finite_points("points", points)?;
        if let Some(t) = params.pair_tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return Err(GeometryError::InvalidParameter {
                name: "pair_tolerance",
                reason: "must be finite and positive",
            });
        }
        if params.refine_top == 0 {
            return Err(GeometryError::InvalidParameter {
                name: "refine_top",
                reason: "must be at least 1",
            });
        }
        if points.len() < 3 {
            return Err(GeometryError::TooFewPoints {
                what: "adaptive robust fit",
                needed: 3,
                got: points.len(),
            });
        }
        ensure_spread_in_two_directions(points)?;
        Ok(Self {
            model,
            points,
            params: *params,
            cost_model: CostModel::new(points, 6),
        })
    }

    /// Every gated minimal hypothesis, scored, best first.
    fn hypotheses(&self) -> Vec<(f64, Placed)> {
        let corners = self.model.corners();
        let half = self.model.size() * 0.5;
        let tolerance = self
            .params
            .pair_tolerance
            .unwrap_or((0.5 * self.model.size().min()).max(0.04));
        let points = self.points;
        let n = points.len();
        let corner_distance: [[f64; CORNER_COUNT]; CORNER_COUNT] =
            std::array::from_fn(|a| std::array::from_fn(|b| (corners[a] - corners[b]).norm()));
        let point_distance: Vec<Vec<f64>> = (0..n)
            .map(|i| (0..n).map(|j| (points[i] - points[j]).norm()).collect())
            .collect();
        let agrees = |i: usize, j: usize, a: usize, b: usize| {
            (point_distance[i][j] - corner_distance[a][b]).abs() <= tolerance
        };
        let triples = cached_corner_triples(self.model);
        let mut scratch = Vec::with_capacity(n);
        let mut hypotheses = Vec::new();
        for i in 0..n {
            for j in i + 1..n {
                for k in j + 1..n {
                    for &[a, b, c] in triples {
                        if !(agrees(i, j, a, b) && agrees(i, k, a, c) && agrees(j, k, b, c)) {
                            continue;
                        }
                        let Some(rotation) = triad(
                            [&corners[a], &corners[b], &corners[c]],
                            [&points[i], &points[j], &points[k]],
                        ) else {
                            continue;
                        };
                        let source_mean =
                            (corners[a].coords + corners[b].coords + corners[c].coords) / 3.0;
                        let target_mean =
                            (points[i].coords + points[j].coords + points[k].coords) / 3.0;
                        let placed = Placed {
                            rotation,
                            centre: target_mean - rotation * source_mean,
                            half,
                        };
                        let profile = placed.cost(points, &self.cost_model, &mut scratch);
                        hypotheses.push((profile.cost, placed));
                    }
                }
            }
        }
        adaptive::sort_by_cost(hypotheses)
    }

    /// Poses farther apart than the failure criterion, MSSD > 0.1 × diameter.
    fn separation(&self) -> Separation {
        Separation::Mssd {
            threshold: 0.1 * self.model.diameter(),
            permutations: self.model.symmetry_permutations(),
        }
    }

    /// The best mutually different hypotheses, each refined.
    fn refined_candidates(&self) -> Vec<Refined> {
        let hypotheses = self.hypotheses();
        adaptive::distinct(&hypotheses, self.separation(), self.params.refine_top)
            .into_iter()
            .map(|placed| self.refine(placed))
            .collect()
    }

    fn refine(&self, placed: Placed) -> Refined {
        let corners = self.model.corners();
        let mut best = Refined::new(placed, self.points, &self.cost_model);
        for _ in 0..self.params.max_refinements {
            let (sources, targets): (Vec<_>, Vec<_>) = best
                .inlier_indices()
                .into_iter()
                .map(|i| (corners[best.nearest[i].0], self.points[i]))
                .unzip();
            let Ok(pose) = kabsch(&sources, &targets) else {
                break;
            };
            let next = Refined::new(placed_of(self.model, &pose), self.points, &self.cost_model);
            if next.cost >= best.cost {
                break;
            }
            best = next;
        }
        best
    }
}

fn placed_of(model: &BoxModel, pose: &Isometry3<f64>) -> Placed {
    Placed {
        rotation: pose.rotation.to_rotation_matrix(),
        centre: pose.translation.vector,
        half: model.size() * 0.5,
    }
}

fn isometry_of(placed: &Placed) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(placed.centre),
        UnitQuaternion::from_rotation_matrix(&placed.rotation),
    )
}

/// The rotation taking the frame of `source` (first edge, triangle normal) onto that of
/// `target`; `None` when either triangle is degenerate.
pub(crate) fn triad(
    source: [&Point3<f64>; 3],
    target: [&Point3<f64>; 3],
) -> Option<Rotation3<f64>> {
    let frame = |p: [&Point3<f64>; 3]| -> Option<Matrix3<f64>> {
        let (u, v) = (p[1] - p[0], p[2] - p[0]);
        let normal = u.cross(&v);
        let scale = u.norm_squared() * v.norm_squared();
        if normal.norm_squared() <= 1e-12 * scale || scale == 0.0 {
            return None;
        }
        let e1 = u.normalize();
        let e3 = normal.normalize();
        Some(Matrix3::from_columns(&[e1, e3.cross(&e1), e3]))
    };
    let (s, t) = (frame(source)?, frame(target)?);
    Some(Rotation3::from_matrix_unchecked(t * s.transpose()))
}

/// [`canonical_corner_triples`] per symmetry class, computed once.
fn cached_corner_triples(model: &BoxModel) -> &'static [[usize; 3]] {
    static TABLES: OnceLock<[Vec<[usize; 3]>; 5]> = OnceLock::new();
    let tables = TABLES.get_or_init(|| {
        let of = |size: [f64; 3]| {
            canonical_corner_triples(&BoxModel::new(Vector3::from(size)).expect("positive sides"))
        };
        [
            of([1.0, 2.0, 3.0]),
            of([1.0, 2.0, 2.0]),
            of([2.0, 1.0, 2.0]),
            of([2.0, 2.0, 1.0]),
            of([1.0, 1.0, 1.0]),
        ]
    });
    let index = match model.shape_class(BoxModel::DEFAULT_SYMMETRY_TOLERANCE) {
        ShapeClass::Generic => 0,
        ShapeClass::SquareFaced { axis } => 1 + axis,
        ShapeClass::Cube => 4,
    };
    &tables[index]
}
