mod common;

use boxpose_geometry::size_fit::{SizeFitParams, fit_pose_and_size};
use boxpose_geometry::{BoxModel, GeometryError};
use common::*;
use nalgebra::{Point3, Vector3};
use proptest::prelude::*;

fn sorted(v: Vector3<f64>) -> [f64; 3] {
    let mut s = [v.x, v.y, v.z];
    s.sort_by(f64::total_cmp);
    s
}

/// Largest distance from a true corner to the nearest corner of the fitted box.
fn corner_mismatch(truth: &[Point3<f64>], fit: &boxpose_geometry::size_fit::SizedBoxFit) -> f64 {
    let fitted: Vec<_> = fit.model.corners().iter().map(|c| fit.pose * c).collect();
    truth
        .iter()
        .map(|t| {
            fitted
                .iter()
                .map(|f| (f - t).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// From the 8 noisy corners of a box of unknown size (any shape class, random sizes), the fit
    /// recovers the side lengths and puts a fitted corner at every true one.
    #[test]
    fn recovers_size_and_pose_from_noisy_corners(
        model in arb_model(),
        pose in arb_pose(),
        noise in 0.0f64..0.003,
        jitter in arb_unit_triples(),
        order in Just((0..8).collect::<Vec<usize>>()).prop_shuffle(),
    ) {
        let detected = detections(&model, &pose, noise, &jitter, &[], &[[0.0; 3]; 8]);
        let points: Vec<_> = order.iter().map(|&i| detected[i]).collect();
        let fit = fit_pose_and_size(&points, &SizeFitParams::default()).unwrap();
        let (got, want) = (sorted(fit.model.size()), sorted(model.size()));
        for axis in 0..3 {
            prop_assert!((got[axis] - want[axis]).abs() < 3.0 * noise + 1e-9, "size {:?} vs {:?}", got, want);
        }
        prop_assert!(corner_mismatch(&true_corners(&model, &pose), &fit) < 4.0 * noise + 1e-9);
    }

    /// With truncation, one outlier among the corners is rejected and the size still recovered.
    #[test]
    fn truncation_rejects_an_outlier(
        model in arb_model(),
        pose in arb_pose(),
        jitter in arb_unit_triples(),
        outlier in 0usize..8,
        offsets in arb_unit_triples(),
    ) {
        let noise = 0.002;
        let points = detections(&model, &pose, noise, &jitter, &[outlier], &offsets);
        let truth = true_corners(&model, &pose);
        let truncation = 0.25 * model.size().min();
        prop_assume!(truth.iter().all(|c| (points[outlier] - c).norm() > 3.0 * truncation));
        let fit = fit_pose_and_size(&points, &SizeFitParams { truncation, ..SizeFitParams::default() }).unwrap();
        prop_assert!(!fit.inliers[outlier]);
        prop_assert_eq!(fit.inliers.iter().filter(|&&b| b).count(), 7);
        let (got, want) = (sorted(fit.model.size()), sorted(model.size()));
        for axis in 0..3 {
            prop_assert!((got[axis] - want[axis]).abs() < 4.0 * noise, "size {:?} vs {:?}", got, want);
        }
    }
}

#[test]
fn a_missing_corner_still_determines_the_box() {
    let model = BoxModel::new(Vector3::new(0.4, 0.22, 0.1)).unwrap();
    let pose = nalgebra::Isometry3::new(Vector3::new(0.1, 0.0, 1.3), Vector3::new(1.0, 0.2, -0.6));
    let truth = true_corners(&model, &pose);
    let fit = fit_pose_and_size(&truth[1..], &SizeFitParams::default()).unwrap();
    assert!(corner_mismatch(&truth, &fit) < 1e-9);
    assert!(fit.inlier_rms < 1e-9);
}

#[test]
fn bad_inputs_are_errors() {
    let params = SizeFitParams::default();
    let corners = BoxModel::unit().corners();
    assert!(matches!(
        fit_pose_and_size(&corners[..3], &params),
        Err(GeometryError::TooFewPoints { .. })
    ));
    // The four corners of one face leave the third side undetermined.
    let face = [corners[0], corners[1], corners[2], corners[3]];
    assert_eq!(
        fit_pose_and_size(&face, &params),
        Err(GeometryError::Degenerate("coplanar points"))
    );
    let mut nan = corners.to_vec();
    nan[2].x = f64::INFINITY;
    assert!(matches!(
        fit_pose_and_size(&nan, &params),
        Err(GeometryError::NonFinite { .. })
    ));
    for truncation in [0.0, -1.0, f64::NAN] {
        let bad = SizeFitParams {
            truncation,
            ..params
        };
        assert!(matches!(
            fit_pose_and_size(&corners, &bad),
            Err(GeometryError::InvalidParameter { .. })
        ));
    }
}
