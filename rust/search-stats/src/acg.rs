//! The angular central Gaussian ACG(Λ) on S³ (Tyler 1987) and the small symmetric 4×4 linear
//! algebra it needs (Cholesky, Jacobi eigen-decomposition), for the rotation blocks of
//! [`crate::Proposal`].
//!
//! ACG(Λ) is the law of u = x/‖x‖ for x ~ N(0, Λ); its density with respect to the uniform
//! probability measure on S³ is |Λ|^{-1/2} (uᵀΛ⁻¹u)^{-2}. It is antipodally symmetric
//! (u ≡ −u, as a unit quaternion's rotation q ≡ −q), invariant under Λ → cΛ (so Λ is kept at
//! trace 4), and uniform for Λ = I.

/// A symmetric 4×4 matrix, row-major.
pub type Sym4 = [[f64; 4]; 4];

/// The identity.
pub const IDENTITY: Sym4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Sweeps of the cyclic Jacobi eigenvalue method (4×4 converges to rounding in ≤ 6).
const JACOBI_SWEEPS: usize = 12;

/// Lower Cholesky factor L (Λ = L Lᵀ), or `None` if Λ is not symmetric positive definite.
pub fn cholesky(a: &Sym4) -> Option<Sym4> {
    let mut l = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    Some(l)
}

/// ‖L⁻¹x‖² = xᵀΛ⁻¹x by forward substitution.
pub fn quad_inv(l: &Sym4, x: &[f64]) -> f64 {
    let mut y = [0.0; 4];
    let mut acc = 0.0;
    for i in 0..4 {
        let mut s = x[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
        acc += y[i] * y[i];
    }
    acc
}

/// ln |Λ| = 2 Σ ln L_ii.
pub fn log_det(l: &Sym4) -> f64 {
    2.0 * (0..4).map(|i| l[i][i].ln()).sum::<f64>()
}

/// Whether `a` is finite and symmetric (to 1e-9 relative to its largest entry).
pub fn is_symmetric(a: &Sym4) -> bool {
    let scale = a
        .iter()
        .flatten()
        .fold(0.0f64, |m, x| m.max(x.abs()))
        .max(1e-300);
    a.iter().flatten().all(|x| x.is_finite())
        && (0..4).all(|i| (0..i).all(|j| (a[i][j] - a[j][i]).abs() <= 1e-9 * scale))
}

/// ln ACG(u; Λ) with respect to the uniform measure on S³, for any x ≠ 0 with u = x/‖x‖:
/// −½ ln|Λ| − 2 ln(xᵀΛ⁻¹x / xᵀx). `l` is Λ's Cholesky factor. Returns 0 at x = 0 (a null set).
pub fn log_acg_rel(l: &Sym4, x: &[f64]) -> f64 {
    let r2: f64 = x.iter().map(|v| v * v).sum();
    if !(r2 > 0.0) {
        return 0.0;
    }
    -0.5 * log_det(l) - 2.0 * (quad_inv(l, x) / r2).ln()
}

/// Eigenvalues and eigenvectors (columns of V, Λ = V diag(e) Vᵀ) by cyclic Jacobi rotations.
pub fn eigen(a: &Sym4) -> ([f64; 4], Sym4) {
    let mut m = *a;
    let mut v = IDENTITY;
    for _ in 0..JACOBI_SWEEPS {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| m[i][j] * m[i][j])
            .sum();
        let diag: f64 = (0..4).map(|i| m[i][i] * m[i][i]).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if m[p][q] == 0.0 {
                    continue;
                }
                let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let (mkp, mkq) = (m[k][p], m[k][q]);
                    m[k][p] = c * mkp - s * mkq;
                    m[k][q] = s * mkp + c * mkq;
                }
                for k in 0..4 {
                    let (mpk, mqk) = (m[p][k], m[q][k]);
                    m[p][k] = c * mpk - s * mqk;
                    m[q][k] = s * mpk + c * mqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    ([m[0][0], m[1][1], m[2][2], m[3][3]], v)
}

/// V diag(e) Vᵀ.
fn compose(e: &[f64; 4], v: &Sym4) -> Sym4 {
    let mut a = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            a[i][j] = (0..4).map(|k| v[i][k] * e[k] * v[j][k]).sum();
        }
    }
    // exact symmetry
    for i in 0..4 {
        for j in 0..i {
            let s = 0.5 * (a[i][j] + a[j][i]);
            a[i][j] = s;
            a[j][i] = s;
        }
    }
    a
}

/// Projects a symmetric positive semi-definite (or slightly indefinite) matrix to trace 4 with
/// every eigenvalue ≥ `floor` (0 < floor ≤ 1): eigenvalues μ_i = max(c e_i, floor) with c
/// chosen so that Σ μ_i = 4 (water-filling). Then |Λ| ≤ 1 and λ_min ≥ floor.
pub fn floor_trace4(a: &Sym4, floor: f64) -> Sym4 {
    let (e, v) = eigen(a);
    let e = e.map(|x| x.max(0.0));
    let mut clamped = [false; 4];
    let mut mu = [1.0; 4];
    for _ in 0..5 {
        let free_sum: f64 = (0..4).filter(|&i| !clamped[i]).map(|i| e[i]).sum();
        let n_clamped = clamped.iter().filter(|&&c| c).count() as f64;
        let c = if free_sum > 0.0 {
            (4.0 - n_clamped * floor) / free_sum
        } else {
            0.0
        };
        let mut changed = false;
        for i in 0..4 {
            if !clamped[i] && c * e[i] < floor {
                clamped[i] = true;
                changed = true;
            }
        }
        for i in 0..4 {
            mu[i] = if clamped[i] { floor } else { c * e[i] };
        }
        if !changed {
            break;
        }
    }
    if clamped.iter().all(|&c| c) {
        mu = [1.0; 4];
    }
    compose(&mu, &v)
}

/// Weighted, floored Tyler fixed point (the weighted MLE of ACG(Λ)) from the start `init`:
/// `steps` times Λ ← 4 Σ_i v_i u_i u_iᵀ/(u_iᵀΛ⁻¹u_i) / Σ_i v_i, then [`floor_trace4`]. Points
/// `xs` need not be unit vectors (only their directions count; x = 0 is skipped).
pub fn tyler(xs: &[[f64; 4]], weights: &[f64], init: &Sym4, floor: f64, steps: usize) -> Sym4 {
    let mut lambda = floor_trace4(init, floor);
    let units: Vec<([f64; 4], f64)> = xs
        .iter()
        .zip(weights)
        .filter_map(|(x, &w)| {
            let r = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            (r > 0.0 && w > 0.0).then(|| (x.map(|v| v / r), w))
        })
        .collect();
    let total: f64 = units.iter().map(|(_, w)| w).sum();
    if !(total > 0.0) {
        return lambda;
    }
    for _ in 0..steps {
        let Some(l) = cholesky(&lambda) else { break };
        let mut s = [[0.0; 4]; 4];
        for (u, w) in &units {
            let f = w / quad_inv(&l, u);
            for i in 0..4 {
                for j in 0..=i {
                    s[i][j] += f * u[i] * u[j];
                }
            }
        }
        for i in 0..4 {
            for j in 0..i {
                s[j][i] = s[i][j];
            }
        }
        lambda = floor_trace4(&s, floor);
    }
    lambda
}

#[cfg(test)]
mod tests {
    use super::*;

    fn matmul(a: &Sym4, b: &Sym4) -> Sym4 {
        let mut c = [[0.0; 4]; 4];
        for i in 0..4 {
            for j in 0..4 {
                c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
            }
        }
        c
    }

    const A: Sym4 = [
        [2.0, 0.3, -0.1, 0.4],
        [0.3, 1.0, 0.2, 0.0],
        [-0.1, 0.2, 0.5, 0.1],
        [0.4, 0.0, 0.1, 0.5],
    ];

    #[test]
    fn cholesky_and_eigen_reconstruct() {
        let l = cholesky(&A).unwrap();
        let mut lt = [[0.0; 4]; 4];
        for i in 0..4 {
            for j in 0..4 {
                lt[i][j] = l[j][i];
            }
        }
        let back = matmul(&l, &lt);
        let (e, v) = eigen(&A);
        let back2 = compose(&e, &v);
        for i in 0..4 {
            for j in 0..4 {
                assert!((back[i][j] - A[i][j]).abs() < 1e-12);
                assert!((back2[i][j] - A[i][j]).abs() < 1e-12);
            }
        }
        assert!((e.iter().product::<f64>().ln() - log_det(&l)).abs() < 1e-10);
        assert!(
            cholesky(&[
                [1.0, 2.0, 0.0, 0.0],
                [2.0, 1.0, 0.0, 0.0],
                [0.0; 4],
                [0.0; 4]
            ])
            .is_none()
        );
    }

    #[test]
    fn floor_keeps_trace_and_floor() {
        let a = [
            [10.0, 0.0, 0.0, 0.0],
            [0.0, 1e-6, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.5],
        ];
        let f = floor_trace4(&a, 0.05);
        let (e, _) = eigen(&f);
        assert!(((0..4).map(|i| f[i][i]).sum::<f64>() - 4.0).abs() < 1e-12);
        assert!(e.iter().all(|&x| x >= 0.05 - 1e-12), "{e:?}");
        assert_eq!(floor_trace4(&IDENTITY, 0.05), IDENTITY);
    }
}
