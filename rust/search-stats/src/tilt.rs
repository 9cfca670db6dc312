//! Which dimensions of z a cross-entropy proposal should tilt, chosen from data.
//!
//! A proposal that moves every dimension of z pays for the ones the failure does not depend
//! on: each adds variance to the likelihood ratio and nothing to the hit rate. The first tuning
//! iteration draws from the nominal, so each dimension can be tested for **any dependence of the
//! score on it**: if the score does not depend on z_d, the ranks of the scores are independent
//! of z_d. The test regresses the centred score ranks on features of the dimension and takes
//! n·R², which is χ²(k) under independence (the score test of a linear model; with ranks it
//! needs no assumption on the score's distribution):
//!
//! - a scalar z_d: k = 2 features, z_d and z_d² (a failure at one end, or at both);
//! - an orientation block (four normals whose direction u is a uniformly random rotation): the
//!   k = 9 free entries of u uᵀ (u_i u_j for i < j, u_i² for i < 3), which are invariant to
//!   u → −u, as a quaternion's rotation is, and which hold every smooth dependence on the
//!   rotation to first order.
//!
//! A dimension is tilted when its p-value is below α divided by the number of tests
//! (Bonferroni), so a search whose failures depend on none of them tilts none by chance with
//! probability at least 1 − α. Holding a dimension at its nominal never biases the
//! importance-sampling estimate (the weight is then exactly 1 along it); a missed dimension only
//! costs variance. Invalid samples (NaN scores) are left out.
//!
//! When no test passes, nothing is tilted: the next iteration draws from the nominal again and
//! the tests are repeated on every nominal sample so far, until a dependence shows or the tuning
//! iterations run out (then the final batch is plain Monte Carlo). Tilting every dimension
//! instead — cross-entropy's usual choice — is what degenerated on the real pipeline: five runs
//! on an event of p ≈ 4.5e-4 whose first 200 samples showed nothing all tilted all 18
//! dimensions, and three of their intervals missed the reference (docs/search.md). Each of the at
//! most `looks` repeated tests is held to α / `looks`, so the family-wise level over all of them
//! stays α.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF};

use crate::ce_error::CeError;
use crate::proposal::{Proposal, ROTATION_BLOCK_DIM};

/// The fewest valid samples [`choose_tilt`] tests on (χ² is a large-sample law).
pub const MIN_SAMPLES: usize = 20;

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

/// The choice made from the nominal samples drawn so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TiltChoice {
    /// Valid samples the tests were made on.
    pub samples: usize,
    /// The level this look was held to (the family-wise α over every look); each test is held
    /// to it divided by `tests.len()`.
    pub alpha: f64,
    /// One entry per scalar dimension and per orientation block, in z's order.
    pub tests: Vec<DimensionTest>,
    /// What a choice in which no test passed means: `true`, nothing is tilted and the choice is
    /// made again at the next iteration; `false` (a choice recorded before 2026-12-06, which
    /// reads without this field), every dimension is tilted — kept so that such a run resumes
    /// as it began.
    #[serde(default)]
    pub nothing_means_nominal: bool,
}

impl TiltChoice {
    /// Per dimension of z: whether it is tilted.
    pub fn mask(&self, dim: usize) -> Vec<bool> {
        if self.is_empty() {
            return vec![!self.nothing_means_nominal; dim];
        }
        let mut mask = vec![false; dim];
        for t in self.tests.iter().filter(|t| t.tilted) {
            mask[t.start..t.start + t.len].fill(true);
        }
        mask
    }

    /// The starts of the tilted orientation blocks.
    pub fn tilted_blocks(&self) -> Vec<usize> {
        let all = self.is_empty() && !self.nothing_means_nominal;
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

    /// Whether the choice is still to be made: nothing passed, so the proposal stayed at the
    /// nominal and the next iteration's samples join the tests.
    pub fn undecided(&self) -> bool {
        self.is_empty() && self.nothing_means_nominal
    }
}

/// Tests every scalar dimension and orientation block of z for a dependence of `scores` on it,
/// at family-wise level `alpha`: `zs` were drawn from the nominal and `scores[i]` is sample i's
/// score (NaN: invalid, left out). `rotation_blocks` are the starts of the four-dimensional
/// orientation blocks. A caller that tests again as samples arrive passes α / its most looks.
pub fn choose_tilt(
    zs: &[Vec<f64>],
    scores: &[f64],
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
    if zs.len() != scores.len() {
        return Err(CeError::Input(format!(
            "{} samples but {} scores",
            zs.len(),
            scores.len()
        )));
    }
    if let Some(z) = zs.iter().find(|z| z.len() != dim) {
        return Err(CeError::Input(format!(
            "a sample has {} dimensions, not {dim}",
            z.len()
        )));
    }
    let valid: Vec<usize> = (0..zs.len()).filter(|&i| !scores[i].is_nan()).collect();
    let n = valid.len();
    if n < MIN_SAMPLES {
        return Err(CeError::Input(format!(
            "{n} valid samples: at least {MIN_SAMPLES} are needed to choose the tilted dimensions"
        )));
    }
    let ranks = centred_ranks(&valid.iter().map(|&i| scores[i]).collect::<Vec<_>>());
    let mut tests = Vec::new();
    let mut d = 0;
    while d < dim {
        let (len, features): (usize, Vec<Vec<f64>>) = if rotation_blocks.contains(&d) {
            if d + ROTATION_BLOCK_DIM > dim {
                return Err(CeError::Input(format!(
                    "the orientation block at {d} does not fit in {dim} dimensions"
                )));
            }
            let features = valid
                .iter()
                .map(|&i| rotation_features(&zs[i][d..d + ROTATION_BLOCK_DIM]))
                .collect();
            (ROTATION_BLOCK_DIM, features)
        } else {
            (
                1,
                valid
                    .iter()
                    .map(|&i| vec![zs[i][d], zs[i][d] * zs[i][d]])
                    .collect(),
            )
        };
        tests.push(DimensionTest {
            start: d,
            len,
            p_value: rank_dependence_p_value(&ranks, &features),
            tilted: false,
        });
        d += len;
    }
    let threshold = alpha / tests.len() as f64;
    for t in &mut tests {
        t.tilted = t.p_value < threshold;
    }
    Ok(TiltChoice {
        samples: n,
        alpha,
        tests,
        nothing_means_nominal: true,
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

/// The ranks of `x` (ties share their mean rank), centred on zero.
fn centred_ranks(x: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..x.len()).collect();
    order.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut ranks = vec![0.0; x.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && x[order[j + 1]] == x[order[i]] {
            j += 1;
        }
        let mean_rank = 0.5 * (i + j) as f64;
        for &k in &order[i..=j] {
            ranks[k] = mean_rank;
        }
        i = j + 1;
    }
    let centre = (x.len() - 1) as f64 / 2.0;
    ranks.iter().map(|r| r - centre).collect()
}

/// The nine free entries of u uᵀ for the direction u of a four-vector (u_i u_j for i < j, and
/// u_i² for i < 3; u_3² = 1 − the rest).
fn rotation_features(block: &[f64]) -> Vec<f64> {
    let norm = block
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt()
        .max(f64::MIN_POSITIVE);
    let u: Vec<f64> = block.iter().map(|v| v / norm).collect();
    let mut f = Vec::with_capacity(9);
    for i in 0..ROTATION_BLOCK_DIM {
        for j in i + 1..ROTATION_BLOCK_DIM {
            f.push(u[i] * u[j]);
        }
    }
    f.extend((0..ROTATION_BLOCK_DIM - 1).map(|i| u[i] * u[i]));
    f
}

/// p-value of "the centred `ranks` do not depend on `features`" (one row per sample): n·R² of
/// the least-squares fit of the ranks on the centred features, against χ²(k).
fn rank_dependence_p_value(ranks: &[f64], features: &[Vec<f64>]) -> f64 {
    let (n, k) = (features.len(), features[0].len());
    let mut x = DMatrix::from_fn(n, k, |i, j| features[i][j]);
    for j in 0..k {
        let mean = x.column(j).mean();
        x.column_mut(j).add_scalar_mut(-mean);
    }
    let y = DVector::from_column_slice(ranks);
    let total = y.norm_squared();
    if total == 0.0 {
        // every score tied: the ranks hold no evidence (and 0/0 would be a NaN p-value, which
        // JSON stores as null and a resumed run could not read back)
        return 1.0;
    }
    let Some(chol) = (x.transpose() * &x).cholesky() else {
        return 1.0; // a constant feature: nothing to test
    };
    let xty = x.transpose() * &y;
    let explained = xty.dot(&chol.solve(&xty));
    let r_squared = (explained / total).clamp(0.0, 1.0);
    let chi = ChiSquared::new(k as f64).expect("k > 0");
    1.0 - chi.cdf(n as f64 * r_squared)
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
    fn a_score_that_depends_on_nothing_tilts_nothing_at_the_family_wise_rate() {
        // 200 independent sets of 300 samples in 18 dimensions (14 scalars, one block) with
        // scores independent of z: at α = 0.05 at most about 5 % may tilt anything.
        let runs = 200;
        let chose = (0..runs)
            .filter(|&seed| {
                let zs = nominal(300, 18, seed);
                let scores: Vec<f64> = nominal(300, 1, seed + 1000).concat();
                !choose_tilt(&zs, &scores, 18, &[10], 0.05)
                    .unwrap()
                    .is_empty()
            })
            .count();
        assert!(
            chose <= 20,
            "{chose} of {runs} independent sets tilted something"
        );
        let zs = nominal(300, 18, 0);
        let none = choose_tilt(&zs, &vec![1.0; 300], 18, &[10], 0.05).unwrap();
        assert!(none.is_empty(), "constant scores: nothing to tilt");
        assert!(
            none.tests.iter().all(|t| t.p_value == 1.0),
            "{:?}",
            none.tests
        );
        assert!(none.undecided());
        assert_eq!(
            none.mask(18),
            vec![false; 18],
            "nothing chosen: hold all at the nominal"
        );
        assert!(none.tilted_blocks().is_empty());
    }

    #[test]
    fn a_choice_recorded_before_nothing_meant_nominal_still_tilts_all() {
        // A plan written before 2026-12-06 has no `nothing_means_nominal`: its run drew its
        // second iteration from a proposal that tilted every dimension, and resumes so.
        let json = r#"{"samples": 200, "alpha": 0.01,
            "tests": [{"start": 0, "len": 4, "p_value": 0.3, "tilted": false},
                      {"start": 4, "len": 1, "p_value": 0.5, "tilted": false}]}"#;
        let legacy: TiltChoice = serde_json::from_str(json).unwrap();
        assert!(legacy.is_empty() && !legacy.undecided());
        assert_eq!(legacy.mask(5), vec![true; 5]);
        assert_eq!(legacy.tilted_blocks(), vec![0]);
    }

    #[test]
    fn a_monotone_a_two_sided_and_an_orientation_dependence_are_found() {
        let zs = nominal(1000, 18, 7);
        let q0 = [0.5, -0.5, 0.5, 0.5];
        let scores: Vec<f64> = zs
            .iter()
            .enumerate()
            .map(|(i, z)| {
                let norm = z[10..14].iter().map(|v| v * v).sum::<f64>().sqrt();
                let dot: f64 = (0..4).map(|j| q0[j] * z[10 + j]).sum::<f64>() / norm;
                let score = 0.5 * z[2] + 0.5 * z[5] * z[5] + dot * dot;
                if i % 50 == 0 { f64::NAN } else { score } // invalid samples are left out
            })
            .collect();
        let choice = choose_tilt(&zs, &scores, 18, &[10], 0.01).unwrap();
        assert_eq!(choice.samples, 980);
        let tilted: Vec<usize> = choice
            .tests
            .iter()
            .filter(|t| t.tilted)
            .map(|t| t.start)
            .collect();
        assert_eq!(tilted, vec![2, 5, 10], "{:?}", choice.tests);
        assert_eq!(choice.tilted_blocks(), vec![10]);
        let mask = choice.mask(18);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 6);
        assert!(mask[13] && !mask[14] && !mask[3]);
    }

    #[test]
    fn ranks_share_ties() {
        assert_eq!(
            centred_ranks(&[3.0, 1.0, 3.0, 2.0]),
            vec![1.0, -1.5, 1.0, -0.5]
        );
    }

    #[test]
    fn bad_inputs_are_refused() {
        let zs = nominal(30, 3, 1);
        let scores = vec![0.0; 30];
        assert!(choose_tilt(&zs[..10], &scores[..10], 3, &[], 0.05).is_err());
        assert!(choose_tilt(&zs, &scores, 3, &[], 1.0).is_err());
        assert!(choose_tilt(&zs, &scores, 3, &[1], 0.05).is_err());
        assert!(choose_tilt(&zs, &scores, 4, &[], 0.05).is_err());
        assert!(choose_tilt(&zs, &scores[1..], 3, &[], 0.05).is_err());
    }
}
