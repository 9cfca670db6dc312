//! What the noise-adaptive fits share: the cost that chooses among hypotheses without a threshold
//! in box units, and the confidence every fit reports.
//!
//! **The cost.** Under a hypothesis (a box placed in the camera frame) each peak has a residual,
//! its distance to the nearest placed corner. The peaks are modelled as a mixture: inliers are
//! the placed corners plus isotropic Gaussian noise of unknown scale σ (per coordinate), outliers
//! are uniform over the volume V of the ball around the peaks' centroid that holds them all. For
//! each inlier count m (from 4, or all peaks if fewer) the m smallest residuals are the inliers,
//! σ² is their sum of squares over the residual degrees of freedom 3m − p (p = 6 parameters for a
//! box of known size, 9 with its sides), and the cost is the negative restricted log-likelihood
//!
//! NLL(m) = ((3m − p)/2)·ln(2πσ²) + S_m / (2σ²) + (n − m)·ln V,
//!
//! minimised over m (a profile likelihood over the inlier count and the scale). Only the 3m − p
//! residual dimensions have a Gaussian density: the other p are absorbed by the fitted parameters,
//! so that a box fitted through barely more points than it has parameters (4 peaks for 9 of a box
//! of unknown size) does not win by fitting them exactly. The effective
//! inlier threshold is where the Gaussian density falls to the uniform one, about 5σ for
//! millimetre noise: it follows the peaks' noise, not the box size. Four peaks within a
//! centimetre beat five loose ones, because σ enters as ln σ per coordinate per inlier.
//! σ is floored at 1e-6 of the peaks' spread so that exact data keep a finite cost.
//!
//! **The confidence.** The cost is a negative log-likelihood, so the difference between the
//! chosen box's cost and the best cost of a *different* box is a log-likelihood ratio in nats:
//! the margin. "Different" is the failure criterion of the fit's own benchmark, a [`Separation`]
//! of a tenth of the diameter: for a box of known size, its MSSD from the chosen pose (modulo the
//! box's exact symmetries, so a box whose sides differ by a few per cent turned 90° is different
//! though its corners nearly coincide); for the size fit, whose failure criterion is blind to axis
//! labels, the distance between the corner sets.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

use crate::box_model::{CORNER_COUNT, corner_signs};

/// How far to trust a fit, returned with every noise-adaptive fit and computed for the others by
/// [`crate::pipeline::fit_and_score`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitConfidence {
    /// margin / (margin + 10), clamped to [0, 1): 0 when a different pose explains the peaks at
    /// least as well, ½ at a likelihood ratio of e¹⁰, approaching 1 as the margin grows. A
    /// monotone map of the margin, so that it ranks fits the same way.
    pub confidence: f64,
    /// Likelihood cost of the best different box minus that of this one (nats; infinite when no
    /// other hypothesis exists), without the visibility prior: a mirror tie that the prior
    /// settled keeps a margin near 0. Negative when the search found a different pose that
    /// explains the peaks better.
    pub margin_nats: f64,
    /// Peaks the cost counts as inliers (the m of the minimum).
    pub inliers: usize,
    /// The estimated per-coordinate noise of the inlier peaks (metres).
    pub noise_scale_m: f64,
    /// The inliers lie in one plane (within 3σ) and less than 2 nats of likelihood separate this
    /// pose from the next: the box and its mirror image through that plane fit them alike, and
    /// only the visibility prior chose.
    pub mirror_ambiguous: bool,
}

impl FitConfidence {
    pub(crate) fn from_margin(
        margin_nats: f64,
        inliers: usize,
        noise_scale_m: f64,
        mirror_ambiguous: bool,
    ) -> Self {
        let confidence = if margin_nats.is_nan() || margin_nats <= 0.0 {
            0.0
        } else if margin_nats.is_infinite() {
            1.0
        } else {
            margin_nats / (margin_nats + 10.0)
        };
        Self {
            confidence,
            margin_nats,
            inliers,
            noise_scale_m,
            mirror_ambiguous,
        }
    }
}

/// Below this margin (nats) a coplanar inlier set is reported as mirror-ambiguous.
pub(crate) const MIRROR_MARGIN_NATS: f64 = 2.0;

/// Cost added per inlier peak matched to a corner that the box itself hides from the camera (at
/// the origin): the prior that settles a mirror tie, where likelihood cannot. Small beside the
/// likelihood margins of determined fits (tens of nats).
pub(crate) const HIDDEN_INLIER_NATS: f64 = 1.0;

/// The data-dependent constants of the cost.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CostModel {
    /// ln V of the outlier ball.
    pub log_volume: f64,
    /// Floor of σ².
    pub sigma_floor_sq: f64,
    /// Parameters fitted (6 or 9).
    pub parameters: usize,
    /// The smallest inlier count considered.
    pub min_inliers: usize,
}

impl CostModel {
    pub fn new(points: &[Point3<f64>], parameters: usize) -> Self {
        let n = points.len() as f64;
        let centroid = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
        let radius = points
            .iter()
            .map(|p| (p.coords - centroid).norm())
            .fold(0.0, f64::max)
            .max(1e-9);
        Self {
            log_volume: (4.0 / 3.0 * std::f64::consts::PI * radius.powi(3)).ln(),
            sigma_floor_sq: (1e-6 * radius).powi(2),
            parameters,
            min_inliers: points.len().min(4),
        }
    }

    /// The profile cost of sorted squared residuals: (cost, inlier count m, σ).
    pub fn profile(&self, sorted_sq: &[f64]) -> Profile {
        let n = sorted_sq.len();
        let mut best = Profile {
            cost: f64::INFINITY,
            inliers: n,
            sigma: f64::INFINITY,
        };
        let mut sum = 0.0;
        for (index, &s) in sorted_sq.iter().enumerate() {
            sum += s;
            let m = index + 1;
            if m < self.min_inliers {
                continue;
            }
            let dof = (3 * m).saturating_sub(self.parameters).max(1) as f64;
            let variance = (sum / dof).max(self.sigma_floor_sq);
            let cost = 0.5 * (3 * m) as f64 - 0.25 * self.parameters as f64;
            let cost = cost * (std::f64::consts::TAU * variance).ln()
                + sum / (2.0 * variance)
                + (n - m) as f64 * self.log_volume;
            if cost < best.cost {
                best = Profile {
                    cost,
                    inliers: m,
                    sigma: variance.sqrt(),
                };
            }
        }
        best
    }
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct Profile {
    pub cost: f64,
    pub inliers: usize,
    pub sigma: f64,
}

/// A box placed in the camera frame: rotation (columns are the box axes), centre, half sides.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Placed {
    pub rotation: Rotation3<f64>,
    pub centre: Vector3<f64>,
    pub half: Vector3<f64>,
}

impl Placed {
    pub fn corners(&self) -> [Vector3<f64>; CORNER_COUNT] {
        std::array::from_fn(|c| {
            self.rotation * corner_signs(c).component_mul(&self.half) + self.centre
        })
    }

    /// Per point: (nearest corner, squared distance).
    pub fn nearest(&self, points: &[Point3<f64>]) -> Vec<(usize, f64)> {
        let to_box = self.rotation.inverse();
        points
            .iter()
            .map(|p| self.nearest_corner(&to_box, p))
            .collect()
    }

    /// The corner nearest to `p` and its squared distance, in the box's frame (`to_box` is the
    /// inverse rotation): the distance to a corner (±h₀, ±h₁, ±h₂) separates by axis, so the
    /// nearest corner takes the sign of each coordinate, and the squared distance is
    /// Σ (|qᵢ| − hᵢ)². A tenth of the work of comparing all 8 corners, in the fits' inner loop.
    fn nearest_corner(&self, to_box: &Rotation3<f64>, p: &Point3<f64>) -> (usize, f64) {
        let q = to_box * (p.coords - self.centre);
        let mut corner = 0;
        let mut squared = 0.0;
        for axis in 0..3 {
            if q[axis] > 0.0 {
                corner |= 1 << axis;
            }
            squared += (q[axis].abs() - self.half[axis]).powi(2);
        }
        (corner, squared)
    }

    /// The profile cost of this box on `points`, using `scratch` for the sorted residuals.
    pub fn cost(
        &self,
        points: &[Point3<f64>],
        model: &CostModel,
        scratch: &mut Vec<f64>,
    ) -> Profile {
        let to_box = self.rotation.inverse();
        scratch.clear();
        scratch.extend(points.iter().map(|p| self.nearest_corner(&to_box, p).1));
        sort_small(scratch);
        model.profile(scratch)
    }

    /// Whether corner `c` is seen by a camera at the origin: a vertex of a convex body is visible
    /// when one of the faces through it faces the camera.
    pub fn corner_visible(&self, c: usize) -> bool {
        let signs = corner_signs(c);
        let position = self.rotation * signs.component_mul(&self.half) + self.centre;
        (0..3).any(|axis| {
            let normal = self.rotation * Vector3::ith(axis, signs[axis]);
            normal.dot(&position) < 0.0
        })
    }

    /// MSSD between two placements of one box: min over the corner permutations π of its symmetry
    /// group of max_i ‖cᵢ − c'_π(i)‖ ([`crate::metrics::mssd`], which this equals for the same
    /// sides).
    pub fn mssd_to(&self, other: &Placed, permutations: &[[usize; CORNER_COUNT]]) -> f64 {
        let (a, b) = (self.corners(), other.corners());
        permutations
            .iter()
            .map(|pi| {
                (0..CORNER_COUNT)
                    .map(|i| (a[i] - b[pi[i]]).norm_squared())
                    .fold(0.0, f64::max)
            })
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    }

    /// Largest distance from a corner of either box to the nearest corner of the other (the
    /// Hausdorff distance of the corner sets): blind to symmetries and to axis labels.
    pub fn corner_distance(&self, other: &Placed) -> f64 {
        let (a, b) = (self.corners(), other.corners());
        let one_way = |a: &[Vector3<f64>; CORNER_COUNT], b: &[Vector3<f64>; CORNER_COUNT]| {
            a.iter().map(|x| nearest_of(b, x).1).fold(0.0, f64::max)
        };
        one_way(&a, &b).max(one_way(&b, &a)).sqrt()
    }

    pub fn diameter(&self) -> f64 {
        2.0 * self.half.norm()
    }
}

fn nearest_of(corners: &[Vector3<f64>; CORNER_COUNT], p: &Vector3<f64>) -> (usize, f64) {
    let mut best = (0, (corners[0] - p).norm_squared());
    for (c, corner) in corners.iter().enumerate().skip(1) {
        let d = (corner - p).norm_squared();
        if d < best.1 {
            best = (c, d);
        }
    }
    best
}

/// Insertion sort: the residual lists are short (8 peaks).
pub(crate) fn sort_small(values: &mut [f64]) {
    for i in 1..values.len() {
        let mut j = i;
        while j > 0 && values[j - 1] > values[j] {
            values.swap(j - 1, j);
            j -= 1;
        }
    }
}

/// The indices of the `m` smallest squared residuals (ties to the lower index).
pub(crate) fn smallest(nearest: &[(usize, f64)], m: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..nearest.len()).collect();
    order.sort_by(|&a, &b| nearest[a].1.total_cmp(&nearest[b].1).then(a.cmp(&b)));
    order.truncate(m);
    order.sort_unstable();
    order
}

/// The points' centroid and scatter matrix Σ (p − c)(p − c)ᵀ: the eigenvector of its smallest
/// eigenvalue is the normal of their best plane.
pub(crate) fn scatter(points: &[Point3<f64>]) -> (Vector3<f64>, Matrix3<f64>) {
    let n = points.len().max(1) as f64;
    let centroid = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let scatter = points
        .iter()
        .map(|p| (p.coords - centroid) * (p.coords - centroid).transpose())
        .sum();
    (centroid, scatter)
}

/// Whether the points lie in one plane within `tolerance` (RMS distance from their best plane).
pub(crate) fn coplanar(points: &[Point3<f64>], tolerance: f64) -> bool {
    if points.len() < 4 {
        return true;
    }
    let smallest = scatter(points).1.symmetric_eigenvalues().min().max(0.0);
    (smallest / points.len() as f64).sqrt() <= tolerance
}

/// A refined hypothesis with its cost and what the confidence needs.
#[derive(Debug, Clone)]
pub(crate) struct Refined {
    pub placed: Placed,
    /// Likelihood cost plus the visibility prior.
    pub cost: f64,
    pub profile: Profile,
    pub nearest: Vec<(usize, f64)>,
}

impl Refined {
    pub fn new(placed: Placed, points: &[Point3<f64>], model: &CostModel) -> Self {
        let nearest = placed.nearest(points);
        let mut sq: Vec<f64> = nearest.iter().map(|n| n.1).collect();
        sort_small(&mut sq);
        let profile = model.profile(&sq);
        let inliers = smallest(&nearest, profile.inliers);
        let hidden = inliers
            .iter()
            .filter(|&&i| !placed.corner_visible(nearest[i].0))
            .count();
        Self {
            placed,
            cost: profile.cost + HIDDEN_INLIER_NATS * hidden as f64,
            profile,
            nearest,
        }
    }

    pub fn inlier_indices(&self) -> Vec<usize> {
        smallest(&self.nearest, self.profile.inliers)
    }
}

/// When two placed boxes count as different poses: farther apart than `threshold` (a tenth of the
/// diameter, the benchmarks' failure criterion) by the fit's failure metric.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Separation {
    /// MSSD under the given symmetry group's corner permutations (box of known size).
    Mssd {
        threshold: f64,
        permutations: &'static [[usize; CORNER_COUNT]],
    },
    /// Distance between the corner sets (box of unknown size, whose failure criterion matches
    /// corners under the best axis labelling).
    Corners { threshold: f64 },
}

impl Separation {
    pub fn differ(&self, a: &Placed, b: &Placed) -> bool {
        match *self {
            // MSSD is a largest corner distance, at least the distance of the corners' means
            // (the centres), which settles most pairs without the corners
            Self::Mssd {
                threshold,
                permutations,
            } => (a.centre - b.centre).norm() > threshold || a.mssd_to(b, permutations) > threshold,
            Self::Corners { threshold } => a.corner_distance(b) > threshold,
        }
    }

    /// The best cost among `candidates` that differ from `chosen` (infinite when none does).
    pub fn runner_up_cost<'a>(
        &self,
        chosen: &Placed,
        candidates: impl IntoIterator<Item = &'a Refined>,
    ) -> f64 {
        candidates
            .into_iter()
            .filter(|r| self.differ(&r.placed, chosen))
            .map(|r| r.profile.cost)
            .fold(f64::INFINITY, f64::min)
    }
}

/// Sorts hypotheses by cost, ties in their order of generation (as a stable sort would), moving
/// only (cost, index) keys: a hypothesis is 16 floats, and a fit sorts hundreds.
pub(crate) fn sort_by_cost(hypotheses: Vec<(f64, Placed)>) -> Vec<(f64, Placed)> {
    let mut keys: Vec<(f64, u32)> = hypotheses
        .iter()
        .enumerate()
        .map(|(i, h)| (h.0, i as u32))
        .collect();
    keys.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    keys.iter().map(|&(_, i)| hypotheses[i as usize]).collect()
}

/// From hypotheses sorted by cost, up to `limit` that differ pairwise, best first.
pub(crate) fn distinct(
    sorted: &[(f64, Placed)],
    separation: Separation,
    limit: usize,
) -> Vec<Placed> {
    let mut chosen: Vec<Placed> = Vec::new();
    for (_, candidate) in sorted {
        if chosen.len() >= limit {
            break;
        }
        if chosen.iter().all(|c| separation.differ(c, candidate)) {
            chosen.push(*candidate);
        }
    }
    chosen
}

/// The best refined box, and the confidence from the best of the others that differ from it.
pub(crate) fn choose(
    mut refined: Vec<Refined>,
    points: &[Point3<f64>],
    separation: Separation,
) -> Option<(Refined, FitConfidence)> {
    refined.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let best = refined.first()?.clone();
    let runner_up = separation.runner_up_cost(&best.placed, &refined[1..]);
    let confidence = confidence_of(&best, runner_up - best.profile.cost, points);
    Some((best, confidence))
}

pub(crate) fn confidence_of(fit: &Refined, margin: f64, points: &[Point3<f64>]) -> FitConfidence {
    let inliers: Vec<Point3<f64>> = fit.inlier_indices().iter().map(|&i| points[i]).collect();
    let flat = coplanar(&inliers, 3.0 * fit.profile.sigma);
    FitConfidence::from_margin(
        margin,
        fit.profile.inliers,
        fit.profile.sigma,
        flat && margin < MIRROR_MARGIN_NATS,
    )
}
