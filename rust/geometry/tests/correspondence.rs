mod common;

use boxpose_geometry::correspondence::{fast_exact_search, paper_exact_search};
use boxpose_geometry::{BoxModel, GeometryError};
use common::*;
use nalgebra::{Point3, Vector3};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// The branch and bound finds the brute force's minimum on every kind of input: all shape
    /// classes, random poses, noise from none to a third of the box, 0–4 outliers, shuffled scores.
    #[test]
    fn fast_search_finds_the_paper_minimum(
        model in arb_model(),
        pose in arb_pose(),
        noise_level in prop::sample::select(vec![0.0, 0.002, 0.02, 0.08]),
        jitter in arb_unit_triples(),
        outliers in arb_outlier_corners(),
        outlier_offsets in arb_unit_triples(),
        scores in prop::array::uniform8(0.0f64..1.0),
        m in prop::sample::select(vec![3usize, 4, 5, 5, 5]),
    ) {
        let points = detections(&model, &pose, noise_level, &jitter, &outliers, &outlier_offsets);
        let reference = paper_exact_search(&model, &points, &scores, m);
        let fast = fast_exact_search(&model, &points, &scores, m);
        match (reference, fast) {
            (Ok(reference), Ok(fast)) => {
                let tolerance = 1e-9 * reference.sum_squared_error + 1e-12 * model.diameter().powi(2);
                prop_assert!(
                    (reference.sum_squared_error - fast.sum_squared_error).abs() <= tolerance,
                    "paper {} vs fast {}", reference.sum_squared_error, fast.sum_squared_error
                );
                prop_assert_eq!(&reference.peaks, &fast.peaks);
                // The fast result is self-consistent: its pose reproduces its error.
                let corners = model.corners();
                let sse: f64 = fast.peaks.iter().zip(&fast.corners)
                    .map(|(&p, &c)| (fast.pose * corners[c] - points[p]).norm_squared()).sum();
                prop_assert!((sse - fast.sum_squared_error).abs() <= tolerance);
            }
            (Err(a), Err(b)) => prop_assert_eq!(a, b),
            (a, b) => prop_assert!(false, "paper {:?} vs fast {:?}", a.map(|f| f.sum_squared_error), b.map(|f| f.sum_squared_error)),
        }
    }
}

#[test]
fn exact_corners_give_zero_error_and_the_true_pose_up_to_symmetry() {
    let model = BoxModel::new(Vector3::new(0.3, 0.2, 0.1)).unwrap();
    let pose = nalgebra::Isometry3::new(Vector3::new(0.1, -0.2, 1.2), Vector3::new(0.4, -1.1, 0.7));
    let points = true_corners(&model, &pose);
    let scores: Vec<f64> = (0..8).map(|i| 1.0 - 0.1 * i as f64).collect();
    for search in [paper_exact_search, fast_exact_search] {
        let fit = search(&model, &points, &scores, 5).unwrap();
        assert!(fit.sum_squared_error < 1e-20);
        assert_eq!(fit.peaks, vec![0, 1, 2, 3, 4]);
        // The pose may differ from the truth by a box symmetry, but it maps the corner set onto
        // itself.
        for corner in model.corners() {
            let image = fit.pose * corner;
            assert!(points.iter().any(|p| (p - image).norm() < 1e-9));
        }
    }
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let model = BoxModel::unit();
    let good: Vec<Point3<f64>> = model.corners().to_vec();
    let scores = [1.0; 8];
    for search in [paper_exact_search, fast_exact_search] {
        assert!(matches!(
            search(&model, &good[..4], &scores[..4], 5),
            Err(GeometryError::TooFewPoints { .. })
        ));
        assert!(matches!(
            search(&model, &good, &scores[..7], 5),
            Err(GeometryError::ShapeMismatch { .. })
        ));
        assert!(matches!(
            search(&model, &good, &scores, 2),
            Err(GeometryError::InvalidParameter { .. })
        ));
        assert!(matches!(
            search(&model, &good, &scores, 9),
            Err(GeometryError::InvalidParameter { .. })
        ));
        let mut nan = good.clone();
        nan[3].x = f64::NAN;
        assert!(matches!(
            search(&model, &nan, &scores, 5),
            Err(GeometryError::NonFinite { .. })
        ));
        let mut bad_scores = scores;
        bad_scores[0] = f64::INFINITY;
        assert!(matches!(
            search(&model, &good, &bad_scores, 5),
            Err(GeometryError::NonFinite { .. })
        ));
        let line: Vec<_> = (0..8)
            .map(|i| Point3::new(0.0, 0.0, 1.0 + i as f64))
            .collect();
        assert_eq!(
            search(&model, &line, &scores, 5),
            Err(GeometryError::Degenerate("collinear points"))
        );
        let same = vec![Point3::new(0.0, 0.0, 1.0); 8];
        assert_eq!(
            search(&model, &same, &scores, 5),
            Err(GeometryError::Degenerate("coincident points"))
        );
    }
}
