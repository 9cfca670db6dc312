//! Golden values for the binomial intervals and the plain Monte Carlo estimator (computed with
//! SciPy; see shared/research/rare-event-search.md §2.1).

use boxpose_search_stats::{
    CiMethod, EstimatorKind, ImportanceEstimate, WeightedSample, clopper_pearson, wilson,
};

fn assert_rel(actual: f64, expected: f64, what: &str) {
    let rel = if expected == 0.0 {
        actual.abs()
    } else {
        ((actual - expected) / expected).abs()
    };
    assert!(
        rel <= 1e-6,
        "{what}: {actual:e} vs {expected:e} (rel {rel:e})"
    );
}

#[test]
fn clopper_pearson_golden() {
    let cases = [
        (3, 20000, 3.093467e-05, 4.383005e-04),
        (5, 100, 1.643188e-02, 1.128349e-01),
        (0, 1000, 0.0, 3.682084e-03),
        (1, 1000, 2.531749e-05, 5.558924e-03),
        (0, 20000, 0.0, 1.844270e-04),
    ];
    for (k, n, lo, hi) in cases {
        let (l, h) = clopper_pearson(k, n, 0.95);
        assert_rel(l, lo, &format!("CP lower {k}/{n}"));
        assert_rel(h, hi, &format!("CP upper {k}/{n}"));
    }
    assert_eq!(clopper_pearson(10, 10, 0.95).1, 1.0);
}

#[test]
fn wilson_golden() {
    let cases = [
        (3, 20000, 5.101482e-05, 4.409636e-04),
        (1, 1000, 1.765464e-04, 5.642559e-03),
        (5, 100, 2.154368e-02, 1.117505e-01),
    ];
    for (k, n, lo, hi) in cases {
        let (l, h) = wilson(k, n, 0.95);
        assert_rel(l, lo, &format!("Wilson lower {k}/{n}"));
        assert_rel(h, hi, &format!("Wilson upper {k}/{n}"));
    }
    let (l, h) = wilson(0, 1000, 0.95);
    assert!(l.abs() < 1e-15);
    assert_rel(h, 3.826758e-03, "Wilson upper 0/1000");
}

fn mc(k: usize, n: usize, invalid: usize) -> Vec<WeightedSample> {
    (0..n + invalid)
        .map(|i| WeightedSample {
            log_weight: 0.0,
            valid: i < n,
            failed: i < k || i >= n, // invalid samples flagged failed must not count
            stratum: 0,
        })
        .collect()
}

#[test]
fn plain_monte_carlo_reports_clopper_pearson() {
    let e = ImportanceEstimate::compute(&mc(3, 20000, 0), &[1.0]).unwrap();
    assert_eq!(e.ci_method, CiMethod::ClopperPearson);
    assert_eq!(e.estimator, EstimatorKind::Unbiased);
    assert_rel(e.p_hat, 1.5e-4, "p_hat");
    let (l, h) = e.ci95.unwrap();
    assert_rel(l, 3.093467e-05, "lower");
    assert_rel(h, 4.383005e-04, "upper");
    assert_eq!((e.samples, e.valid, e.failures), (20000, 20000, 3));
    assert_rel(e.kish_ess, 20000.0, "kish");
    assert_rel(e.failure_ess, 3.0, "failure ess");
    assert_rel(e.max_weight_share, 1.0 / 3.0, "share");
    // binomial standard error √(p(1−p)/(n−1)) with the unbiased sample variance
    assert_rel(
        e.std_error,
        (1.5e-4f64 * (1.0 - 1.5e-4) / 19999.0).sqrt(),
        "se",
    );

    let e = ImportanceEstimate::compute(&mc(0, 1000, 0), &[1.0]).unwrap();
    assert_eq!(e.ci95.unwrap().0, 0.0);
    assert_rel(e.ci95.unwrap().1, 3.682084e-03, "upper 0/1000");
    assert_eq!(e.relative_error, None);
}

#[test]
fn monte_carlo_with_redrawn_samples_uses_valid_count() {
    // 5 failures in 100 valid samples, 37 invalid (redrawn) ones.
    let e = ImportanceEstimate::compute(&mc(5, 100, 37), &[1.0]).unwrap();
    assert_eq!(e.estimator, EstimatorKind::Ratio);
    assert_eq!(e.ci_method, CiMethod::ClopperPearson);
    assert_rel(e.p_hat, 0.05, "p_hat");
    let (l, h) = e.ci95.unwrap();
    assert_rel(l, 1.643188e-02, "lower");
    assert_rel(h, 1.128349e-01, "upper");
    assert_rel(e.p_valid, 100.0 / 137.0, "p_valid");
    assert_rel(e.p_fail_and_valid, 5.0 / 137.0, "joint");
    assert_eq!((e.samples, e.valid, e.failures), (137, 100, 5));
    // delta-method se of a plain ratio = √(r(1−r)/n_valid)
    assert_rel(e.std_error, (0.05 * 0.95 / 100.0f64).sqrt(), "se");
}

/// The search's estimator: the ratio form Σ w·1{fail} / Σ w even when every sample is valid
/// (the nominal's P(valid) is unknown when scenes can be rejected).
#[test]
fn forced_ratio_is_the_self_normalised_estimate() {
    use boxpose_search_stats::{EstimatorKind, ImportanceEstimate, WeightedSample};
    let weights = [0.5f64, 2.0, 1.5, 0.25];
    let failed = [true, false, true, false];
    let samples: Vec<WeightedSample> = weights
        .iter()
        .zip(failed)
        .map(|(w, f)| WeightedSample {
            log_weight: w.ln(),
            valid: true,
            failed: f,
            stratum: 0,
        })
        .collect();
    let ratio = ImportanceEstimate::compute_ratio(&samples, &[1.0]).unwrap();
    assert_eq!(ratio.estimator, EstimatorKind::Ratio);
    assert!((ratio.p_hat - 2.0 / 4.25).abs() < 1e-12, "{}", ratio.p_hat);
    let unbiased = ImportanceEstimate::compute(&samples, &[1.0]).unwrap();
    assert_eq!(unbiased.estimator, EstimatorKind::Unbiased);
    assert!(
        (unbiased.p_hat - 2.0 / 4.0).abs() < 1e-12,
        "{}",
        unbiased.p_hat
    );
}
