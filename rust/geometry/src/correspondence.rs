//! Step 6 of the paper: the box pose from unordered corner detections, by searching over which
//! detected peak is which model corner.
//!
//! [`paper_exact_search`] is the paper's method, kept as the reference: take the `m` highest-scoring
//! peaks, fit every ordered injective assignment of them to the 8 corners (8!/(8−m)!, 6720 for
//! m = 5) by least squares, and keep the assignment with the least sum of squared residuals.
//! [`fast_exact_search`] returns the same minimum by branch and bound.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::align::{QuaternionFit, ensure_scatter_spans_a_plane, kabsch, sum_squared_residuals};
use crate::box_model::{BoxModel, CORNER_COUNT};
use crate::error::{GeometryError, Result, ensure_finite, ensure_finite_points, ensure_len};

/// The number of peaks the paper fits.
pub const PAPER_PEAKS_USED: usize = 5;

/// The best assignment of detected peaks to model corners and its pose.
#[derive(Debug, Clone, PartialEq)]
pub struct CorrespondenceFit {
    /// Maps model (box-frame) points into the camera frame: peak ≈ pose · corner.
    pub pose: Isometry3<f64>,
    /// Indices into the input points of the peaks used, highest score first.
    pub peaks: Vec<usize>,
    /// `corners[k]` is the model corner matched to `points[peaks[k]]`.
    pub corners: Vec<usize>,
    /// Σ_k ‖pose · corner(`corners[k]`) − `points[peaks[k]]`‖² over the pairs used, in m².
    pub sum_squared_error: f64,
}

/// The paper's search, by brute force: the `m` highest-scoring points (ties to the lower index)
/// are fitted to every ordered injective assignment of model corners with [`kabsch`], and the
/// assignment with the least sum of squared residuals wins (the first in lexicographic order on
/// ties).
///
/// `scores` gives one score per point; 3 ≤ m ≤ 8 and at least m points are needed, and the chosen
/// points must not be collinear or coincident.
pub fn paper_exact_search(
    model: &BoxModel,
    points: &[Point3<f64>],
    scores: &[f64],
    m: usize,
) -> Result<CorrespondenceFit> {
    let peaks = highest_scoring(points, scores, m)?;
    let targets: Vec<Point3<f64>> = peaks.iter().map(|&i| points[i]).collect();
    let corners = model.corners();

    let mut best: Option<(f64, Isometry3<f64>, Vec<usize>)> = None;
    let mut assignment = Vec::with_capacity(m);
    let mut sources = Vec::with_capacity(m);
    for_each_injective_assignment(m, &mut assignment, &mut |assignment| {
        sources.clear();
        sources.extend(assignment.iter().map(|&c| corners[c]));
        let pose = kabsch(&sources, &targets)?;
        let sse = sum_squared_residuals(&pose, &sources, &targets);
        if best.as_ref().is_none_or(|(best_sse, ..)| sse < *best_sse) {
            best = Some((sse, pose, assignment.to_vec()));
        }
        Ok(())
    })?;
    let (sum_squared_error, pose, corners) =
        best.expect("at least one assignment exists for m ≤ 8");
    Ok(CorrespondenceFit {
        pose,
        peaks,
        corners,
        sum_squared_error,
    })
}

/// Calls `visit` with every ordered injective map from `m` peaks to the 8 corners, in
/// lexicographic order.
fn for_each_injective_assignment(
    m: usize,
    assignment: &mut Vec<usize>,
    visit: &mut impl FnMut(&[usize]) -> Result<()>,
) -> Result<()> {
    if assignment.len() == m {
        return visit(assignment);
    }
    for corner in 0..CORNER_COUNT {
        if !assignment.contains(&corner) {
            assignment.push(corner);
            for_each_injective_assignment(m, assignment, visit)?;
            assignment.pop();
        }
    }
    Ok(())
}

/// The same optimum as [`paper_exact_search`] (same inputs, same minimum sum of squared error),
/// found by an exact branch and bound instead of brute force.
///
/// Peaks are assigned depth-first. Four facts prune the tree without losing the optimum:
/// 1. Assignments related by a symmetry of the box (a corner permutation induced by one of its 4,
///    8 or 24 rotations; side lengths compared exactly) have equal error, so only the
///    lexicographically smallest of each orbit is visited. The group acts freely on injective maps
///    of ≥ 3 peaks, so this divides the work by the group order.
/// 2. The least-squares error of a set of pairs is at least that of any subset (the superset's
///    optimal motion is a candidate motion for the subset), so a partial assignment whose fitted
///    error already reaches the best complete one is cut. Whether it does is decided in O(1),
///    without an SVD: the error is Σ‖a‖² + Σ‖b‖² − 2λ with λ the largest eigenvalue of Horn's
///    quaternion matrix, and the sign pattern of its characteristic quartic and derivatives at
///    the threshold tells whether λ lies below it (Budan–Fourier; the quartic is real-rooted).
/// 3. For two pairs the fitted error is exactly (d − D)²/2, d the peaks' distance and D the
///    corners': a cheap cut before any fit, and the key that orders candidates so that consistent
///    corners are tried first and a tight bound is found early.
/// 4. A peak not yet placed must still find a free corner whose distances to the corners placed
///    agree with its distances to the peaks placed: the least two-pair error it can reach bounds
///    every completion (look-ahead). The peak with the largest such bound is placed next, so that
///    an outlier is placed early and its error cuts the tree.
///
/// The winner is re-fitted with [`kabsch`], so the returned pose and error are computed exactly
/// as the reference computes them.
pub fn fast_exact_search(
    model: &BoxModel,
    points: &[Point3<f64>],
    scores: &[f64],
    m: usize,
) -> Result<CorrespondenceFit> {
    let peaks = highest_scoring(points, scores, m)?;
    let mut targets = [Point3::origin(); CORNER_COUNT];
    for (target, &i) in targets.iter_mut().zip(&peaks) {
        *target = points[i];
    }
    let targets = &targets[..m];
    let mut search = BranchAndBound::new(model, targets);
    // A greedy dive from every first corner finds a good incumbent before the exhaustive pass,
    // which then cuts far more: the two chiral halves of a box's corners cannot be told apart by
    // distances, and without it the wrong half may be searched first with a poor bound.
    for dive in [true, false] {
        search.descend(
            0,
            0,
            search.all_symmetries_active(),
            PartialSums::default(),
            &[[0.0; CORNER_COUNT]; CORNER_COUNT],
            dive,
        );
    }
    let corners = search.best_corners[..m].to_vec();
    let model_corners = model.corners();
    let sources: Vec<_> = corners.iter().map(|&c| model_corners[c]).collect();
    let pose = kabsch(&sources, targets)?;
    let sum_squared_error = sum_squared_residuals(&pose, &sources, targets);
    Ok(CorrespondenceFit {
        pose,
        peaks,
        corners,
        sum_squared_error,
    })
}

/// Running sums over the pairs assigned so far, from which the centred cross-covariance and the
/// minimal rigid error of the prefix follow in O(1).
#[derive(Debug, Clone, Copy, Default)]
struct PartialSums {
    count: f64,
    corner_sum: Vector3<f64>,
    peak_sum: Vector3<f64>,
    /// Σ peak · cornerᵀ.
    cross: Matrix3<f64>,
    corner_norms: f64,
    peak_norms: f64,
}

impl PartialSums {
    fn with_pair(&self, corner: &Vector3<f64>, peak: &Vector3<f64>) -> Self {
        Self {
            count: self.count + 1.0,
            corner_sum: self.corner_sum + corner,
            peak_sum: self.peak_sum + peak,
            cross: self.cross + peak * corner.transpose(),
            corner_norms: self.corner_norms + corner.norm_squared(),
            peak_norms: self.peak_norms + peak.norm_squared(),
        }
    }

    /// The quaternion form of the pairs' least-squares rigid fit.
    fn fit(&self) -> QuaternionFit {
        let corner_mean = self.corner_sum / self.count;
        let peak_mean = self.peak_sum / self.count;
        let cross = self.cross - self.peak_sum * corner_mean.transpose();
        let corner_norms = self.corner_norms - self.count * corner_mean.norm_squared();
        let peak_norms = self.peak_norms - self.count * peak_mean.norm_squared();
        QuaternionFit::new(&cross, corner_norms.max(0.0), peak_norms.max(0.0))
    }
}

struct BranchAndBound {
    m: usize,
    /// Peaks relative to their centroid, which keeps the running sums well conditioned.
    peaks: [Vector3<f64>; CORNER_COUNT],
    corners: [Vector3<f64>; CORNER_COUNT],
    peak_distance: [[f64; CORNER_COUNT]; CORNER_COUNT],
    corner_distance: [[f64; CORNER_COUNT]; CORNER_COUNT],
    /// Corner permutations of the box's non-identity symmetries.
    symmetries: &'static [[usize; CORNER_COUNT]],
    /// Rounding allowance on bounds: a bound must exceed the incumbent by this much to cut.
    margin: f64,
    best_error: f64,
    /// Corner of each peak in the best complete assignment.
    best_corners: [usize; CORNER_COUNT],
    /// The peak placed at each depth, and its corner.
    order: [usize; CORNER_COUNT],
    assignment: [usize; CORNER_COUNT],
    peak_placed: [bool; CORNER_COUNT],
    corner_used: [bool; CORNER_COUNT],
}

impl BranchAndBound {
    fn new(model: &BoxModel, targets: &[Point3<f64>]) -> Self {
        let centroid =
            targets.iter().map(|p| p.coords).sum::<Vector3<f64>>() / targets.len() as f64;
        let mut peaks = [Vector3::zeros(); CORNER_COUNT];
        for (peak, target) in peaks.iter_mut().zip(targets) {
            *peak = target.coords - centroid;
        }
        let model_corners = model.corners();
        let corners = std::array::from_fn(|i| model_corners[i].coords);
        let distances = |points: &[Vector3<f64>; CORNER_COUNT]| {
            std::array::from_fn(|i| std::array::from_fn(|j| (points[i] - points[j]).norm()))
        };
        let scale = peaks.iter().map(|p| p.norm_squared()).sum::<f64>()
            + targets.len() as f64 * model.diameter().powi(2);
        Self {
            m: targets.len(),
            peak_distance: distances(&peaks),
            corner_distance: distances(&corners),
            peaks,
            corners,
            symmetries: &model.symmetry_permutations()[1..],
            margin: 1e-12 * scale,
            best_error: f64::INFINITY,
            best_corners: [0; CORNER_COUNT],
            order: [0; CORNER_COUNT],
            assignment: [0; CORNER_COUNT],
            peak_placed: [false; CORNER_COUNT],
            corner_used: [false; CORNER_COUNT],
        }
    }

    fn all_symmetries_active(&self) -> u32 {
        (1u32 << self.symmetries.len()) - 1
    }

    /// Half the squared difference between the distance of peaks `a`, `b` and that of corners
    /// `c`, `d`: the least-squares error of those two pairs alone, a lower bound on any
    /// assignment that contains them.
    fn pair_error(&self, a: usize, b: usize, c: usize, d: usize) -> f64 {
        let gap = self.peak_distance[a][b] - self.corner_distance[c][d];
        0.5 * gap * gap
    }

    /// Places `peak` at `depth`. `active` holds the symmetries that fix every corner assigned so
    /// far: only they can still map the prefix to a lexicographically smaller one.
    /// `worst_pair[k][c]` is the largest two-pair error of peak `k` on corner `c` against the
    /// pairs placed so far, a lower bound on every completion that puts `k` on `c`.
    ///
    /// The next peak is the one whose best free corner has the largest such bound (the most
    /// constrained, so that an outlier is placed early and its error cuts the tree). Those bounds
    /// depend only on distances, which the box's symmetries preserve exactly, so all assignments
    /// of one orbit follow the same peak order and the lexicographic choice of one per orbit
    /// stays sound.
    ///
    /// With `dive`, only one path is followed below each first corner: a quick greedy search for
    /// an incumbent.
    fn descend(
        &mut self,
        depth: usize,
        peak: usize,
        active: u32,
        sums: PartialSums,
        worst_pair: &[[f64; CORNER_COUNT]; CORNER_COUNT],
        dive: bool,
    ) {
        let mut candidates: [(f64, usize, u32); CORNER_COUNT] = [(0.0, 0, 0); CORNER_COUNT];
        let mut candidate_count = 0;
        'corners: for corner in 0..CORNER_COUNT {
            if self.corner_used[corner] || worst_pair[peak][corner] >= self.best_error + self.margin
            {
                continue;
            }
            let mut still_fixing = 0u32;
            for (g, permutation) in self.symmetries.iter().enumerate() {
                if active & (1 << g) == 0 {
                    continue;
                }
                match permutation[corner].cmp(&corner) {
                    std::cmp::Ordering::Less => continue 'corners,
                    std::cmp::Ordering::Equal => still_fixing |= 1 << g,
                    std::cmp::Ordering::Greater => {}
                }
            }
            candidates[candidate_count] = (worst_pair[peak][corner], corner, still_fixing);
            candidate_count += 1;
        }
        let candidates = &mut candidates[..candidate_count];
        candidates.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        // Below the first peak a dive follows only the most consistent candidate.
        let candidates = if dive && depth > 0 {
            &candidates[..candidates.len().min(1)]
        } else {
            candidates
        };

        self.order[depth] = peak;
        self.peak_placed[peak] = true;
        for &(_, corner, still_fixing) in candidates.iter() {
            let cut = self.best_error + self.margin;
            self.corner_used[corner] = true;
            // Tighten the two-pair bounds of the unplaced peaks with the new pair, and pick the
            // most constrained of them.
            let mut tightened = *worst_pair;
            let mut next = None;
            let mut next_bound = -1.0;
            for later in (0..self.m).filter(|&k| !self.peak_placed[k]) {
                let mut bound = f64::INFINITY;
                for c in (0..CORNER_COUNT).filter(|&c| !self.corner_used[c]) {
                    let error = tightened[later][c].max(self.pair_error(peak, later, corner, c));
                    tightened[later][c] = error;
                    bound = bound.min(error);
                }
                if bound > next_bound {
                    (next, next_bound) = (Some(later), bound);
                }
            }
            let sums = sums.with_pair(&self.corners[corner], &self.peaks[peak]);
            let promising = next_bound < cut && (depth < 2 || !sums.fit().error_reaches(cut));
            if promising {
                self.assignment[depth] = corner;
                match next {
                    Some(next) => {
                        self.descend(depth + 1, next, still_fixing, sums, &tightened, dive)
                    }
                    None => {
                        let error = sums.fit().min_error();
                        if error < self.best_error {
                            self.best_error = error;
                            for i in 0..self.m {
                                self.best_corners[self.order[i]] = self.assignment[i];
                            }
                        }
                    }
                }
            }
            self.corner_used[corner] = false;
        }
        self.peak_placed[peak] = false;
    }
}

/// Indices of the `m` highest-scoring points, highest first (ties to the lower index), after
/// checking the inputs.
fn highest_scoring(points: &[Point3<f64>], scores: &[f64], m: usize) -> Result<Vec<usize>> {
    ensure_len("scores (one per point)", points.len(), scores.len())?;
    ensure_finite_points("points", points)?;
    ensure_finite("scores", scores)?;
    if !(3..=CORNER_COUNT).contains(&m) {
        return Err(GeometryError::InvalidParameter {
            name: "m",
            reason: "the number of peaks fitted must be between 3 and 8",
        });
    }
    if points.len() < m {
        return Err(GeometryError::TooFewPoints {
            what: "correspondence search",
            needed: m,
            got: points.len(),
        });
    }
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    order.truncate(m);
    let chosen: Vec<_> = order.iter().map(|&i| points[i]).collect();
    ensure_spread_in_two_directions(&chosen)?;
    Ok(order)
}

/// Fails unless the points span at least a plane, without which no rotation is determined.
pub(crate) fn ensure_spread_in_two_directions(points: &[Point3<f64>]) -> Result<()> {
    let centroid = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
    let scatter: Matrix3<f64> = points
        .iter()
        .map(|p| (p.coords - centroid) * (p.coords - centroid).transpose())
        .sum();
    ensure_scatter_spans_a_plane(&scatter)
}
