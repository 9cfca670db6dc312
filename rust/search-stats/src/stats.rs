//! Binomial intervals, the normal quantile and importance-sampling estimates of a failure
//! probability.

use serde::{Deserialize, Serialize};
use statrs::distribution::{Binomial, ContinuousCDF, DiscreteCDF, Normal};
use statrs::function::beta::inv_beta_reg;

/// Relative error above which [`ImportanceEstimate`] reports the log-scale Wald interval instead
/// of the plain Wald interval.
pub const LOG_WALD_RELATIVE_ERROR: f64 = 0.3;

fn standard_normal() -> Normal {
    Normal::new(0.0, 1.0).expect("N(0, 1) is a valid distribution")
}

/// The standard normal quantile Φ⁻¹(p): the x with P(Z ≤ x) = p for Z ~ N(0, 1).
///
/// Returns −∞ at p = 0, +∞ at p = 1 and NaN outside [0, 1].
pub fn normal_quantile(p: f64) -> f64 {
    if !(0.0..=1.0).contains(&p) {
        return f64::NAN;
    }
    standard_normal().inverse_cdf(p)
}

/// The standard normal distribution function Φ(x) = P(Z ≤ x) for Z ~ N(0, 1).
pub fn normal_cdf(x: f64) -> f64 {
    standard_normal().cdf(x)
}

fn check_binomial(k: u64, n: u64, confidence: f64) {
    assert!(k <= n, "binomial interval: k = {k} > n = {n}");
    assert!(
        confidence > 0.0 && confidence < 1.0,
        "binomial interval: confidence {confidence} not in (0, 1)"
    );
}

/// The exact (Clopper–Pearson) two-sided interval for a binomial proportion: `k` successes in
/// `n` trials at the given `confidence` (e.g. 0.95), central, α/2 = (1 − confidence)/2 per tail:
///
/// lower = Beta⁻¹(α/2; k, n − k + 1) (0 when k = 0),
/// upper = Beta⁻¹(1 − α/2; k + 1, n − k) (1 when k = n).
///
/// Coverage is at least `confidence` for every true proportion. With `n = 0` the interval is
/// [0, 1]. Panics if `k > n` or `confidence` is not in (0, 1).
pub fn clopper_pearson(k: u64, n: u64, confidence: f64) -> (f64, f64) {
    check_binomial(k, n, confidence);
    if n == 0 {
        return (0.0, 1.0);
    }
    let alpha = 1.0 - confidence;
    let (kf, nf) = (k as f64, n as f64);
    let lower = if k == 0 {
        0.0
    } else {
        inv_beta_reg(kf, nf - kf + 1.0, alpha / 2.0)
    };
    let upper = if k == n {
        1.0
    } else {
        inv_beta_reg(kf + 1.0, nf - kf, 1.0 - alpha / 2.0)
    };
    (lower, upper)
}

/// McNemar's exact test of paired binary outcomes (each sample failed or not, before and after a
/// change, on the same inputs): of the `fixed + new` discordant pairs (failed before only, failed
/// after only), the count `fixed` is Binomial(fixed + new, ½) when the change does nothing. The
/// two-sided p-value is
///
/// p = min(1, 2 · P(X ≤ min(fixed, new))), X ~ Binomial(fixed + new, ½),
///
/// and 1 without discordant pairs. The concordant pairs (failed both times, or neither) carry no
/// information about the difference and do not enter.
pub fn mcnemar_exact(fixed: u64, new: u64) -> f64 {
    let discordant = fixed + new;
    if discordant == 0 {
        return 1.0;
    }
    let binomial = Binomial::new(0.5, discordant).expect("p = ½ and n ≥ 1 are valid");
    (2.0 * binomial.cdf(fixed.min(new))).min(1.0)
}

/// The Wilson score interval for a binomial proportion p̂ = k/n at the given `confidence`, with
/// z = Φ⁻¹(1 − α/2):
///
/// centre = (p̂ + z²/(2n)) / (1 + z²/n),
/// half-width = z / (1 + z²/n) · √(p̂(1 − p̂)/n + z²/(4n²)).
///
/// With `n = 0` the interval is [0, 1]. Panics if `k > n` or `confidence` is not in (0, 1).
pub fn wilson(k: u64, n: u64, confidence: f64) -> (f64, f64) {
    check_binomial(k, n, confidence);
    if n == 0 {
        return (0.0, 1.0);
    }
    let z = normal_quantile(1.0 - (1.0 - confidence) / 2.0);
    let nf = n as f64;
    let p = k as f64 / nf;
    let denom = 1.0 + z * z / nf;
    let centre = (p + z * z / (2.0 * nf)) / denom;
    let half = z / denom * (p * (1.0 - p) / nf + z * z / (4.0 * nf * nf)).sqrt();
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// One evaluated sample, as [`ImportanceEstimate::compute`] consumes it.
///
/// `log_weight` = log p(z) − log q(z), the nominal over the density the sample was drawn from
/// (0 for plain Monte Carlo). `valid` is false for a sample whose scene was rejected (e.g. did
/// not settle) and redrawn; such samples must still be passed in, since they were drawn from q.
/// `failed` is only read for valid samples. `stratum` indexes the nominal stratum probabilities.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WeightedSample {
    /// log p(z) − log q(z).
    pub log_weight: f64,
    /// Whether the sample's scene was valid (not rejected and redrawn).
    pub valid: bool,
    /// Whether the system under test failed on it (ignored when `valid` is false).
    pub failed: bool,
    /// Index of the stratum (e.g. number of boxes) the sample was drawn in.
    pub stratum: usize,
}

/// Which estimator the headline [`ImportanceEstimate::p_hat`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorKind {
    /// Every sample was valid: p̂_s = (1/n_s) Σ w_i 1{fail_i}, unbiased for P(fail | s)
    /// (P(valid) is taken as 1).
    Unbiased,
    /// Some samples were invalid: p̂_s = Σ w_i 1{valid ∧ fail} / Σ w_i 1{valid}, the ratio
    /// estimator of P(fail | valid, s), with delta-method variance.
    Ratio,
    /// Subset simulation: the product of the levels' conditional probabilities
    /// ([`crate::splitting::SplittingEstimate`]), over the share of valid first-stage samples.
    Splitting,
}

/// Which 95 % interval [`ImportanceEstimate::ci95`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CiMethod {
    /// Plain Monte Carlo (every log weight 0, one stratum): Clopper–Pearson on (failures, valid
    /// samples).
    ClopperPearson,
    /// p̂ ± z·se, lower end clipped at 0; used when the relative error is ≤ 0.3.
    Wald,
    /// Wald on log p̂ with se(log p̂) = se/p̂ (delta method): [p̂ e^{−z·RE}, p̂ e^{z·RE}]; used when
    /// the relative error is > 0.3 ([`LOG_WALD_RELATIVE_ERROR`]).
    LogWald,
    /// No interval: importance sampling with no failure (p̂ = 0, se = 0) gives none.
    None,
    /// Subset simulation's log-normal interval from the larger of two coefficients of
    /// variation ([`crate::splitting::SplittingEstimate`]).
    LogNormal,
}

/// The estimate within one stratum.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StratumEstimate {
    /// Stratum index.
    pub stratum: usize,
    /// Its nominal probability P0(s).
    pub nominal_probability: f64,
    /// Samples drawn in it (valid or not).
    pub samples: u64,
    /// Valid samples in it.
    pub valid: u64,
    /// Valid failing samples in it.
    pub failures: u64,
    /// p̂_s, by the estimator named in [`ImportanceEstimate::estimator`].
    pub p_hat: f64,
    /// Its standard error.
    pub std_error: f64,
}

/// An importance-sampling estimate of the failure probability P(fail | valid), from samples
/// z_i ~ q with weights w_i = p(z_i)/q(z_i), I_i = 1{valid_i ∧ fail_i}, V_i = 1{valid_i}.
///
/// Within stratum s (n_s samples, all drawn from that stratum's proposal):
/// - unbiased (every sample valid): p̂_s = (1/n_s) Σ w_i I_i, Var = s²/n_s with s² the sample
///   variance (n_s − 1 denominator) of w_i I_i;
/// - ratio (some sample invalid): p̂_s = Σ w_i I_i / Σ w_i V_i, delta-method
///   Var = Σ (w_i I_i − p̂_s w_i V_i)² / (Σ w_i V_i)².
///
/// Strata are combined by post-stratification: p̂ = Σ_s P0(s) p̂_s, Var = Σ_s P0(s)² Var_s.
/// The 95 % interval is Clopper–Pearson for plain Monte Carlo, else Wald, or log-scale Wald when
/// the relative error se/p̂ exceeds 0.3 (see [`CiMethod`]).
///
/// Diagnostics pool all samples: Kish ESS = (Σ w)²/Σ w², failure ESS = (Σ w I)²/Σ (w I)²,
/// max weight share = max w I / Σ w I.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportanceEstimate {
    /// Which estimator `p_hat` is.
    pub estimator: EstimatorKind,
    /// The estimate of P(fail | valid).
    pub p_hat: f64,
    /// Its standard error.
    pub std_error: f64,
    /// se/p̂; `None` when p̂ = 0.
    pub relative_error: Option<f64>,
    /// The 95 % interval (see `ci_method`); `None` when there is none.
    pub ci95: Option<(f64, f64)>,
    /// How `ci95` was formed.
    pub ci_method: CiMethod,
    /// Samples drawn (valid or not).
    pub samples: u64,
    /// Valid samples.
    pub valid: u64,
    /// Valid failing samples (each sample counted once).
    pub failures: u64,
    /// Estimate of P(valid): Σ_s P0(s) Σ w_i V_i / Σ w_i, self-normalised (as the ratio
    /// estimator of P(fail | valid) is) so that it is a probability — 1 when every sample is
    /// valid, V/n for plain Monte Carlo — whereas the unbiased (1/n_s) Σ w_i V_i exceeds 1
    /// whenever the weights happen to average above 1.
    pub p_valid: f64,
    /// Its standard error (delta method).
    pub p_valid_std_error: f64,
    /// Unbiased estimate of P(fail ∧ valid) = Σ_s P0(s) (1/n_s) Σ w_i I_i.
    pub p_fail_and_valid: f64,
    /// Its standard error.
    pub p_fail_and_valid_std_error: f64,
    /// Kish effective sample size (Σ w)²/Σ w² over all samples.
    pub kish_ess: f64,
    /// Failure effective sample size (Σ w I)²/Σ (w I)² (0 with no failure).
    pub failure_ess: f64,
    /// Largest failing weight's share max w I / Σ w I (0 with no failure).
    pub max_weight_share: f64,
    /// Per-stratum estimates, in stratum order (left out of the JSON when a caller pooled them
    /// away: the search reports its strata on their own).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub strata: Vec<StratumEstimate>,
}

/// Why an [`ImportanceEstimate`] could not be formed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    /// No samples at all.
    #[error("no samples")]
    NoSamples,
    /// Stratum probabilities are negative, non-finite or do not sum to 1.
    #[error("stratum probabilities must be non-negative and sum to 1 (sum = {sum})")]
    BadStratumProbabilities {
        /// Their sum.
        sum: f64,
    },
    /// A sample names a stratum with no probability given.
    #[error(
        "sample {index} is in stratum {stratum}, but only {strata} stratum probabilities were given"
    )]
    UnknownStratum {
        /// Sample position.
        index: usize,
        /// Its stratum.
        stratum: usize,
        /// Number of strata.
        strata: usize,
    },
    /// A sample's log weight is NaN or +∞.
    #[error("sample {index} has log weight {log_weight}")]
    BadLogWeight {
        /// Sample position.
        index: usize,
        /// The offending log weight.
        log_weight: f64,
    },
    /// A stratum with positive nominal probability has no sample, or no valid sample.
    #[error("stratum {stratum} has positive probability but no valid sample with positive weight")]
    EmptyStratum {
        /// The stratum.
        stratum: usize,
    },
}

#[derive(Default, Clone, Copy)]
struct Sums {
    n: u64,
    valid: u64,
    failures: u64,
    a: f64,
    a2: f64,
    b: f64,
    b2: f64,
    /// Σ w and Σ w² over every sample, valid or not: P(valid)'s normaliser.
    w: f64,
    w2: f64,
}

fn ratio_ess(sum: f64, sum_sq: f64) -> f64 {
    if sum_sq > 0.0 {
        sum * sum / sum_sq
    } else {
        0.0
    }
}

impl ImportanceEstimate {
    /// Forms the estimate from evaluated samples and the nominal stratum probabilities P0(s)
    /// (`&[1.0]` when there is no stratification). See the type's documentation for the
    /// definitions.
    pub fn compute(
        samples: &[WeightedSample],
        stratum_probabilities: &[f64],
    ) -> Result<Self, EstimateError> {
        Self::compute_as(samples, stratum_probabilities, false)
    }

    /// [`compute`](Self::compute) with the ratio estimator of P(fail | valid) even when every
    /// sample happens to be valid: the estimate a search needs whenever a drawn scene *can* be
    /// invalid (the nominal's normaliser P(valid) is then unknown, and mean(w·1{fail}) would
    /// estimate P(fail ∧ valid) instead).
    pub fn compute_ratio(
        samples: &[WeightedSample],
        stratum_probabilities: &[f64],
    ) -> Result<Self, EstimateError> {
        Self::compute_as(samples, stratum_probabilities, true)
    }

    fn compute_as(
        samples: &[WeightedSample],
        stratum_probabilities: &[f64],
        force_ratio: bool,
    ) -> Result<Self, EstimateError> {
        if samples.is_empty() {
            return Err(EstimateError::NoSamples);
        }
        let sum: f64 = stratum_probabilities.iter().sum();
        if stratum_probabilities
            .iter()
            .any(|p| !p.is_finite() || *p < 0.0)
            || (sum - 1.0).abs() > 1e-9
        {
            return Err(EstimateError::BadStratumProbabilities { sum });
        }
        let strata = stratum_probabilities.len();
        let mut sums = vec![Sums::default(); strata];
        for (index, s) in samples.iter().enumerate() {
            if s.stratum >= strata {
                return Err(EstimateError::UnknownStratum {
                    index,
                    stratum: s.stratum,
                    strata,
                });
            }
            if s.log_weight.is_nan() || s.log_weight == f64::INFINITY {
                return Err(EstimateError::BadLogWeight {
                    index,
                    log_weight: s.log_weight,
                });
            }
        }
        let ratio = force_ratio || samples.iter().any(|s| !s.valid);
        let plain_mc = samples.iter().all(|s| s.log_weight == 0.0)
            && stratum_probabilities.iter().filter(|p| **p > 0.0).count() == 1;

        // Pooled diagnostics, scaled by the largest log weight so exp cannot overflow.
        let max_log = samples
            .iter()
            .map(|s| s.log_weight)
            .fold(f64::NEG_INFINITY, f64::max);
        let (mut sw, mut sw2, mut swi, mut swi2, mut max_wi) = (0.0, 0.0, 0.0, 0.0, 0.0f64);
        for s in samples {
            let w = (s.log_weight - max_log).exp();
            sw += w;
            sw2 += w * w;
            if s.valid && s.failed {
                swi += w;
                swi2 += w * w;
                max_wi = max_wi.max(w);
            }
        }

        for s in samples {
            let w = s.log_weight.exp();
            let t = &mut sums[s.stratum];
            t.n += 1;
            t.w += w;
            t.w2 += w * w;
            if s.valid {
                t.valid += 1;
                t.b += w;
                t.b2 += w * w;
                if s.failed {
                    t.failures += 1;
                    t.a += w;
                    t.a2 += w * w;
                }
            }
        }

        let mean_var = |sum: f64, sum_sq: f64, n: u64| -> (f64, f64) {
            let nf = n as f64;
            let mean = sum / nf;
            let var = if n > 1 {
                ((sum_sq - nf * mean * mean) / (nf - 1.0)).max(0.0) / nf
            } else {
                0.0
            };
            (mean, var)
        };

        let mut per_stratum = Vec::with_capacity(strata);
        let (mut p_hat, mut var) = (0.0, 0.0);
        let (mut p_joint, mut var_joint, mut p_valid, mut var_valid) = (0.0, 0.0, 0.0, 0.0);
        for (stratum, (t, &p0)) in sums.iter().zip(stratum_probabilities).enumerate() {
            if p0 > 0.0 && (t.valid == 0 || t.b <= 0.0) {
                return Err(EstimateError::EmptyStratum { stratum });
            }
            if t.n == 0 {
                per_stratum.push(StratumEstimate {
                    stratum,
                    nominal_probability: p0,
                    samples: 0,
                    valid: 0,
                    failures: 0,
                    p_hat: 0.0,
                    std_error: 0.0,
                });
                continue;
            }
            let (a_mean, a_var) = mean_var(t.a, t.a2, t.n);
            // P(valid) as the ratio Σ w V / Σ w, delta-method variance
            // Σ (w V − r w)² / (Σ w)² (valid samples' w·V = w, so Σ (w V)(w) = Σ (w V)²)
            let (valid_share, valid_share_var) = if t.w > 0.0 {
                let r = t.b / t.w;
                let num = (t.b2 - 2.0 * r * t.b2 + r * r * t.w2).max(0.0);
                (r, num / (t.w * t.w))
            } else {
                (0.0, 0.0)
            };
            // Failing samples are valid, so Σ a·b = Σ a².
            let (ps, vs) = if ratio {
                if t.b > 0.0 {
                    let r = t.a / t.b;
                    let num = (t.a2 - 2.0 * r * t.a2 + r * r * t.b2).max(0.0);
                    (r, num / (t.b * t.b))
                } else {
                    (0.0, 0.0)
                }
            } else {
                (a_mean, a_var)
            };
            p_hat += p0 * ps;
            var += p0 * p0 * vs;
            p_joint += p0 * a_mean;
            var_joint += p0 * p0 * a_var;
            p_valid += p0 * valid_share;
            var_valid += p0 * p0 * valid_share_var;
            per_stratum.push(StratumEstimate {
                stratum,
                nominal_probability: p0,
                samples: t.n,
                valid: t.valid,
                failures: t.failures,
                p_hat: ps,
                std_error: vs.sqrt(),
            });
        }

        let n_valid: u64 = sums.iter().map(|t| t.valid).sum();
        let failures: u64 = sums.iter().map(|t| t.failures).sum();
        let std_error = var.sqrt();
        let relative_error = (p_hat > 0.0).then(|| std_error / p_hat);
        let z = normal_quantile(0.975);
        let (ci95, ci_method) = if plain_mc {
            (
                Some(clopper_pearson(failures, n_valid, 0.95)),
                CiMethod::ClopperPearson,
            )
        } else {
            match relative_error {
                None => (None, CiMethod::None),
                Some(re) if re <= LOG_WALD_RELATIVE_ERROR => (
                    Some(((p_hat - z * std_error).max(0.0), p_hat + z * std_error)),
                    CiMethod::Wald,
                ),
                Some(re) => (
                    Some((p_hat * (-z * re).exp(), p_hat * (z * re).exp())),
                    CiMethod::LogWald,
                ),
            }
        };

        Ok(Self {
            estimator: if ratio {
                EstimatorKind::Ratio
            } else {
                EstimatorKind::Unbiased
            },
            p_hat,
            std_error,
            relative_error,
            ci95,
            ci_method,
            samples: samples.len() as u64,
            valid: n_valid,
            failures,
            p_valid,
            p_valid_std_error: var_valid.sqrt(),
            p_fail_and_valid: p_joint,
            p_fail_and_valid_std_error: var_joint.sqrt(),
            kish_ess: ratio_ess(sw, sw2),
            failure_ess: ratio_ess(swi, swi2),
            max_weight_share: if swi > 0.0 { max_wi / swi } else { 0.0 },
            strata: per_stratum,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mcnemar_exact_matches_the_binomial_tail_and_is_symmetric() {
        // 10 fixed, none new: 2 · (½)¹⁰.
        assert!((mcnemar_exact(10, 0) - 2.0 / 1024.0).abs() < 1e-12);
        assert_eq!(mcnemar_exact(7, 3), mcnemar_exact(3, 7));
        assert_eq!(mcnemar_exact(5, 5), 1.0);
        assert_eq!(mcnemar_exact(0, 0), 1.0);
        // 8 against 2: 2 · (1 + 10 + 45)/1024 (scipy.stats.binomtest(2, 10).pvalue).
        assert!((mcnemar_exact(8, 2) - 112.0 / 1024.0).abs() < 1e-12);
        assert!(mcnemar_exact(40, 10) < 1e-4);
    }

    fn close(actual: f64, expected: f64, rel: f64) -> bool {
        (actual - expected).abs() <= rel * expected.abs()
    }

    #[test]
    fn normal_quantile_golden() {
        assert!(close(normal_quantile(0.975), 1.959963984540054, 1e-12));
        assert!(close(normal_quantile(1e-4), -3.719016485455709, 1e-10));
        assert!(close(normal_quantile(0.999), 3.090232306167813, 1e-10));
        assert_eq!(normal_quantile(0.5), 0.0);
        assert!(normal_quantile(1.5).is_nan());
        assert!(close(normal_cdf(normal_quantile(0.3)), 0.3, 1e-12));
    }

    #[test]
    fn unbiased_weighted_by_hand() {
        // w = 2, 0.5, 1, 1; failures on the first two.
        let s = |w: f64, failed| WeightedSample {
            log_weight: w.ln(),
            valid: true,
            failed,
            stratum: 0,
        };
        let samples = [s(2.0, true), s(0.5, true), s(1.0, false), s(1.0, false)];
        let e = ImportanceEstimate::compute(&samples, &[1.0]).unwrap();
        assert_eq!(e.estimator, EstimatorKind::Unbiased);
        assert!(close(e.p_hat, 2.5 / 4.0, 1e-12));
        // sample variance of (2, 0.5, 0, 0) around 0.625, /(n−1), /n
        let v = ((2.0f64 - 0.625).powi(2) + (0.5f64 - 0.625).powi(2) + 2.0 * 0.625f64.powi(2))
            / 3.0
            / 4.0;
        assert!(close(e.std_error, v.sqrt(), 1e-12));
        assert!(close(e.kish_ess, 4.5 * 4.5 / 6.25, 1e-12));
        assert!(close(e.failure_ess, 2.5 * 2.5 / 4.25, 1e-12));
        assert!(close(e.max_weight_share, 0.8, 1e-12));
        assert_ne!(e.ci_method, CiMethod::ClopperPearson);
    }

    /// Every sample valid: P(valid) is 1 whatever the weights average (they average 1 only in
    /// expectation; their mean was once reported as P(valid), e.g. 1.07).
    #[test]
    fn p_valid_is_one_when_every_sample_is_valid() {
        let samples: Vec<WeightedSample> = [1.5f64, 0.9, 1.2, 0.7]
            .iter()
            .map(|w| WeightedSample {
                log_weight: w.ln(),
                valid: true,
                failed: false,
                stratum: 0,
            })
            .collect();
        let e = ImportanceEstimate::compute_ratio(&samples, &[1.0]).unwrap();
        assert_eq!(e.p_valid, 1.0);
        assert_eq!(e.p_valid_std_error, 0.0);
    }

    #[test]
    fn ratio_by_hand() {
        let s = |w: f64, valid, failed| WeightedSample {
            log_weight: w.ln(),
            valid,
            failed,
            stratum: 0,
        };
        let samples = [
            s(2.0, true, true),
            s(1.0, true, false),
            s(1.0, false, true), // invalid: its failure flag is ignored
            s(1.0, true, false),
        ];
        let e = ImportanceEstimate::compute(&samples, &[1.0]).unwrap();
        assert_eq!(e.estimator, EstimatorKind::Ratio);
        let r = 2.0 / 4.0;
        assert!(close(e.p_hat, r, 1e-12));
        let num = (2.0f64 - r * 2.0).powi(2) + 2.0 * (0.0f64 - r).powi(2);
        assert!(close(e.std_error, (num / 16.0).sqrt(), 1e-12));
        // Σ w V / Σ w: the invalid sample's weight 1 of 5
        assert!(close(e.p_valid, 4.0 / 5.0, 1e-12));
        assert!(close(e.p_fail_and_valid, 0.5, 1e-12));
        assert_eq!((e.samples, e.valid, e.failures), (4, 3, 1));
    }

    #[test]
    fn stratified_combination() {
        let mut samples = Vec::new();
        // stratum 0: 1 failure in 10; stratum 1: 5 in 10
        for i in 0..10 {
            samples.push(WeightedSample {
                log_weight: 0.0,
                valid: true,
                failed: i == 0,
                stratum: 0,
            });
            samples.push(WeightedSample {
                log_weight: 0.0,
                valid: true,
                failed: i < 5,
                stratum: 1,
            });
        }
        let e = ImportanceEstimate::compute(&samples, &[0.8, 0.2]).unwrap();
        assert!(close(e.p_hat, 0.8 * 0.1 + 0.2 * 0.5, 1e-12));
        let v0: f64 = 0.1 * 0.9 * 10.0 / 9.0 / 10.0;
        let v1: f64 = 0.5 * 0.5 * 10.0 / 9.0 / 10.0;
        assert!(close(e.std_error, (0.64 * v0 + 0.04 * v1).sqrt(), 1e-12));
        assert_ne!(e.ci_method, CiMethod::ClopperPearson);
        assert_eq!(e.strata.len(), 2);
        assert!(matches!(
            ImportanceEstimate::compute(&samples, &[0.5, 0.4]),
            Err(EstimateError::BadStratumProbabilities { .. })
        ));
        assert!(matches!(
            ImportanceEstimate::compute(&samples, &[1.0]),
            Err(EstimateError::UnknownStratum { .. })
        ));
        assert!(matches!(
            ImportanceEstimate::compute(&samples[..1], &[0.5, 0.5]),
            Err(EstimateError::EmptyStratum { stratum: 1 })
        ));
    }

    #[test]
    fn serializes() {
        let samples = [WeightedSample {
            log_weight: -1.0,
            valid: true,
            failed: false,
            stratum: 0,
        }];
        let e = ImportanceEstimate::compute(&samples, &[1.0]).unwrap();
        let json = serde_json::to_string(&e).unwrap();
        let back: ImportanceEstimate = serde_json::from_str(&json).unwrap();
        assert_eq!(back, e);
        assert_eq!(e.ci_method, CiMethod::None);
    }
}
