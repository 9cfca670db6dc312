//! Which dimensions of z a cross-entropy proposal should tilt, chosen from data.
//!
//! A proposal that moves every dimension of z pays for the ones the failure does not depend
//! on: each adds variance to the likelihood ratio and nothing to the hit rate. The first tuning
//! iteration draws from the nominal, and its elites are chosen by the score alone, so **if the
//! score does not depend on z_d, z_d is exactly N(0, 1) among the elites** (and a direction
//! block is exactly uniform on S³). Each dimension is therefore tested against its nominal on
//! the elites:
//!
//! - a scalar z_d: the mean (√n·z̄ ~ N(0, 1)) and the variance ((n − 1)s² ~ χ²(n − 1)), both
//!   two-sided, the smaller p-value doubled;
//! - an orientation block (four normals whose direction is a uniformly random rotation):
//!   Bingham's test of uniformity on the sphere, S = 12 n (tr T² − 1/4) ~ χ²(9) with
//!   T = (1/n) Σ u uᵀ over the unit directions u (Mardia & Jupp 2000, §10.7; it is invariant to
//!   u → −u, as a quaternion's rotation is).
//!
//! A dimension is tilted when its p-value is below α divided by the number of tests
//! (Bonferroni), so a search whose failures depend on none of them tilts none by chance with
//! probability at least 1 − α. Holding a dimension at its nominal never biases the
//! importance-sampling estimate (the weight is then exactly 1 along it); a missed dimension only
//! costs variance.

use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF};

use crate::ce::CeError;
use crate::proposal::{Proposal, ROTATION_BLOCK_DIM};
use crate::stats::normal_cdf;

/// One test: a scalar dimension (`len` 1) or an orientation block (`len` 4) starting at `start`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DimensionTest {
    /// The first dimension of z tested.
    pub start: usize,
    /// 1 for a scalar, 4 for an orientation block.
    pub len: usize,
    /// The p-value under "the failure does not depend on these dimensions".
    pub p_value: f64,
    /// Whether the proposal tilts these dimensions.
    pub tilted: bool,
}

/// The choice made from one batch of elites.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TiltChoice {
    /// Elites the tests were made on.
    pub elites: usize,
    /// The family-wise level α; each test is held to α / `tests.len()`.
    pub alpha: f64,
    /// One entry per scalar dimension and per orientation block, in z's order.
    pub tests: Vec<DimensionTest>,
}

impl TiltChoice {
    /// Per dimension of z: whether it is tilted. When no test passed, every dimension is (the
    /// failure's dependence did not show in one iteration; tilting all is cross-entropy's usual
    /// choice, and [`TiltChoice::is_empty`] says so).
    pub fn mask(&self, dim: usize) -> Vec<bool> {
        if self.is_empty() {
            return vec![true; dim];
        }
        let mut mask = vec![false; dim];
        for t in self.tests.iter().filter(|t| t.tilted) {
            mask[t.start..t.start + t.len].fill(true);
        }
        mask
    }

    /// The starts of the tilted orientation blocks (every block when no test passed).
    pub fn tilted_blocks(&self) -> Vec<usize> {
        let all = self.is_empty();
        self.tests
            .iter()
            .filter(|t| (all || t.tilted) && t.len == ROTATION_BLOCK_DIM)
            .map(|t| t.start)
            .collect()
    }

    /// Whether no dimension passed its test.
    pub fn is_empty(&self) -> bool {
        !self.tests.iter().any(|t| t.tilted)
    }
}

/// Tests every scalar dimension and orientation block of `elite_zs` (drawn from the nominal and
/// kept for their scores) against its nominal distribution at family-wise level `alpha`.
/// `rotation_blocks` are the starts of the four-dimensional orientation blocks.
pub fn choose_tilt(
    elite_zs: &[Vec<f64>],
    dim: usize,
    rotation_blocks: &[usize],
    alpha: f64,
) -> Result<TiltChoice, CeError> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(CeError::Config {
            key: "tilt_alpha",
            message: format!("{alpha} is not in (0, 1)"),
        });
    }
    let n = elite_zs.len();
    if n < 2 {
        return Err(CeError::Input(format!(
            "{n} elites: at least 2 are needed to choose the tilted dimensions"
        )));
    }
    if let Some(z) = elite_zs.iter().find(|z| z.len() != dim) {
        return Err(CeError::Input(format!(
            "an elite has {} dimensions, not {dim}",
            z.len()
        )));
    }
    let mut tests = Vec::new();
    let mut d = 0;
    while d < dim {
        if rotation_blocks.contains(&d) {
            if d + ROTATION_BLOCK_DIM > dim {
                return Err(CeError::Input(format!(
                    "the orientation block at {d} does not fit in {dim} dimensions"
                )));
            }
            let blocks: Vec<&[f64]> = elite_zs
                .iter()
                .map(|z| &z[d..d + ROTATION_BLOCK_DIM])
                .collect();
            tests.push(test(d, ROTATION_BLOCK_DIM, bingham_p_value(&blocks)));
            d += ROTATION_BLOCK_DIM;
        } else {
            let values: Vec<f64> = elite_zs.iter().map(|z| z[d]).collect();
            tests.push(test(d, 1, standard_normal_p_value(&values)));
            d += 1;
        }
    }
    let threshold = alpha / tests.len() as f64;
    for t in &mut tests {
        t.tilted = t.p_value < threshold;
    }
    Ok(TiltChoice {
        elites: n,
        alpha,
        tests,
    })
}

/// `proposal` with every dimension that `mask` does not tilt back at N(0, 1) in every component:
/// the proposal then factorises into the nominal on those dimensions, and the weights do not
/// depend on them at all.
pub fn hold_at_nominal(mut proposal: Proposal, mask: &[bool]) -> Proposal {
    for (d, &tilted) in mask.iter().enumerate() {
        if !tilted {
            for c in &mut proposal.components {
                c.mean[d] = 0.0;
                c.std[d] = 1.0;
            }
        }
    }
    proposal
}

fn test(start: usize, len: usize, p_value: f64) -> DimensionTest {
    DimensionTest {
        start,
        len,
        p_value,
        tilted: false,
    }
}

/// Two-sided p-value of "`x` is an i.i.d. N(0, 1) sample", from its mean and its variance
/// (the smaller of the two p-values, doubled).
fn standard_normal_p_value(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let p_mean = 2.0 * (1.0 - normal_cdf((mean * n.sqrt()).abs()));
    let sum_sq: f64 = x.iter().map(|v| (v - mean).powi(2)).sum();
    let chi = ChiSquared::new(n - 1.0).expect("n ≥ 2");
    let lower = chi.cdf(sum_sq);
    let p_var = 2.0 * lower.min(1.0 - lower);
    (2.0 * p_mean.min(p_var)).min(1.0)
}

/// Bingham's test that the directions of the four-vectors `blocks` are uniform on S³:
/// S = p(p + 2)/2 · n · (tr T² − 1/p) ~ χ²((p − 1)(p + 2)/2) with p = 4, T = (1/n) Σ u uᵀ.
fn bingham_p_value(blocks: &[&[f64]]) -> f64 {
    const P: usize = ROTATION_BLOCK_DIM;
    let mut t = [[0.0; P]; P];
    let mut n = 0usize;
    for b in blocks {
        let norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm == 0.0 || !norm.is_finite() {
            continue;
        }
        n += 1;
        for i in 0..P {
            for j in 0..P {
                t[i][j] += b[i] * b[j] / (norm * norm);
            }
        }
    }
    if n == 0 {
        return 1.0;
    }
    let trace_sq: f64 = t.iter().flatten().map(|v| (v / n as f64).powi(2)).sum();
    let p = P as f64;
    let statistic = p * (p + 2.0) / 2.0 * n as f64 * (trace_sq - 1.0 / p);
    let df = (p - 1.0) * (p + 2.0) / 2.0;
    1.0 - ChiSquared::new(df).expect("df > 0").cdf(statistic.max(0.0))
}

#[cfg(test)]
mod tests {
    use rand::Rng;
    use rand_distr::StandardNormal;

    use super::*;
    use crate::rng::sample_rng;

    fn nominal(n: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
        (0..n as u64)
            .map(|i| {
                let mut rng = sample_rng(seed, 0, i);
                (0..dim).map(|_| rng.sample(StandardNormal)).collect()
            })
            .collect()
    }

    #[test]
    fn nominal_elites_tilt_nothing_at_the_family_wise_rate() {
        // 200 independent nominal "elite" sets of 100 in 18 dimensions (14 scalars, one block):
        // at α = 0.05 at most about 5 % may tilt anything.
        let runs = 200;
        let chose = (0..runs)
            .filter(|&seed| {
                !choose_tilt(&nominal(100, 18, seed), 18, &[10], 0.05)
                    .unwrap()
                    .is_empty()
            })
            .count();
        assert!(
            chose <= 20,
            "{chose} of {runs} nominal sets tilted something"
        );
        let none = choose_tilt(&nominal(100, 18, 0), 18, &[10], 1e-9).unwrap();
        assert!(none.is_empty());
        assert_eq!(none.mask(18), vec![true; 18], "nothing chosen: tilt all");
        assert_eq!(none.tilted_blocks(), vec![10]);
    }

    #[test]
    fn a_shifted_scalar_a_narrowed_scalar_and_a_concentrated_block_are_found() {
        let mut zs = nominal(100, 18, 7);
        for z in &mut zs {
            z[2] += 1.0; // shifted mean
            z[5] *= 0.4; // narrowed
            // a block concentrated near ±(1, 0, 0, 0)
            z[11] *= 0.3;
            z[12] *= 0.3;
            z[13] *= 0.3;
        }
        let choice = choose_tilt(&zs, 18, &[10], 0.01).unwrap();
        let tilted: Vec<usize> = choice
            .tests
            .iter()
            .filter(|t| t.tilted)
            .map(|t| t.start)
            .collect();
        assert_eq!(tilted, vec![2, 5, 10]);
        assert_eq!(choice.tilted_blocks(), vec![10]);
        let mask = choice.mask(18);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 6);
        assert!(mask[13] && !mask[14] && !mask[3]);
    }

    #[test]
    fn bad_inputs_are_refused() {
        assert!(choose_tilt(&nominal(1, 3, 1), 3, &[], 0.05).is_err());
        assert!(choose_tilt(&nominal(10, 3, 1), 3, &[], 1.0).is_err());
        assert!(choose_tilt(&nominal(10, 3, 1), 3, &[1], 0.05).is_err());
        assert!(choose_tilt(&nominal(10, 3, 1), 4, &[], 0.05).is_err());
    }
}
