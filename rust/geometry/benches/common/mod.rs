//! Deterministic benchmark inputs, shared by the criterion bench and the NumPy comparison example:
//! boxes of random size and pose seen as 8 noisy corner peaks, a few of them outliers.

use boxpose_geometry::BoxModel;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub struct Scene {
    pub model: BoxModel,
    pub points: Vec<Point3<f64>>,
    pub scores: Vec<f64>,
}

/// `count` scenes from `seed`: sides 0.1–0.5 m, poses 0.8–2 m in front of the camera, 3 mm peak
/// noise, and among the 8 peaks between `outliers.start()` and `outliers.end()` outliers (uniform
/// within the box's diameter of its centre); scores are random, so outliers are as likely as
/// inliers to be among the 5 that the paper's search fits.
pub fn scenes(count: usize, seed: u64, outliers: std::ops::RangeInclusive<usize>) -> Vec<Scene> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let model = BoxModel::new(Vector3::from_fn(|_, _| rng.random_range(0.1..0.5))).unwrap();
            let truth = Isometry3::new(
                Vector3::new(
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(0.8..2.0),
                ),
                Vector3::from_fn(|_, _| rng.random_range(-3.0..3.0)),
            );
            let outliers = rng.random_range(outliers.clone());
            let points = model
                .corners()
                .iter()
                .enumerate()
                .map(|(i, corner)| {
                    let offset = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
                    if i < outliers {
                        Point3::from(truth.translation.vector + offset * 0.5 * model.diameter())
                    } else {
                        truth * corner + offset * 0.003
                    }
                })
                .collect();
            let scores = (0..8).map(|_| rng.random_range(0.2..1.0)).collect();
            Scene {
                model,
                points,
                scores,
            }
        })
        .collect()
}
