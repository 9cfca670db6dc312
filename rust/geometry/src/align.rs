//! Least-squares alignment of corresponding point sets: Kabsch (rigid) and Umeyama (similarity),
//! optionally weighted. The rotation is always proper (det = +1): when the best orthogonal matrix
//! is a reflection, the smallest singular direction is flipped (Umeyama 1991).

use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3,
};

use crate::error::{GeometryError, Result, ensure_finite, ensure_finite_points, ensure_len};

/// The rigid transform `T` minimising Σ ‖T·source_i − target_i‖² (Arun 1987 / Kabsch 1976).
///
/// Needs at least 3 pairs, and neither set may be collinear or coincident, since then the rotation
/// about their common line is undetermined.
pub fn kabsch(source: &[Point3<f64>], target: &[Point3<f64>]) -> Result<Isometry3<f64>> {
    let fit = weighted_fit(source, target, None)?;
    Ok(fit.isometry())
}

/// The rigid transform `T` minimising Σ w_i ‖T·source_i − target_i‖²; weights must be finite and
/// non-negative, and at least 3 must be positive.
pub fn kabsch_weighted(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: &[f64],
) -> Result<Isometry3<f64>> {
    let fit = weighted_fit(source, target, Some(weights))?;
    Ok(fit.isometry())
}

/// The similarity `T` (rotation, translation, positive uniform scale) minimising
/// Σ ‖T·source_i − target_i‖² (Umeyama 1991).
pub fn umeyama(source: &[Point3<f64>], target: &[Point3<f64>]) -> Result<Similarity3<f64>> {
    let fit = weighted_fit(source, target, None)?;
    Ok(fit.similarity())
}

/// The similarity minimising Σ w_i ‖T·source_i − target_i‖²; weights as in [`kabsch_weighted`].
pub fn umeyama_weighted(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: &[f64],
) -> Result<Similarity3<f64>> {
    let fit = weighted_fit(source, target, Some(weights))?;
    Ok(fit.similarity())
}

/// The rigid fit of [`kabsch`] by Horn's quaternion method instead of an SVD (several times
/// faster), for hot loops; falls back to [`kabsch`] when the quaternion is not determined.
pub(crate) fn quaternion_kabsch(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
) -> Result<Isometry3<f64>> {
    let n = source.len() as f64;
    let source_mean = source.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let target_mean = target.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let (mut cross, mut source_norms, mut target_norms) = (Matrix3::zeros(), 0.0, 0.0);
    for (s, t) in source.iter().zip(target) {
        let (s, t) = (s.coords - source_mean, t.coords - target_mean);
        cross += t * s.transpose();
        source_norms += s.norm_squared();
        target_norms += t.norm_squared();
    }
    match QuaternionFit::new(&cross, source_norms, target_norms).rotation() {
        Some(rotation) => Ok(Isometry3::from_parts(
            Translation3::from(target_mean - rotation * source_mean),
            rotation,
        )),
        None => kabsch(source, target),
    }
}

/// Σ ‖T·source_i − target_i‖² for a rigid transform.
pub fn sum_squared_residuals(
    transform: &Isometry3<f64>,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
) -> f64 {
    source
        .iter()
        .zip(target)
        .map(|(s, t)| (transform * s - t).norm_squared())
        .sum()
}

/// The parts of a weighted fit that both Kabsch and Umeyama are built from.
struct WeightedFit {
    rotation: Matrix3<f64>,
    source_mean: Vector3<f64>,
    target_mean: Vector3<f64>,
    /// Weighted mean of ‖source_i − source_mean‖².
    source_variance: f64,
    /// tr(D·S) of Umeyama's paper: Σ σ_k with the last one negated when a reflection was avoided.
    signed_singular_sum: f64,
}

impl WeightedFit {
    fn isometry(&self) -> Isometry3<f64> {
        let rotation = rotation_from_matrix(&self.rotation);
        let translation = self.target_mean - rotation * self.source_mean;
        Isometry3::from_parts(Translation3::from(translation), rotation)
    }

    fn similarity(&self) -> Similarity3<f64> {
        let rotation = rotation_from_matrix(&self.rotation);
        let scale = self.signed_singular_sum / self.source_variance;
        let translation = self.target_mean - rotation * self.source_mean * scale;
        Similarity3::from_parts(Translation3::from(translation), rotation, scale)
    }
}

fn rotation_from_matrix(matrix: &Matrix3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(*matrix))
}

fn weighted_fit(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: Option<&[f64]>,
) -> Result<WeightedFit> {
    ensure_len(
        "target points (one per source point)",
        source.len(),
        target.len(),
    )?;
    ensure_finite_points("source points", source)?;
    ensure_finite_points("target points", target)?;
    let uniform;
    let weights = match weights {
        Some(w) => {
            ensure_len("weights (one per point)", source.len(), w.len())?;
            ensure_finite("weights", w)?;
            if w.iter().any(|&x| x < 0.0) {
                return Err(GeometryError::InvalidParameter {
                    name: "weights",
                    reason: "weights must be non-negative",
                });
            }
            w
        }
        None => {
            uniform = vec![1.0; source.len()];
            &uniform
        }
    };
    let positive = weights.iter().filter(|&&w| w > 0.0).count();
    if positive < 3 {
        return Err(GeometryError::TooFewPoints {
            what: "rigid alignment",
            needed: 3,
            got: positive,
        });
    }

    let total: f64 = weights.iter().sum();
    let weighted_mean = |points: &[Point3<f64>]| {
        points
            .iter()
            .zip(weights)
            .map(|(p, &w)| p.coords * w)
            .sum::<Vector3<f64>>()
            / total
    };
    let source_mean = weighted_mean(source);
    let target_mean = weighted_mean(target);
    let mut covariance = Matrix3::zeros();
    let mut source_scatter = Matrix3::zeros();
    let mut target_scatter = Matrix3::zeros();
    for ((s, t), &w) in source.iter().zip(target).zip(weights) {
        let s = s.coords - source_mean;
        let t = t.coords - target_mean;
        covariance += t * s.transpose() * (w / total);
        source_scatter += s * s.transpose() * (w / total);
        target_scatter += t * t.transpose() * (w / total);
    }
    // Each set must span a plane for the rotation to be determined. (The covariance itself may
    // still be rank-deficient, for example for a rectangle matched to a rotated copy of itself
    // with its corners permuted; the optimal rotation is then not unique but the SVD gives one
    // that attains the minimum.)
    ensure_scatter_spans_a_plane(&source_scatter)?;
    ensure_scatter_spans_a_plane(&target_scatter)?;
    let source_variance = source_scatter.trace();

    // Horn's quaternion method, exact where the rotation is determined. An SVD is not: nalgebra's
    // (both its special 3×3 path and the general one) stops with U·Σ·Vᵀ 4e-4 away from the matrix
    // when two singular values nearly coincide — the corners of a square-faced box — and fitted a
    // half turn of a 0.15 × 0.25 × 0.25 m box 0.4 mrad wrong at 10 µm of noise.
    let rotation =
        match QuaternionFit::new(&covariance, source_variance, target_scatter.trace()).rotation() {
            Some(rotation) => rotation.to_rotation_matrix().into_inner(),
            None => svd_rotation(&covariance),
        };
    // tr(Rᵀ·C) = Σ σ_k, the last negated when a reflection was avoided (Umeyama's tr(D·S)).
    let signed_singular_sum = (rotation.transpose() * covariance).trace();
    Ok(WeightedFit {
        rotation,
        source_mean,
        target_mean,
        source_variance,
        signed_singular_sum,
    })
}

/// The rotation nearest to `m` in the Frobenius norm (the maximiser of tr(Rᵀm), Horn's
/// quaternion method); `None` when it is not unique, as for a matrix of rank ≤ 1.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    // λ = σ₁ + σ₂ + σ₃ ≤ √3‖m‖_F, so norms of √3‖m‖_F keep QuaternionFit's bound on λ valid.
    let bound = 3f64.sqrt() * m.norm();
    QuaternionFit::new(m, bound, bound)
        .rotation()
        .map(|q| q.to_rotation_matrix())
}

/// The proper rotation maximising tr(Rᵀ·C) from an SVD, for a covariance whose optimal rotation
/// is not unique (rank ≤ 1, or a rectangle matched to a rotated copy of itself): any optimum will
/// do there, and the SVD gives one. When U·Vᵀ is a reflection, the smallest singular direction is
/// flipped (Umeyama 1991).
fn svd_rotation(covariance: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = covariance.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested U"), svd.v_t.expect("requested V^T"));
    let mut signs = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        let smallest = svd.singular_values.imin();
        signs[(smallest, smallest)] = -1.0;
    }
    u * signs * v_t
}

/// Fails unless points with this (centred) scatter matrix span at least a plane.
pub(crate) fn ensure_scatter_spans_a_plane(scatter: &Matrix3<f64>) -> Result<()> {
    let trace = scatter.trace();
    if trace <= 0.0 {
        return Err(GeometryError::Degenerate("coincident points"));
    }
    // The sum of the principal 2×2 minors is λ₁λ₂ + λ₁λ₃ + λ₂λ₃, about λ₁λ₂ when the points are
    // nearly collinear: against trace² ≈ λ₁², a ratio of 1e-20 is a width of 1e-10 of the extent.
    // (Cheaper than an eigen-decomposition, and on the searches' hot paths.)
    let minor =
        |i: usize, j: usize| scatter[(i, i)] * scatter[(j, j)] - scatter[(i, j)] * scatter[(j, i)];
    if minor(0, 1) + minor(0, 2) + minor(1, 2) <= 1e-20 * trace * trace {
        return Err(GeometryError::Degenerate("collinear points"));
    }
    Ok(())
}

/// Horn's quaternion form of the rigid fit of centred point sets a_i → b_i, from their cross term
/// `cross = Σ b_i a_iᵀ` and squared norms Σ‖a_i‖², Σ‖b_i‖²: the least Σ ‖R·a_i − b_i‖² over
/// rotations is Σ‖a‖² + Σ‖b‖² − 2λ, with λ the largest eigenvalue of a traceless symmetric 4×4
/// matrix, i.e. the largest root of its characteristic quartic λ⁴ + c₂λ² + c₁λ + c₀ (Theobald's
/// QCP, 2005). No SVD and no rotation are formed.
pub(crate) struct QuaternionFit {
    total: f64,
    c2: f64,
    c1: f64,
    c0: f64,
    /// Horn's matrix, whose eigenvector for λ is the optimal rotation as a quaternion.
    horn: [[f64; 4]; 4],
    /// An upper bound on λ: the least of (Σ‖a‖² + Σ‖b‖²)/2, √(Σ‖a‖²·Σ‖b‖²) and √3·‖cross‖_F, all
    /// bounds on λ = σ₁ + σ₂ ± σ₃ (σ the singular values of `cross`).
    lambda_bound: f64,
}

impl QuaternionFit {
    pub(crate) fn new(cross: &Matrix3<f64>, source_norms: f64, target_norms: f64) -> Self {
        // Horn's matrix is written for S = Σ a bᵀ, the transpose of `cross`.
        let s = |row: usize, col: usize| cross[(col, row)];
        let (sxx, sxy, sxz) = (s(0, 0), s(0, 1), s(0, 2));
        let (syx, syy, syz) = (s(1, 0), s(1, 1), s(1, 2));
        let (szx, szy, szz) = (s(2, 0), s(2, 1), s(2, 2));
        let n = [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ];
        let frobenius_squared = cross.norm_squared();
        let total = source_norms + target_norms;
        Self {
            total,
            c2: -2.0 * frobenius_squared,
            c1: -8.0 * cross.determinant(),
            c0: determinant4(&n),
            horn: n,
            lambda_bound: (0.5 * total)
                .min((source_norms * target_norms).sqrt())
                .min((3.0 * frobenius_squared).sqrt()),
        }
    }

    /// Whether the least squared error is at least `enough`, decided without finding λ: that is
    /// λ ≤ x = (Σ‖a‖² + Σ‖b‖² − enough)/2, and since the quartic has only real roots, Budan–Fourier
    /// says it has none above x > 0 exactly when it and its derivatives are all positive there
    /// (the third, 24x, and fourth, 24, are). Each must be positive by more than its rounding
    /// error, so that a "yes" is never an artefact of rounding.
    pub(crate) fn error_reaches(&self, enough: f64) -> bool {
        let x = 0.5 * (self.total - enough);
        if self.lambda_bound <= x {
            return true;
        }
        if x <= 0.0 {
            return false;
        }
        let (x2, c2, c1, c0) = (x * x, self.c2, self.c1, self.c0);
        let clearly_positive = |value: f64, magnitude: f64| value > 1e-13 * magnitude;
        clearly_positive(12.0 * x2 + 2.0 * c2, 12.0 * x2 + 2.0 * c2.abs())
            && clearly_positive(
                4.0 * x2 * x + 2.0 * c2 * x + c1,
                4.0 * x2 * x + 2.0 * c2.abs() * x + c1.abs(),
            )
            && clearly_positive(
                (x2 + c2) * x2 + c1 * x + c0,
                x2 * x2 + c2.abs() * x2 + c1.abs() * x + c0.abs(),
            )
    }

    /// The least squared error, by Newton's method on the quartic from `lambda_bound`: from the
    /// right of the largest root of a real-rooted polynomial it decreases monotonically onto it.
    pub(crate) fn min_error(&self) -> f64 {
        (self.total - 2.0 * self.largest_eigenvalue()).max(0.0)
    }

    /// The optimal rotation: the eigenvector of Horn's matrix for λ, read off the adjugate of
    /// (N − λI), every non-zero column of which is proportional to it when λ is a simple
    /// eigenvalue. `None` when λ is (nearly) double and the rotation is not determined this way.
    pub(crate) fn rotation(&self) -> Option<UnitQuaternion<f64>> {
        let lambda = self.largest_eigenvalue();
        let mut shifted = self.horn;
        for (i, row) in shifted.iter_mut().enumerate() {
            row[i] -= lambda;
        }
        const OTHERS: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
        let minor = |skip_row: usize, skip_col: usize| {
            let (rows, cols) = (OTHERS[skip_row], OTHERS[skip_col]);
            Matrix3::from_fn(|r, c| shifted[rows[r]][cols[c]]).determinant()
        };
        let column = |j: usize| {
            nalgebra::Vector4::from_fn(|i, _| {
                if (i + j) & 1 == 0 {
                    minor(j, i)
                } else {
                    -minor(j, i)
                }
            })
        };
        let best = (0..4)
            .map(column)
            .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))?;
        // Cofactors are cubic in the matrix entries, whose size λ bounds.
        if best.norm() <= 1e-9 * lambda.abs().powi(3) {
            return None;
        }
        let q = nalgebra::Quaternion::new(best[0], best[1], best[2], best[3]);
        Some(UnitQuaternion::from_quaternion(q))
    }

    fn largest_eigenvalue(&self) -> f64 {
        let mut lambda = self.lambda_bound;
        for _ in 0..100 {
            let l2 = lambda * lambda;
            let value = (l2 + self.c2) * l2 + self.c1 * lambda + self.c0;
            let slope = 4.0 * l2 * lambda + 2.0 * self.c2 * lambda + self.c1;
            if slope <= 0.0 {
                break;
            }
            let step = value / slope;
            if step.is_nan() || step <= 1e-15 * lambda.abs() {
                break;
            }
            lambda -= step;
        }
        lambda
    }
}

fn determinant4(a: &[[f64; 4]; 4]) -> f64 {
    let s0 = a[0][0] * a[1][1] - a[1][0] * a[0][1];
    let s1 = a[0][0] * a[1][2] - a[1][0] * a[0][2];
    let s2 = a[0][0] * a[1][3] - a[1][0] * a[0][3];
    let s3 = a[0][1] * a[1][2] - a[1][1] * a[0][2];
    let s4 = a[0][1] * a[1][3] - a[1][1] * a[0][3];
    let s5 = a[0][2] * a[1][3] - a[1][2] * a[0][3];
    let c5 = a[2][2] * a[3][3] - a[3][2] * a[2][3];
    let c4 = a[2][1] * a[3][3] - a[3][1] * a[2][3];
    let c3 = a[2][1] * a[3][2] - a[3][1] * a[2][2];
    let c2 = a[2][0] * a[3][3] - a[3][0] * a[2][3];
    let c1 = a[2][0] * a[3][2] - a[3][0] * a[2][2];
    let c0 = a[2][0] * a[3][1] - a[3][0] * a[2][1];
    s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    fn cloud() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.1, -0.2, 0.3),
            Point3::new(-0.4, 0.5, 0.1),
            Point3::new(0.7, 0.2, -0.3),
            Point3::new(0.0, -0.6, -0.5),
            Point3::new(0.3, 0.3, 0.9),
        ]
    }

    fn pose() -> Isometry3<f64> {
        let axis = Unit::new_normalize(Vector3::new(0.3, -1.0, 0.5));
        Isometry3::from_parts(
            Translation3::new(0.2, -0.1, 1.5),
            UnitQuaternion::from_axis_angle(&axis, 2.3),
        )
    }

    /// The case proptest found: nearly equal singular values (a square-faced box's corners) and a
    /// half turn, where nalgebra's special 3×3 SVD fitted the rotation 2.2 mrad wrong.
    #[test]
    fn kabsch_is_exact_when_two_singular_values_nearly_coincide() {
        let half = Vector3::new(0.075, 0.125, 0.125);
        let corners: Vec<Point3<f64>> = (0..8)
            .map(|c| {
                let sign = |bit: usize| if c >> bit & 1 == 1 { 1.0 } else { -1.0 };
                Point3::new(sign(0) * half.x, sign(1) * half.y, sign(2) * half.z)
            })
            .collect();
        let axis = Unit::new_normalize(Vector3::new(0.43, -0.64, 0.635));
        let truth = Isometry3::from_parts(
            Translation3::new(0.0, 0.44, 1.8),
            UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI),
        );
        // 10 µm of deterministic noise.
        let target: Vec<_> = corners
            .iter()
            .enumerate()
            .map(|(i, p)| {
                truth * p + Vector3::new(1.0, -0.7, 0.4) * (1e-5 * (i as f64 - 3.5) / 3.5)
            })
            .collect();
        let fit = kabsch(&corners, &target).unwrap();
        // First-order optimality: with centred sets, Rᵀ·Σ t sᵀ is symmetric at the optimum.
        let centred = |points: &[Point3<f64>]| {
            let mean = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
            points.iter().map(|p| p.coords - mean).collect::<Vec<_>>()
        };
        let cross: Matrix3<f64> = centred(&target)
            .iter()
            .zip(centred(&corners))
            .map(|(t, s)| t * s.transpose())
            .sum();
        let m = fit.rotation.to_rotation_matrix().into_inner().transpose() * cross;
        assert!((m - m.transpose()).norm() < 1e-12 * cross.norm());
        let at_truth: f64 = corners
            .iter()
            .zip(&target)
            .map(|(p, t)| (truth * p - t).norm_squared())
            .sum();
        assert!(sum_squared_residuals(&fit, &corners, &target) <= at_truth);
    }

    #[test]
    fn nearest_rotation_of_a_perturbed_rotation() {
        let rotation = pose().rotation.to_rotation_matrix();
        let nearest = nearest_rotation(rotation.matrix()).unwrap();
        assert!((nearest.matrix() - rotation.matrix()).norm() < 1e-12);
        let perturbed = rotation.matrix() + Matrix3::repeat(1e-3);
        let nearest = nearest_rotation(&perturbed).unwrap();
        let m = nearest.matrix().transpose() * perturbed;
        assert!((m - m.transpose()).norm() < 1e-12);
        assert!(nearest_rotation(&Matrix3::zeros()).is_none());
    }

    #[test]
    fn kabsch_recovers_an_exact_rigid_motion() {
        let source = cloud();
        let target: Vec<_> = source.iter().map(|p| pose() * p).collect();
        let fit = kabsch(&source, &target).unwrap();
        assert!((fit.to_homogeneous() - pose().to_homogeneous()).norm() < 1e-12);
    }

    #[test]
    fn umeyama_recovers_scale() {
        let source = cloud();
        let similarity = Similarity3::from_isometry(pose(), 2.5);
        let target: Vec<_> = source.iter().map(|p| similarity * p).collect();
        let fit = umeyama(&source, &target).unwrap();
        assert!((fit.scaling() - 2.5).abs() < 1e-12);
        assert!((fit.to_homogeneous() - similarity.to_homogeneous()).norm() < 1e-11);
    }

    #[test]
    fn mirrored_target_still_gives_a_proper_rotation() {
        let source = cloud();
        let target: Vec<_> = source.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let fit = kabsch(&source, &target).unwrap();
        let rotation = fit.rotation.to_rotation_matrix();
        assert!((rotation.matrix().determinant() - 1.0).abs() < 1e-12);
        // A proper rotation cannot reproduce a mirror image: the residual must stay positive, and no
        // sampled rotation may beat the returned one.
        let best = sum_squared_residuals(&fit, &source, &target);
        assert!(best > 1e-3);
        for k in 0..200 {
            let axis =
                Unit::new_normalize(Vector3::new((k as f64).sin(), (k as f64 * 0.7).cos(), 0.3));
            let candidate = Isometry3::from_parts(
                fit.translation,
                UnitQuaternion::from_axis_angle(&axis, 0.01) * fit.rotation,
            );
            assert!(sum_squared_residuals(&candidate, &source, &target) >= best - 1e-12);
        }
    }

    #[test]
    fn weights_select_the_trusted_points() {
        let source = cloud();
        let mut target: Vec<_> = source.iter().map(|p| pose() * p).collect();
        target.push(Point3::new(5.0, 5.0, 5.0));
        let mut source_with_outlier = source.clone();
        source_with_outlier.push(Point3::origin());
        let mut weights = vec![1.0; source.len()];
        weights.push(0.0);
        let fit = kabsch_weighted(&source_with_outlier, &target, &weights).unwrap();
        assert!((fit.to_homogeneous() - pose().to_homogeneous()).norm() < 1e-12);
        let unweighted = kabsch(&source_with_outlier, &target).unwrap();
        assert!((unweighted.to_homogeneous() - pose().to_homogeneous()).norm() > 1e-3);
    }

    #[test]
    fn quaternion_fit_matches_the_svd_fit() {
        let source = cloud();
        for k in 0..10 {
            let target: Vec<_> = source
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    pose() * p
                        + Vector3::new(
                            0.01 * (i as f64 + k as f64).sin(),
                            0.02 * (k as f64).cos(),
                            -0.01,
                        )
                })
                .collect();
            let svd = kabsch(&source, &target).unwrap();
            let quaternion = quaternion_kabsch(&source, &target).unwrap();
            assert!((svd.to_homogeneous() - quaternion.to_homogeneous()).norm() < 1e-9);
            // Three points, as the robust fit's hypotheses use.
            let svd = kabsch(&source[..3], &target[..3]).unwrap();
            let quaternion = quaternion_kabsch(&source[..3], &target[..3]).unwrap();
            assert!((svd.to_homogeneous() - quaternion.to_homogeneous()).norm() < 1e-9);
        }
    }

    #[test]
    fn rank_deficient_covariance_still_gives_an_optimal_fit() {
        // A rectangle matched to itself with corners permuted so that Σ b aᵀ has rank 1: the
        // rotation is not unique, but the fit exists and no rotation does better.
        let rectangle = [
            Point3::new(-0.15, -0.1, 0.0),
            Point3::new(0.15, -0.1, 0.0),
            Point3::new(0.15, 0.1, 0.0),
            Point3::new(-0.15, 0.1, 0.0),
        ];
        let permuted = [rectangle[0], rectangle[2], rectangle[1], rectangle[3]];
        let fit = kabsch(&rectangle, &permuted).unwrap();
        let best = sum_squared_residuals(&fit, &rectangle, &permuted);
        for k in 0..100 {
            let axis =
                Unit::new_normalize(Vector3::new((k as f64).cos(), (k as f64 * 1.3).sin(), 0.5));
            let other = Isometry3::from_parts(
                fit.translation,
                UnitQuaternion::from_axis_angle(&axis, 0.02 * k as f64),
            );
            assert!(sum_squared_residuals(&other, &rectangle, &permuted) >= best - 1e-12);
        }
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let line: Vec<_> = (0..4)
            .map(|i| Point3::new(i as f64, 2.0 * i as f64, 0.0))
            .collect();
        let same = vec![Point3::new(1.0, 1.0, 1.0); 4];
        let good = cloud()[..4].to_vec();
        assert_eq!(
            kabsch(&line, &good),
            Err(GeometryError::Degenerate("collinear points"))
        );
        assert_eq!(
            kabsch(&good, &same),
            Err(GeometryError::Degenerate("coincident points"))
        );
        assert!(matches!(
            kabsch(&good[..2], &good[..2]),
            Err(GeometryError::TooFewPoints { .. })
        ));
        assert!(matches!(
            kabsch(&good, &good[..3]),
            Err(GeometryError::ShapeMismatch { .. })
        ));
        let mut nan = good.clone();
        nan[1].y = f64::NAN;
        assert!(matches!(
            kabsch(&good, &nan),
            Err(GeometryError::NonFinite { .. })
        ));
        assert!(matches!(
            kabsch_weighted(&good, &good, &[1.0, -1.0, 1.0, 1.0]),
            Err(GeometryError::InvalidParameter { .. })
        ));
    }

    #[test]
    fn quaternion_minimum_matches_the_svd_fit() {
        let source = cloud();
        let target: Vec<_> = source
            .iter()
            .enumerate()
            .map(|(i, p)| {
                pose() * p + Vector3::new(0.05 * (i as f64).sin(), 0.03, -0.02 * i as f64)
            })
            .collect();
        let fit = kabsch(&source, &target).unwrap();
        let svd_sse = sum_squared_residuals(&fit, &source, &target);
        let centroid = |pts: &[Point3<f64>]| {
            pts.iter().map(|p| p.coords).sum::<Vector3<f64>>() / pts.len() as f64
        };
        let (ca, cb) = (centroid(&source), centroid(&target));
        let mut cross = Matrix3::zeros();
        let (mut na, mut nb) = (0.0, 0.0);
        for (a, b) in source.iter().zip(&target) {
            let (a, b) = (a.coords - ca, b.coords - cb);
            cross += b * a.transpose();
            na += a.norm_squared();
            nb += b.norm_squared();
        }
        let fit = QuaternionFit::new(&cross, na, nb);
        let qcp_sse = fit.min_error();
        assert!(fit.error_reaches(0.99 * svd_sse));
        assert!(!fit.error_reaches(1.01 * svd_sse));
        assert!((qcp_sse - svd_sse).abs() < 1e-12, "{qcp_sse} vs {svd_sse}");
    }
}
