//! The defensive Gaussian-mixture proposal over the search's z-space.

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::acg::{self, Sym4};

/// Smallest per-dimension standard deviation [`Proposal::fit`] may produce.
pub const MIN_STD: f64 = 0.05;

/// Smallest mixture weight a fit with K > 1 keeps for a component (then renormalised), so no
/// component dies.
pub const MIN_COMPONENT_WEIGHT: f64 = 1e-3;

/// EM iterations per [`Proposal::fit`] when K > 1.
pub const EM_STEPS: usize = 8;

/// Smallest eigenvalue of a fitted rotation-block shape Λ (kept at trace 4), the analogue of
/// [`MIN_STD`]: a block's likelihood ratio is then at most |Λ|^{1/2}/λ_min² ≤ 1/0.05² = 400.
pub const MIN_SHAPE_EIGENVALUE: f64 = 0.05;

/// Tyler fixed-point iterations per rotation block and fit (or EM step).
pub const TYLER_STEPS: usize = 10;

/// Dimensions of a rotation block (a quaternion).
pub const ROTATION_BLOCK_DIM: usize = 4;

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// log N(z; 0, I_d) = −(d/2) ln 2π − ‖z‖²/2, the exact nominal density of the search's z-space.
pub fn log_nominal(z: &[f64]) -> f64 {
    -0.5 * (z.len() as f64 * LN_2PI + z.iter().map(|x| x * x).sum::<f64>())
}

fn logsumexp(terms: &[f64]) -> f64 {
    let max = terms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        return max;
    }
    max + terms.iter().map(|t| (t - max).exp()).sum::<f64>().ln()
}

/// The shape of one rotation block z[start..start + 4] within a component: the block's
/// direction u = z_B/‖z_B‖ is ACG(Λ) on S³ and its radius ‖z_B‖ keeps the nominal χ₄ law, so
/// the block's density in R⁴ is N(z_B; 0, I₄) · |Λ|^{-1/2} (uᵀΛ⁻¹u)^{-2}.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RotationShape {
    /// Index of the block's first dimension.
    pub start: usize,
    /// Λ: symmetric positive definite 4×4 (row-major); only its direction matters (fits keep
    /// trace 4). Λ = I is the nominal (uniform rotation).
    pub shape: Sym4,
}

/// One mixture component with its mixture weight π: N(μ, diag σ²) on the dimensions outside
/// its rotation blocks, and on each rotation block the nominal radius with an ACG(Λ)
/// direction ([`RotationShape`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Component {
    /// Mixture weight π_k (the weights of a proposal's components sum to 1).
    pub weight: f64,
    /// Mean μ_k (entries in rotation blocks are unused; fits keep them at 0).
    pub mean: Vec<f64>,
    /// Per-dimension standard deviation σ_k, all > 0 (entries in rotation blocks are unused;
    /// fits keep them at 1).
    pub std: Vec<f64>,
    /// The rotation blocks, by increasing `start` (empty: the plain diagonal Gaussian). Every
    /// component of a proposal has the same block starts.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rotations: Vec<RotationShape>,
}

fn in_block(rotations: &[RotationShape], j: usize) -> bool {
    rotations
        .iter()
        .any(|r| (r.start..r.start + ROTATION_BLOCK_DIM).contains(&j))
}

impl Component {
    fn standard(dim: usize, weight: f64) -> Self {
        Self {
            weight,
            mean: vec![0.0; dim],
            std: vec![1.0; dim],
            rotations: Vec::new(),
        }
    }

    /// log of the component's density: log N(z; μ, diag σ²) over the dimensions outside the
    /// rotation blocks, plus, per block B, log N(z_B; 0, I₄) + log ACG(z_B/‖z_B‖; Λ) (ACG
    /// relative to the uniform measure on S³).
    pub fn log_density(&self, z: &[f64]) -> f64 {
        let mut acc = -0.5 * z.len() as f64 * LN_2PI;
        for (j, ((x, m), s)) in z.iter().zip(&self.mean).zip(&self.std).enumerate() {
            if !self.rotations.is_empty() && in_block(&self.rotations, j) {
                acc -= 0.5 * x * x;
                continue;
            }
            let u = (x - m) / s;
            acc -= 0.5 * u * u + s.ln();
        }
        for r in &self.rotations {
            if r.shape == acg::IDENTITY {
                continue;
            }
            let l = acg::cholesky(&r.shape).expect("validated shape");
            acc += acg::log_acg_rel(&l, &z[r.start..r.start + ROTATION_BLOCK_DIM]);
        }
        acc
    }

    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Vec<f64> {
        let mut z: Vec<f64> = self
            .mean
            .iter()
            .zip(&self.std)
            .enumerate()
            .map(|(j, (m, s))| {
                let e: f64 = StandardNormal.sample(rng);
                if !self.rotations.is_empty() && in_block(&self.rotations, j) {
                    e
                } else {
                    m + s * e
                }
            })
            .collect();
        for r in &self.rotations {
            // radius ‖N(0, I₄)‖ ~ χ₄ (from the block's own draws), direction L e/‖L e‖
            let block = &mut z[r.start..r.start + ROTATION_BLOCK_DIM];
            let radius = block.iter().map(|x| x * x).sum::<f64>().sqrt();
            let l = acg::cholesky(&r.shape).expect("validated shape");
            let e: [f64; 4] = std::array::from_fn(|_| StandardNormal.sample(rng));
            let x: [f64; 4] = std::array::from_fn(|i| (0..=i).map(|k| l[i][k] * e[k]).sum());
            let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            for (b, v) in block.iter_mut().zip(x) {
                *b = radius * v / norm;
            }
        }
        z
    }
}

/// Why a proposal or its fit is malformed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProposalError {
    /// `defensive` (λ) is not in [0, 1].
    #[error("defensive weight λ = {0} is not in [0, 1]")]
    BadDefensive(f64),
    /// No component.
    #[error("a proposal needs at least one component")]
    NoComponents,
    /// A component's mean or std has the wrong length, a non-finite entry, or a std ≤ 0.
    #[error("component {0}: mean and std must have the proposal's dimension, be finite, std > 0")]
    BadComponent(usize),
    /// Mixture weights negative, non-finite or summing to zero.
    #[error("mixture weights must be non-negative with a positive sum")]
    BadWeights,
    /// `fit` got different numbers of points and weights, no positive weight, a point of the
    /// wrong dimension, or a smoothing outside [0, 1].
    #[error("fit: {0}")]
    BadFit(String),
    /// Rotation blocks overlap, leave the dimension, differ between components, or a shape Λ
    /// is not symmetric positive definite.
    #[error("rotation blocks: {0}")]
    BadRotationBlocks(String),
}

/// The defensive mixture proposal over R^d:
///
/// q(z) = λ N(z; 0, I_d) + (1 − λ) Σ_k π_k N(z; μ_k, diag σ_k²),  K ≥ 1, Σ_k π_k = 1.
///
/// λ = `defensive` ∈ [0, 1]; λ = 1 is the nominal itself, and λ > 0 bounds the likelihood ratio
/// w(z) = p(z)/q(z) ≤ 1/λ. Serialises to JSON so a run can store it at each iteration barrier.
///
/// **Rotation blocks.** When z[s..s + 4] normalised is an orientation (a unit quaternion,
/// uniform on SO(3) under the nominal, q ≡ −q), declare it a rotation block:
/// `Proposal::tuning_start(dim, k).with_rotation_blocks(&[s])?`. In every component that block
/// is then not a diagonal Gaussian but the nominal radius ‖z_B‖ ~ χ₄ with an angular central
/// Gaussian direction ACG(Λ_k) (see [`RotationShape`]), whose likelihood ratio against the
/// nominal is 1/ACG(u; Λ) ≤ |Λ|^{1/2}/λ_min(Λ)² (≤ 1/[`MIN_SHAPE_EIGENVALUE`]² after a fit).
/// The block's mean and std entries are unused. [`Proposal::fit`] and the cross-entropy step
/// keep the blocks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Proposal {
    /// Dimension d of z.
    pub dim: usize,
    /// Defensive weight λ of the nominal N(0, I_d).
    pub defensive: f64,
    /// The adapted components (K ≥ 1).
    pub components: Vec<Component>,
}

impl Proposal {
    /// Builds and checks a proposal; mixture weights are renormalised to sum to 1.
    pub fn new(
        dim: usize,
        defensive: f64,
        mut components: Vec<Component>,
    ) -> Result<Self, ProposalError> {
        if !(0.0..=1.0).contains(&defensive) {
            return Err(ProposalError::BadDefensive(defensive));
        }
        if components.is_empty() {
            return Err(ProposalError::NoComponents);
        }
        for (k, c) in components.iter().enumerate() {
            let ok = c.mean.len() == dim
                && c.std.len() == dim
                && c.mean.iter().all(|m| m.is_finite())
                && c.std.iter().all(|s| s.is_finite() && *s > 0.0);
            if !ok {
                return Err(ProposalError::BadComponent(k));
            }
        }
        let starts: Vec<usize> = components[0].rotations.iter().map(|r| r.start).collect();
        check_blocks(dim, &starts)?;
        for (k, c) in components.iter().enumerate() {
            if !c
                .rotations
                .iter()
                .map(|r| r.start)
                .eq(starts.iter().copied())
            {
                return Err(ProposalError::BadRotationBlocks(format!(
                    "component {k} has other block starts than component 0 ({starts:?})"
                )));
            }
            for r in &c.rotations {
                if !acg::is_symmetric(&r.shape) || acg::cholesky(&r.shape).is_none() {
                    return Err(ProposalError::BadRotationBlocks(format!(
                        "component {k}, block at {}: Λ is not symmetric positive definite",
                        r.start
                    )));
                }
            }
        }
        let total: f64 = components.iter().map(|c| c.weight).sum();
        if components
            .iter()
            .any(|c| !c.weight.is_finite() || c.weight < 0.0)
            || !(total > 0.0 && total.is_finite())
        {
            return Err(ProposalError::BadWeights);
        }
        for c in &mut components {
            c.weight /= total;
        }
        Ok(Self {
            dim,
            defensive,
            components,
        })
    }

    /// The nominal N(0, I_d) itself: λ = 1, one standard component.
    pub fn nominal(dim: usize) -> Self {
        Self {
            dim,
            defensive: 1.0,
            components: vec![Component::standard(dim, 1.0)],
        }
    }

    /// The starting proposal of a cross-entropy search with `components` (K ≥ 1) mixture
    /// components: λ = 0 and K copies of N(0, I_d) with equal weights, i.e. the nominal
    /// distribution. The first [`Proposal::fit`] with K > 1 seeds the components apart.
    pub fn tuning_start(dim: usize, components: usize) -> Self {
        let k = components.max(1);
        Self {
            dim,
            defensive: 0.0,
            components: (0..k)
                .map(|_| Component::standard(dim, 1.0 / k as f64))
                .collect(),
        }
    }

    /// The same proposal with rotation blocks z[s..s + 4] for each s in `starts` (replacing any
    /// present): in every component each block gets Λ = I (so the distribution of a component
    /// whose block entries were mean 0, std 1 is unchanged) and its mean/std entries are reset
    /// to 0/1. Blocks must lie inside the dimension and not overlap; `&[]` removes the blocks.
    ///
    /// E.g. the starting proposal of a search whose z[0..4] is an orientation:
    /// `Proposal::tuning_start(dim, k).with_rotation_blocks(&[0])?`.
    pub fn with_rotation_blocks(&self, starts: &[usize]) -> Result<Self, ProposalError> {
        let mut starts = starts.to_vec();
        starts.sort_unstable();
        check_blocks(self.dim, &starts)?;
        let mut out = self.clone();
        for c in &mut out.components {
            c.rotations = starts
                .iter()
                .map(|&start| RotationShape {
                    start,
                    shape: acg::IDENTITY,
                })
                .collect();
            for &s in &starts {
                for j in s..s + ROTATION_BLOCK_DIM {
                    c.mean[j] = 0.0;
                    c.std[j] = 1.0;
                }
            }
        }
        Ok(out)
    }

    /// The start indices of the rotation blocks (empty when there are none).
    pub fn rotation_blocks(&self) -> Vec<usize> {
        self.components
            .first()
            .map(|c| c.rotations.iter().map(|r| r.start).collect())
            .unwrap_or_default()
    }

    /// The same components with defensive weight λ (clamped to [0, 1]). When every component is
    /// N(0, I) (nothing tilted) the mixture is the nominal itself, written as [`Proposal::nominal`]'s
    /// λ = 1: every log weight is then exactly 0 and the estimate is plain Monte Carlo's, with its
    /// exact interval.
    pub fn with_defensive(&self, lambda: f64) -> Self {
        let nominal = self.components.iter().all(|c| {
            c.mean.iter().all(|&m| m == 0.0)
                && c.std.iter().all(|&s| s == 1.0)
                && c.rotations.iter().all(|r| r.shape == acg::IDENTITY)
        });
        Self {
            defensive: if nominal { 1.0 } else { lambda.clamp(0.0, 1.0) },
            ..self.clone()
        }
    }

    /// Draws one z ~ q: with probability λ from N(0, I), else from component k with
    /// probability π_k.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Vec<f64> {
        let u: f64 = rng.random();
        if u < self.defensive || self.defensive >= 1.0 {
            return (0..self.dim).map(|_| StandardNormal.sample(rng)).collect();
        }
        let mut v: f64 = rng.random();
        let mut chosen = self.components.len() - 1;
        for (k, c) in self.components.iter().enumerate() {
            if v < c.weight {
                chosen = k;
                break;
            }
            v -= c.weight;
        }
        self.components[chosen].sample(rng)
    }

    /// log q(z), exact, by log-sum-exp over the nominal and the components.
    pub fn log_density(&self, z: &[f64]) -> f64 {
        let nominal = log_nominal(z);
        if self.defensive >= 1.0 {
            return nominal;
        }
        let mut terms = Vec::with_capacity(self.components.len() + 1);
        if self.defensive > 0.0 {
            terms.push(self.defensive.ln() + nominal);
        }
        let rest = (1.0 - self.defensive).ln();
        for c in &self.components {
            if c.weight > 0.0 {
                terms.push(rest + c.weight.ln() + c.log_density(z));
            }
        }
        logsumexp(&terms)
    }

    /// log w(z) = log p(z) − log q(z), the log likelihood ratio of the nominal over q
    /// (exactly 0 when λ = 1; at most ln(1/λ) when λ > 0).
    pub fn log_weight(&self, z: &[f64]) -> f64 {
        if self.defensive >= 1.0 {
            return 0.0;
        }
        log_nominal(z) - self.log_density(z)
    }

    /// Weighted maximum-likelihood update of the components (λ is kept), smoothed:
    ///
    /// - K = 1: μ = Σ w_i z_i / Σ w_i, σ_j² = Σ w_i (z_ij − μ_j)² / Σ w_i (closed form);
    /// - K > 1: [`EM_STEPS`] steps of weighted EM initialised from the current components
    ///   (or, when they coincide, from farthest-point seeds among the heaviest points), mixture
    ///   weights floored at [`MIN_COMPONENT_WEIGHT`].
    ///
    /// σ is floored at [`MIN_STD`] ([`Proposal::fit_floored`] takes the floor). Smoothing acts on (μ, σ) and on the mixture weights π:
    /// θ_new = α θ_fit + (1 − α) θ_old, with α = `smoothing` ∈ [0, 1] (α = 1: no smoothing).
    ///
    /// Rotation blocks: per component and block, [`TYLER_STEPS`] iterations of the weighted
    /// Tyler fixed point (the ACG's MLE) from the current Λ, with u_i = z_iB/‖z_iB‖ and weights
    /// v_i = w_i (times the EM responsibility when K > 1):
    /// Λ ← 4 Σ_i v_i u_i u_iᵀ/(u_iᵀΛ⁻¹u_i) / Σ_i v_i, each iterate projected to trace 4 with
    /// every eigenvalue ≥ [`MIN_SHAPE_EIGENVALUE`] (the fitted shape's direction-only density
    /// then gives a block likelihood ratio ≤ |Λ|^{1/2}/λ_min² ≤ 1/[`MIN_SHAPE_EIGENVALUE`]²),
    /// then smoothed Λ_new = α Λ_fit + (1 − α) Λ_old (which keeps trace 4 and the floor).
    /// `weights` need not be normalised (they are self-normalised) and must be non-negative.
    pub fn fit(
        &self,
        zs: &[Vec<f64>],
        weights: &[f64],
        smoothing: f64,
    ) -> Result<Proposal, ProposalError> {
        self.fit_floored(zs, weights, smoothing, MIN_STD)
    }

    /// [`Proposal::fit`] with every fitted and smoothed σ floored at `min_std` (> 0) instead of
    /// [`MIN_STD`]. A floor above 1/√2 keeps E_q[w²] finite for every component even without
    /// the defensive nominal, since ∫ N(0,1)²/N(μ,σ²) is finite iff σ² > 1/2.
    pub fn fit_floored(
        &self,
        zs: &[Vec<f64>],
        weights: &[f64],
        smoothing: f64,
        min_std: f64,
    ) -> Result<Proposal, ProposalError> {
        if !(min_std.is_finite() && min_std > 0.0) {
            return Err(ProposalError::BadFit(format!(
                "min_std {min_std} must be > 0"
            )));
        }
        if zs.len() != weights.len() {
            return Err(ProposalError::BadFit(format!(
                "{} points but {} weights",
                zs.len(),
                weights.len()
            )));
        }
        if !(0.0..=1.0).contains(&smoothing) {
            return Err(ProposalError::BadFit(format!(
                "smoothing {smoothing} is not in [0, 1]"
            )));
        }
        if weights.iter().any(|w| !w.is_finite() || *w < 0.0) {
            return Err(ProposalError::BadFit(
                "weights must be finite and non-negative".into(),
            ));
        }
        let total: f64 = weights.iter().sum();
        if total.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(ProposalError::BadFit("no positive weight".into()));
        }
        if zs.iter().any(|z| z.len() != self.dim) {
            return Err(ProposalError::BadFit(format!(
                "a point's dimension differs from {}",
                self.dim
            )));
        }
        let fitted = if self.components.len() == 1 {
            vec![fit_component(
                &self.components[0],
                zs,
                weights,
                |_| 1.0,
                min_std,
                1.0,
            )]
        } else {
            self.em(zs, weights, min_std)
        };
        let a = smoothing;
        let components = fitted
            .into_iter()
            .zip(&self.components)
            .map(|(f, old)| {
                let mut c = Component {
                    weight: a * f.weight + (1.0 - a) * old.weight,
                    mean: f
                        .mean
                        .iter()
                        .zip(&old.mean)
                        .map(|(n, o)| a * n + (1.0 - a) * o)
                        .collect(),
                    std: f
                        .std
                        .iter()
                        .zip(&old.std)
                        .map(|(n, o)| (a * n + (1.0 - a) * o).max(min_std))
                        .collect(),
                    rotations: f
                        .rotations
                        .iter()
                        .zip(&old.rotations)
                        .map(|(n, o)| RotationShape {
                            start: n.start,
                            shape: smooth_shape(&n.shape, &o.shape, a),
                        })
                        .collect(),
                };
                reset_block_entries(&mut c);
                c
            })
            .collect();
        Proposal::new(self.dim, self.defensive, components)
    }

    fn em(&self, zs: &[Vec<f64>], weights: &[f64], min_std: f64) -> Vec<Component> {
        let k = self.components.len();
        let mut comps = self.components.clone();
        if components_coincide(&comps) {
            let seeds = farthest_point_seeds(zs, weights, k, &comps[0].rotations);
            for (c, seed) in comps.iter_mut().zip(seeds) {
                c.mean = zs[seed].clone();
                for r in &mut c.rotations {
                    // a mild concentration on the seed's axis: Λ ∝ I + 3 u uᵀ
                    let x = &zs[seed][r.start..r.start + ROTATION_BLOCK_DIM];
                    let n2: f64 = x.iter().map(|v| v * v).sum();
                    let mut shape = acg::IDENTITY;
                    if n2 > 0.0 {
                        for i in 0..4 {
                            for j in 0..4 {
                                shape[i][j] += 3.0 * x[i] * x[j] / n2;
                            }
                        }
                    }
                    r.shape = acg::floor_trace4(&shape, MIN_SHAPE_EIGENVALUE);
                }
                reset_block_entries(c);
            }
        }
        let mut resp = vec![0.0; zs.len() * k];
        let mut terms = vec![0.0; k];
        for _ in 0..EM_STEPS {
            for (i, z) in zs.iter().enumerate() {
                for (t, c) in terms.iter_mut().zip(&comps) {
                    *t = c.weight.ln() + c.log_density(z);
                }
                let norm = logsumexp(&terms);
                for j in 0..k {
                    resp[i * k + j] = if norm.is_finite() {
                        (terms[j] - norm).exp()
                    } else {
                        1.0 / k as f64
                    };
                }
            }
            let mut new = Vec::with_capacity(k);
            for (j, old) in comps.iter().enumerate() {
                let mass: f64 = weights
                    .iter()
                    .enumerate()
                    .map(|(i, w)| w * resp[i * k + j])
                    .sum();
                if mass > 0.0 {
                    new.push(fit_component(
                        old,
                        zs,
                        weights,
                        |i| resp[i * k + j],
                        min_std,
                        mass,
                    ));
                } else {
                    new.push(Component {
                        weight: 0.0,
                        ..old.clone()
                    });
                }
            }
            let total: f64 = new.iter().map(|c| c.weight).sum();
            for c in &mut new {
                c.weight = (c.weight / total).max(MIN_COMPONENT_WEIGHT);
            }
            let total: f64 = new.iter().map(|c| c.weight).sum();
            for c in &mut new {
                c.weight /= total;
            }
            comps = new;
        }
        comps
    }
}

/// The weighted MLE of one component with per-point extra factor `r(i)` (an EM
/// responsibility, or 1): weighted moments on the dimensions outside the rotation blocks (σ
/// floored at `min_std`), and per block the weighted, floored Tyler fixed point started from
/// `old`'s Λ. Block entries of mean/std are reset to 0/1.
fn fit_component(
    old: &Component,
    zs: &[Vec<f64>],
    weights: &[f64],
    r: impl Fn(usize) -> f64,
    min_std: f64,
    weight: f64,
) -> Component {
    let (mean, std) = weighted_moments(zs, weights, &r, old.mean.len(), min_std);
    let rotations = old
        .rotations
        .iter()
        .map(|rot| {
            let xs: Vec<[f64; 4]> = zs
                .iter()
                .map(|z| std::array::from_fn(|i| z[rot.start + i]))
                .collect();
            let v: Vec<f64> = weights.iter().enumerate().map(|(i, w)| w * r(i)).collect();
            RotationShape {
                start: rot.start,
                shape: acg::tyler(&xs, &v, &rot.shape, MIN_SHAPE_EIGENVALUE, TYLER_STEPS),
            }
        })
        .collect();
    let mut c = Component {
        weight,
        mean,
        std,
        rotations,
    };
    reset_block_entries(&mut c);
    c
}

/// Mean 0 and std 1 on the (unused) rotation-block entries.
fn reset_block_entries(c: &mut Component) {
    for r in &c.rotations {
        for j in r.start..r.start + ROTATION_BLOCK_DIM {
            c.mean[j] = 0.0;
            c.std[j] = 1.0;
        }
    }
}

/// α Λ_fit + (1 − α) Λ_old, renormalised to trace 4. Both have trace 4 and λ_min ≥ the floor,
/// and λ_min is concave, so the result keeps the floor.
fn smooth_shape(new: &Sym4, old: &Sym4, a: f64) -> Sym4 {
    let mut s = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            s[i][j] = a * new[i][j] + (1.0 - a) * old[i][j];
        }
    }
    let tr: f64 = (0..4).map(|i| s[i][i]).sum();
    if tr > 0.0 {
        for row in &mut s {
            for x in row {
                *x *= 4.0 / tr;
            }
        }
    }
    s
}

/// The start indices of `blocks` must be increasing, non-overlapping and inside `dim`.
fn check_blocks(dim: usize, starts: &[usize]) -> Result<(), ProposalError> {
    for (i, &s) in starts.iter().enumerate() {
        if s + ROTATION_BLOCK_DIM > dim {
            return Err(ProposalError::BadRotationBlocks(format!(
                "block at {s} leaves dimension {dim}"
            )));
        }
        if i > 0 && starts[i - 1] + ROTATION_BLOCK_DIM > s {
            return Err(ProposalError::BadRotationBlocks(format!(
                "blocks at {} and {s} overlap",
                starts[i - 1]
            )));
        }
    }
    Ok(())
}

/// Weighted mean and std (floored at `min_std`) with per-point extra factor `r(i)`.
fn weighted_moments(
    zs: &[Vec<f64>],
    weights: &[f64],
    r: &impl Fn(usize) -> f64,
    dim: usize,
    min_std: f64,
) -> (Vec<f64>, Vec<f64>) {
    let mut mean = vec![0.0; dim];
    let mut total = 0.0;
    for (i, (z, w)) in zs.iter().zip(weights).enumerate() {
        let v = w * r(i);
        total += v;
        for (m, x) in mean.iter_mut().zip(z) {
            *m += v * x;
        }
    }
    for m in &mut mean {
        *m /= total;
    }
    let mut var = vec![0.0; dim];
    for (i, (z, w)) in zs.iter().zip(weights).enumerate() {
        let v = w * r(i);
        for ((s, x), m) in var.iter_mut().zip(z).zip(&mean) {
            *s += v * (x - m) * (x - m);
        }
    }
    let std = var
        .into_iter()
        .map(|s| (s / total).sqrt().max(min_std))
        .collect();
    (mean, std)
}

fn components_coincide(comps: &[Component]) -> bool {
    comps.windows(2).all(|w| {
        w[0].mean
            .iter()
            .zip(&w[1].mean)
            .all(|(a, b)| (a - b).abs() < 1e-9)
            && w[0].rotations == w[1].rotations
    })
}

/// Deterministic farthest-point seeding: the heaviest point first, then repeatedly the point
/// maximising weight × squared distance to the nearest chosen seed. In rotation blocks the
/// distance is axial, 4 (1 − (u·v)²) between the directions, so q and −q coincide.
fn farthest_point_seeds(
    zs: &[Vec<f64>],
    weights: &[f64],
    k: usize,
    rotations: &[RotationShape],
) -> Vec<usize> {
    let dist2 = |a: &[f64], b: &[f64]| -> f64 {
        let mut d = 0.0;
        for (j, (x, y)) in a.iter().zip(b).enumerate() {
            if !in_block(rotations, j) {
                d += (x - y) * (x - y);
            }
        }
        for r in rotations {
            let (x, y) = (
                &a[r.start..r.start + ROTATION_BLOCK_DIM],
                &b[r.start..r.start + ROTATION_BLOCK_DIM],
            );
            let nx: f64 = x.iter().map(|v| v * v).sum();
            let ny: f64 = y.iter().map(|v| v * v).sum();
            let dot: f64 = x.iter().zip(y).map(|(p, q)| p * q).sum();
            if nx > 0.0 && ny > 0.0 {
                d += 4.0 * (1.0 - dot * dot / (nx * ny));
            }
        }
        d
    };
    let first = (0..zs.len())
        .max_by(|&a, &b| weights[a].total_cmp(&weights[b]))
        .unwrap_or(0);
    let mut seeds = vec![first];
    let mut nearest: Vec<f64> = zs.iter().map(|z| dist2(z, &zs[first])).collect();
    while seeds.len() < k {
        let next = (0..zs.len())
            .max_by(|&a, &b| (weights[a] * nearest[a]).total_cmp(&(weights[b] * nearest[b])))
            .unwrap_or(0);
        seeds.push(next);
        for (d, z) in nearest.iter_mut().zip(zs) {
            *d = d.min(dist2(z, &zs[next]));
        }
    }
    seeds
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::sample_rng;

    #[test]
    fn nominal_has_zero_log_weight() {
        let p = Proposal::nominal(5);
        let z = [0.3, -1.0, 2.0, 0.0, 0.5];
        assert_eq!(p.log_weight(&z), 0.0);
        assert!((p.log_density(&z) - log_nominal(&z)).abs() < 1e-12);
        // λ = 0 with the standard component is the nominal too, up to rounding.
        assert!(Proposal::tuning_start(5, 2).log_weight(&z).abs() < 1e-12);
    }

    #[test]
    fn density_by_hand_one_dimension() {
        let p = Proposal::new(
            1,
            0.25,
            vec![Component {
                weight: 1.0,
                mean: vec![2.0],
                std: vec![0.5],
                rotations: vec![],
            }],
        )
        .unwrap();
        let z = 1.7;
        let n = |x: f64, m: f64, s: f64| {
            (-(x - m) * (x - m) / (2.0 * s * s)).exp() / (s * (2.0 * std::f64::consts::PI).sqrt())
        };
        let q = 0.25 * n(z, 0.0, 1.0) + 0.75 * n(z, 2.0, 0.5);
        assert!((p.log_density(&[z]) - q.ln()).abs() < 1e-12);
        assert!((p.log_weight(&[z]) - (n(z, 0.0, 1.0) / q).ln()).abs() < 1e-12);
    }

    #[test]
    fn single_component_fit_is_weighted_moments() {
        let zs = vec![vec![0.0, 1.0], vec![2.0, 1.0], vec![4.0, 1.0]];
        let w = [1.0, 2.0, 1.0];
        let f = Proposal::tuning_start(2, 1).fit(&zs, &w, 1.0).unwrap();
        let c = &f.components[0];
        assert!((c.mean[0] - 2.0).abs() < 1e-12);
        assert!((c.std[0] - 2.0f64.sqrt()).abs() < 1e-12); // (4 + 0 + 4)/4
        assert_eq!(c.std[1], MIN_STD);
        // smoothing α = 0.5 against N(0, 1)
        let g = Proposal::tuning_start(2, 1).fit(&zs, &w, 0.5).unwrap();
        assert!((g.components[0].mean[0] - 1.0).abs() < 1e-12);
        assert!((g.components[0].std[0] - (0.5 * 2.0f64.sqrt() + 0.5)).abs() < 1e-12);
        assert!(Proposal::nominal(2).fit(&zs, &[0.0; 3], 1.0).is_err());
        assert!(Proposal::nominal(2).fit(&zs, &w, 1.5).is_err());
    }

    #[test]
    fn em_separates_two_clusters() {
        let mut zs = Vec::new();
        for i in 0..400u64 {
            let mut r = sample_rng(1, 0, i);
            let sign = if i % 2 == 0 { 3.0 } else { -3.0 };
            let e: f64 = StandardNormal.sample(&mut r);
            zs.push(vec![sign + 0.2 * e, 0.0]);
        }
        let w = vec![1.0; zs.len()];
        let f = Proposal::tuning_start(2, 2).fit(&zs, &w, 1.0).unwrap();
        let mut means: Vec<f64> = f.components.iter().map(|c| c.mean[0]).collect();
        means.sort_by(f64::total_cmp);
        assert!((means[0] + 3.0).abs() < 0.1 && (means[1] - 3.0).abs() < 0.1);
        for c in &f.components {
            assert!((c.weight - 0.5).abs() < 0.05);
            assert!((c.std[0] - 0.2).abs() < 0.05);
        }
    }

    #[test]
    fn json_round_trip() {
        let p = Proposal::tuning_start(3, 2).with_defensive(0.1);
        let s = serde_json::to_string(&p).unwrap();
        assert_eq!(serde_json::from_str::<Proposal>(&s).unwrap(), p);
    }

    /// A trace-4 shape with eigenvalues (2.5, 0.9, 0.4, 0.2) on a non-axis-aligned basis.
    fn known_shape() -> Sym4 {
        let axes = [
            [0.5, -0.3, 0.7, 0.4],
            [0.3, 0.5, 0.4, -0.7],
            [-0.7, 0.4, 0.5, 0.3],
            [0.4, 0.7, -0.3, 0.5],
        ];
        let e = [2.5, 0.9, 0.4, 0.2];
        let mut a = [[0.0; 4]; 4];
        for (v, ev) in axes.iter().zip(e) {
            let n2: f64 = v.iter().map(|x| x * x).sum();
            for i in 0..4 {
                for j in 0..4 {
                    a[i][j] += ev * v[i] * v[j] / n2;
                }
            }
        }
        a
    }

    /// dim 6, block at 1 (z[1..5]), λ, one component with a non-nominal z[0], z[5] and the
    /// given Λ.
    fn block_proposal(lambda: f64, shape: Sym4) -> Proposal {
        let mut c = Component {
            weight: 1.0,
            mean: vec![0.7, 0.0, 0.0, 0.0, 0.0, -0.4],
            std: vec![0.8, 1.0, 1.0, 1.0, 1.0, 1.3],
            rotations: vec![],
        };
        c.rotations.push(RotationShape { start: 1, shape });
        Proposal::new(6, lambda, vec![c]).unwrap()
    }

    #[test]
    fn identity_shape_is_the_nominal_block() {
        let z = [0.3, -1.0, 2.0, 0.1, 0.5, -0.2];
        // Λ = I: the block adds exactly nothing to the plain component's density
        let with = block_proposal(0.0, acg::IDENTITY);
        let mut without = with.clone();
        without.components[0].rotations.clear();
        assert_eq!(with.log_density(&z), without.log_density(&z));
        // and the whole proposal from tuning_start with blocks is the nominal
        let p = Proposal::tuning_start(6, 2)
            .with_rotation_blocks(&[1])
            .unwrap();
        assert_eq!(p.rotation_blocks(), vec![1]);
        assert!(p.log_weight(&z).abs() < 1e-12);
        let p = Proposal::tuning_start(8, 1)
            .with_rotation_blocks(&[4, 0])
            .unwrap();
        assert_eq!(p.rotation_blocks(), vec![0, 4]);
        let z8 = [0.3, -1.0, 2.0, 0.1, 0.5, -0.2, 1.1, 0.0];
        assert!(p.log_weight(&z8).abs() < 1e-12);
    }

    #[test]
    fn block_density_by_hand_and_antipodal() {
        let shape = known_shape();
        let p = block_proposal(0.0, shape);
        let z = [0.3, -1.0, 2.0, 0.1, 0.5, -0.2];
        // the block's LR is 1/ACG(u; Λ) = |Λ|^{1/2} (uᵀΛ⁻¹u)², the rest the diagonal Gaussian's
        let l = acg::cholesky(&shape).unwrap();
        let b = &z[1..5];
        let r2: f64 = b.iter().map(|x| x * x).sum();
        let lr_block = 0.5 * acg::log_det(&l) + 2.0 * (acg::quad_inv(&l, b) / r2).ln();
        let c = &p.components[0];
        let n = |x: f64, m: f64, s: f64| -0.5 * ((x - m) / s).powi(2) - s.ln() - 0.5 * LN_2PI;
        let lr_rest = n(z[0], 0.0, 1.0) - n(z[0], c.mean[0], c.std[0]) + n(z[5], 0.0, 1.0)
            - n(z[5], c.mean[5], c.std[5]);
        assert!((p.log_weight(&z) - lr_block - lr_rest).abs() < 1e-12);
        // q(z) = q(z with z_B → −z_B), and with zero means q(z) = q(−z)
        let mut flipped = z;
        for x in &mut flipped[1..5] {
            *x = -*x;
        }
        assert!((p.log_density(&z) - p.log_density(&flipped)).abs() < 1e-12);
        let mut centred = p.clone();
        centred.components[0].mean = vec![0.0; 6];
        let minus = z.map(|x| -x);
        assert!((centred.log_density(&z) - centred.log_density(&minus)).abs() < 1e-12);
        // the radius of the block does not change the block's LR
        let mut scaled = z;
        for x in &mut scaled[1..5] {
            *x *= 3.0;
        }
        let nominal_shift = log_nominal(&scaled) - log_nominal(&z);
        assert!(
            (p.log_density(&scaled) - p.log_density(&z) - nominal_shift).abs() < 1e-12,
            "radius law must be the nominal's"
        );
    }

    #[test]
    fn block_weights_integrate_to_one_and_are_bounded() {
        // λ = 0: E_q[w] = 1 and E_q[w 1{A}] = P_nominal(A) only if q is normalised and its
        // sampler matches its density; the block's LR is ≤ |Λ|^{1/2}/λ_min².
        let shape = known_shape();
        let p = block_proposal(0.0, shape);
        let axis = [0.5f64, -0.3, 0.7, 0.4].map(|x| x / 0.99498743710662f64);
        let bound = {
            let (e, _) = acg::eigen(&shape);
            let det: f64 = e.iter().product();
            let min = e.iter().copied().fold(f64::INFINITY, f64::min);
            det.sqrt() / (min * min)
        };
        let n = 200_000u64;
        let (mut sum, mut sum2, mut cap, mut cap2) = (0.0, 0.0, 0.0, 0.0);
        let mut rest = p.clone();
        rest.components[0].rotations.clear();
        for i in 0..n {
            let z = p.sample(&mut sample_rng(11, 0, i));
            let w = p.log_weight(&z).exp();
            sum += w;
            sum2 += w * w;
            let b = &z[1..5];
            let r = b.iter().map(|x| x * x).sum::<f64>().sqrt();
            let dot: f64 = b.iter().zip(&axis).map(|(x, a)| x * a).sum::<f64>() / r;
            // |u·axis| ≥ cos 0.4: an antipodal cap
            if dot.abs() >= 0.4f64.cos() {
                cap += w;
                cap2 += w * w;
            }
            // block LR = total LR / the LR of the other dimensions
            let block_w = w / rest.log_weight(&z).exp();
            assert!(block_w <= bound * (1.0 + 1e-9), "{block_w} > {bound}");
        }
        let nf = n as f64;
        let mean = sum / nf;
        let se = ((sum2 / nf - mean * mean) / nf).sqrt();
        assert!((mean - 1.0).abs() < 4.0 * se, "E_q[w] = {mean} ± {se}");
        // uniform S³: P(|u·a| ≥ cos θ) = (2θ − sin 2θ)/π for the angle θ ≤ π/2
        let truth = (0.8 - 0.8f64.sin()) / std::f64::consts::PI;
        let m = cap / nf;
        let se = ((cap2 / nf - m * m) / nf).sqrt();
        assert!((m - truth).abs() < 4.0 * se, "cap {m} ± {se} vs {truth}");
    }

    #[test]
    fn fit_recovers_the_shape_from_its_own_samples() {
        let shape = known_shape();
        let p = block_proposal(0.0, shape);
        let zs: Vec<Vec<f64>> = (0..20_000u64)
            .map(|i| p.sample(&mut sample_rng(12, 0, i)))
            .collect();
        let w = vec![1.0; zs.len()];
        let mut fit = Proposal::tuning_start(6, 1)
            .with_rotation_blocks(&[1])
            .unwrap();
        // each fit runs TYLER_STEPS from the current Λ, as successive cross-entropy steps do
        for _ in 0..4 {
            fit = fit.fit(&zs, &w, 1.0).unwrap();
        }
        let got = &fit.components[0].rotations[0].shape;
        for i in 0..4 {
            for j in 0..4 {
                assert!(
                    (got[i][j] - shape[i][j]).abs() < 0.05,
                    "Λ[{i}][{j}] = {} vs {}",
                    got[i][j],
                    shape[i][j]
                );
            }
        }
        let c = &fit.components[0];
        assert!((c.mean[0] - 0.7).abs() < 0.03 && (c.std[5] - 1.3).abs() < 0.03);
        assert_eq!((c.mean[2], c.std[2]), (0.0, 1.0));
    }

    #[test]
    fn shape_floor_and_smoothing() {
        // all points on one axis: Tyler would collapse Λ to rank 1; the floor keeps λ_min
        let zs: Vec<Vec<f64>> = (1..50)
            .map(|i| {
                let s = if i % 2 == 0 { 1.0 } else { -1.0 };
                vec![0.0, s * i as f64, 0.0, 0.0, 0.0, 0.0]
            })
            .collect();
        let w = vec![1.0; zs.len()];
        let start = Proposal::tuning_start(6, 1)
            .with_rotation_blocks(&[1])
            .unwrap();
        let f = start.fit(&zs, &w, 1.0).unwrap();
        let (e, _) = acg::eigen(&f.components[0].rotations[0].shape);
        let tr: f64 = e.iter().sum();
        assert!((tr - 4.0).abs() < 1e-9);
        let min = e.iter().copied().fold(f64::INFINITY, f64::min);
        assert!((min - MIN_SHAPE_EIGENVALUE).abs() < 1e-9, "{e:?}");
        // α = 0.5 against I
        let g = start.fit(&zs, &w, 0.5).unwrap();
        let sg = &g.components[0].rotations[0].shape;
        let sf = &f.components[0].rotations[0].shape;
        for i in 0..4 {
            for j in 0..4 {
                let want = 0.5 * sf[i][j] + 0.5 * acg::IDENTITY[i][j];
                assert!((sg[i][j] - want).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn em_separates_two_orientations() {
        // two antipodally symmetric clusters of directions around axes a and b
        let a = [1.0, 0.0, 0.0, 0.0];
        let b = [0.0, 0.0, 0.6, 0.8];
        let mut zs = Vec::new();
        for i in 0..600u64 {
            let mut r = sample_rng(3, 0, i);
            let axis = if i % 3 == 0 { b } else { a };
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            let mut z = vec![0.0; 5];
            for j in 0..4 {
                let e: f64 = StandardNormal.sample(&mut r);
                z[j] = sign * axis[j] * 2.0 + 0.15 * e;
            }
            z[4] = StandardNormal.sample(&mut r);
            zs.push(z);
        }
        let w = vec![1.0; zs.len()];
        let f = Proposal::tuning_start(5, 2)
            .with_rotation_blocks(&[0])
            .unwrap()
            .fit(&zs, &w, 1.0)
            .unwrap();
        let mut found = Vec::new();
        for c in &f.components {
            let (e, v) = acg::eigen(&c.rotations[0].shape);
            let top = (0..4).max_by(|&i, &j| e[i].total_cmp(&e[j])).unwrap();
            let axis: [f64; 4] = std::array::from_fn(|k| v[k][top]);
            let on_a = axis.iter().zip(&a).map(|(x, y)| x * y).sum::<f64>().abs();
            let on_b = axis.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>().abs();
            found.push((on_a > 0.99, on_b > 0.99, c.weight));
        }
        found.sort_by(|x, y| x.2.total_cmp(&y.2));
        assert!(
            found[0].1 && (found[0].2 - 1.0 / 3.0).abs() < 0.05,
            "{found:?}"
        );
        assert!(
            found[1].0 && (found[1].2 - 2.0 / 3.0).abs() < 0.05,
            "{found:?}"
        );
    }

    #[test]
    fn rotation_blocks_are_checked_and_serialise() {
        let p = Proposal::tuning_start(6, 2);
        assert!(p.with_rotation_blocks(&[3]).is_err()); // 3..7 leaves dim 6
        assert!(
            Proposal::tuning_start(9, 1)
                .with_rotation_blocks(&[0, 2])
                .is_err()
        );
        let mut bad = p.with_rotation_blocks(&[0]).unwrap();
        bad.components[1].rotations[0].shape[0][0] = -1.0;
        assert!(Proposal::new(6, 0.0, bad.components.clone()).is_err());
        bad.components[1].rotations.clear();
        assert!(Proposal::new(6, 0.0, bad.components).is_err());
        // a JSON proposal without rotations (as before blocks existed) still parses, and one
        // with blocks round-trips
        let old = r#"{"dim":1,"defensive":0.1,"components":[{"weight":1,"mean":[0],"std":[1]}]}"#;
        assert!(serde_json::from_str::<Proposal>(old).is_ok());
        let q = block_proposal(0.1, known_shape());
        let s = serde_json::to_string(&q).unwrap();
        let back = serde_json::from_str::<Proposal>(&s).unwrap();
        // serde_json's default float parsing may differ from the printed value in the last bit
        let z = [0.3, -1.0, 2.0, 0.1, 0.5, -0.2];
        assert_eq!(back.rotation_blocks(), vec![1]);
        assert!((back.log_density(&z) - q.log_density(&z)).abs() < 1e-12);
        assert!(
            !serde_json::to_string(&Proposal::nominal(2))
                .unwrap()
                .contains("rotations")
        );
    }
}
