//! Steps 6–7 together, the way every evaluation runs them: from back-projected peaks to each pose
//! fit and its scores against the true pose. One place, so `eval-geometry` (perfect heatmaps)
//! and `eval` (the network's heatmaps) score identically.

use std::time::Instant;

use nalgebra::{Isometry3, Matrix3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::correspondence::{fast_exact_search, paper_exact_search};
use crate::box_model::{CORNER_COUNT, corner_signs};
use crate::{BoxModel, metrics, robust, size_fit};

/// Peaks the paper's search fits (m).
const PAPER_M: usize = 5;

/// The pose fits compared; all but `SizeAndPose` know the box's size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The paper's exhaustive correspondence search over the m best peaks.
    PaperExact,
    /// The same optimum by branch and bound.
    FastExact,
    /// Hypothesize-and-verify with truncated least squares: survives outlier peaks.
    Robust,
    /// Pose and box size together, for a box of unknown size.
    SizeAndPose,
}

impl Method {
    pub const ALL: [Method; 4] = [Method::PaperExact, Method::FastExact, Method::Robust, Method::SizeAndPose];

    pub fn name(self) -> &'static str {
        match self {
            Method::PaperExact => "paper_exact",
            Method::FastExact => "fast_exact",
            Method::Robust => "robust",
            Method::SizeAndPose => "size_and_pose",
        }
    }
}

/// A pose as the dataset stores it: a unit quaternion (w, x, y, z) and a translation in metres.
pub fn isometry(quat_wxyz: [f64; 4], translation: [f64; 3]) -> Isometry3<f64> {
    let [w, x, y, z] = quat_wxyz;
    Isometry3::from_parts(Translation3::from(Vector3::from(translation)), UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)))
}

/// How far one fit is from the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scores {
    /// [`metrics::paper_error`] of the fitted corners against the true ones.
    pub paper_error: f64,
    pub mssd_m: f64,
    pub add_s_m: f64,
    pub rotation_error_deg: f64,
    pub translation_error_m: f64,
    pub fit_time_us: f64,
}

/// Runs every [`Method`] on `points` (with NMS `scores`, best first) and scores each against the
/// true pose of `model`; a fit that fails gives its error message instead of scores.
///
/// The size-known fits are scored with the true model. The size-and-pose fit is scored as the
/// box it fitted: its MSSD and ADD-S compare its own corners with the true ones, so a wrong size
/// counts, and its rotation is taken in the axis labels that best match the true corners.
pub fn fit_and_score(
    model: &BoxModel,
    truth: &Isometry3<f64>,
    points: &[Point3<f64>],
    scores: &[f64],
) -> Vec<(Method, Result<Scores, String>)> {
    let truth_corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth * c).collect();
    let text = |e: crate::GeometryError| e.to_string();
    let known_size = |pose: &Isometry3<f64>, start: Instant| -> Result<Scores, String> {
        let fit_time_us = start.elapsed().as_secs_f64() * 1e6;
        Ok(Scores {
            paper_error: metrics::paper_error(model, pose, &truth_corners).map_err(text)?,
            mssd_m: metrics::mssd(model, pose, truth).map_err(text)?,
            add_s_m: metrics::add_s(model, pose, truth).map_err(text)?,
            rotation_error_deg: metrics::rotation_error_deg(model, pose, truth).map_err(text)?,
            translation_error_m: metrics::translation_error(pose, truth).map_err(text)?,
            fit_time_us,
        })
    };
    let unknown_size = |fitted: &BoxModel, pose: &Isometry3<f64>, start: Instant| -> Result<Scores, String> {
        let fit_time_us = start.elapsed().as_secs_f64() * 1e6;
        let (relabelled, corners, mssd_m) = closest_labelling(fitted, pose, &truth_corners);
        let add_s_m = corners
            .iter()
            .map(|c| truth_corners.iter().map(|t| (c - t).norm()).fold(f64::INFINITY, f64::min))
            .sum::<f64>()
            / corners.len() as f64;
        Ok(Scores {
            paper_error: metrics::paper_error(fitted, pose, &truth_corners).map_err(text)?,
            mssd_m,
            add_s_m,
            rotation_error_deg: metrics::rotation_error_deg(model, &relabelled, truth).map_err(text)?,
            translation_error_m: metrics::translation_error(pose, truth).map_err(text)?,
            fit_time_us,
        })
    };
    Method::ALL
        .into_iter()
        .map(|method| {
            let start = Instant::now();
            let outcome = match method {
                Method::PaperExact => {
                    paper_exact_search(model, points, scores, PAPER_M).map_err(text).and_then(|f| known_size(&f.pose, start))
                }
                Method::FastExact => {
                    fast_exact_search(model, points, scores, PAPER_M).map_err(text).and_then(|f| known_size(&f.pose, start))
                }
                Method::Robust => robust::robust_fit(model, points, &robust::RobustParams::for_box(model))
                    .map_err(text)
                    .and_then(|f| known_size(&f.pose, start)),
                Method::SizeAndPose => size_fit::fit_pose_and_size(points, &size_fit::SizeFitParams::default())
                    .map_err(text)
                    .and_then(|f| unknown_size(&f.model, &f.pose, start)),
            };
            (method, outcome)
        })
        .collect()
}

/// A box fitted without knowing its size has no preferred axis labels: the size fit may call the
/// true x axis its z. Each of the 24 proper signed axis relabellings of the fitted box names the
/// same 8 corners in another order. Returns the relabelled pose whose corners, in the model's
/// corner order, are closest to `truth_corners` — the smallest largest distance, which is the
/// MSSD of the fitted box (the relabellings include the box's symmetries) — with those corners
/// and that distance.
fn closest_labelling(
    fitted: &BoxModel,
    pose: &Isometry3<f64>,
    truth_corners: &[Point3<f64>],
) -> (Isometry3<f64>, Vec<Point3<f64>>, f64) {
    let axes = pose.rotation.to_rotation_matrix();
    let mut best = (f64::INFINITY, *pose, Vec::new());
    for perm in [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]] {
        for signs in 0..8 {
            let relabel = Matrix3::from_fn(|r, c| if perm[c] == r { if signs >> c & 1 == 1 { -1.0 } else { 1.0 } } else { 0.0 });
            if relabel.determinant() < 0.0 {
                continue;
            }
            let candidate = Isometry3::from_parts(pose.translation, UnitQuaternion::from_matrix(&(axes.matrix() * relabel)));
            let size = Vector3::from_fn(|c, _| fitted.size()[perm[c]]);
            let corners: Vec<Point3<f64>> =
                (0..CORNER_COUNT).map(|i| candidate * Point3::from(corner_signs(i).component_mul(&size) * 0.5)).collect();
            let worst = corners.iter().zip(truth_corners).map(|(c, t)| (c - t).norm()).fold(0.0, f64::max);
            if worst < best.0 {
                best = (worst, candidate, corners);
            }
        }
    }
    (best.1, best.2, best.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> (BoxModel, Isometry3<f64>, Vec<Point3<f64>>) {
        let model = BoxModel::new(Vector3::new(0.3, 0.2, 0.1)).unwrap();
        let pose = Isometry3::from_parts(Translation3::new(0.1, -0.2, 1.0), UnitQuaternion::from_euler_angles(0.3, -0.2, 0.7));
        let corners = model.corners().iter().map(|c| pose * c).collect();
        (model, pose, corners)
    }

    #[test]
    fn the_true_box_under_other_axis_labels_scores_zero() {
        let (_, pose, corners) = truth();
        // its axes named (y, z, x): sizes 0.2, 0.1, 0.3 along the true y, z and x axes
        let fitted = BoxModel::new(Vector3::new(0.2, 0.1, 0.3)).unwrap();
        let relabel = Matrix3::new(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let fitted_pose = Isometry3::from_parts(pose.translation, pose.rotation * UnitQuaternion::from_matrix(&relabel));
        let (relabelled, _, mssd) = closest_labelling(&fitted, &fitted_pose, &corners);
        assert!(mssd < 1e-9, "{mssd}");
        assert!(relabelled.rotation.angle_to(&pose.rotation) < 1e-6);
    }

    #[test]
    fn a_box_turned_a_quarter_turn_is_not_excused_by_relabelling() {
        // the true sizes with the long side where the middle one should be: axes that a
        // relabelling aligns exactly with the true ones, corners up to 7 cm off
        let (model, pose, corners) = truth();
        let turned = Isometry3::from_parts(pose.translation, pose.rotation * UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        let (_, _, mssd) = closest_labelling(&model, &turned, &corners);
        assert!((mssd - 0.05 * 2f64.sqrt()).abs() < 1e-9, "{mssd}");
    }
}
