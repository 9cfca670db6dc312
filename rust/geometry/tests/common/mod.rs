//! Scene generation shared by the integration tests: boxes of the three shape classes, random
//! poses, noisy corner detections with outliers.
#![allow(dead_code)] // each test binary uses its own subset of these helpers

use boxpose_geometry::BoxModel;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

/// Side lengths for one of the shape classes: 0 generic, 1 square-faced, 2 cube, 3 random.
pub fn box_size(class: u8, a: f64, b: f64, c: f64) -> Vector3<f64> {
    match class {
        0 => Vector3::new(0.30, 0.20, 0.12),
        1 => Vector3::new(0.15, 0.25, 0.25),
        2 => Vector3::repeat(0.2),
        _ => Vector3::new(a, b, c),
    }
}

pub fn arb_model() -> impl Strategy<Value = BoxModel> {
    (0u8..4, 0.05f64..0.6, 0.05f64..0.6, 0.05f64..0.6)
        .prop_map(|(class, a, b, c)| BoxModel::new(box_size(class, a, b, c)).unwrap())
}

/// A uniformly random rotation (from a normalised 4D Gaussian-ish sample) and a translation in
/// front of the camera.
pub fn arb_pose() -> impl Strategy<Value = Isometry3<f64>> {
    (
        prop::array::uniform4(-1.0f64..1.0),
        -0.5f64..0.5,
        -0.5f64..0.5,
        0.8f64..2.5,
    )
        .prop_filter("quaternion must not vanish", |(q, ..)| {
            q.iter().map(|x| x * x).sum::<f64>() > 1e-3
        })
        .prop_map(|(q, x, y, z)| {
            let rotation =
                UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
            Isometry3::from_parts(Translation3::new(x, y, z), rotation)
        })
}

/// The 8 true corners in the camera frame.
pub fn true_corners(model: &BoxModel, pose: &Isometry3<f64>) -> Vec<Point3<f64>> {
    model.corners().iter().map(|c| pose * c).collect()
}

/// Detections: the true corners, each displaced by `noise` (in metres, per coordinate, from the
/// unit-interval samples in `jitter`), with the corners listed in `outlier_corners` replaced by
/// points drawn around the box centre within its diameter.
pub fn detections(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    noise: f64,
    jitter: &[[f64; 3]; 8],
    outlier_corners: &[usize],
    outlier_offsets: &[[f64; 3]; 8],
) -> Vec<Point3<f64>> {
    let centre = pose.translation.vector;
    true_corners(model, pose)
        .into_iter()
        .enumerate()
        .map(|(i, corner)| {
            if outlier_corners.contains(&i) {
                Point3::from(centre + Vector3::from(outlier_offsets[i]) * model.diameter())
            } else {
                corner + Vector3::from(jitter[i]) * noise
            }
        })
        .collect()
}

/// Up to four distinct corner indices, in increasing order.
pub fn arb_outlier_corners() -> impl Strategy<Value = Vec<usize>> {
    prop::sample::subsequence((0..8).collect::<Vec<usize>>(), 0..=4)
}

pub fn arb_unit_triples() -> impl Strategy<Value = [[f64; 3]; 8]> {
    prop::array::uniform8(prop::array::uniform3(-1.0f64..1.0))
}
