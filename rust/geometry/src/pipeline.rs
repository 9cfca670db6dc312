//! Steps 6–7 together, the way every evaluation runs them: from back-projected peaks to each pose
//! fit and its scores against the true pose. One place, so `eval-geometry` (perfect heatmaps)
//! and `eval` (the network's heatmaps) score identically.

use std::time::Instant;

use nalgebra::{Isometry3, Matrix3, Point3, UnitQuaternion};

use crate::correspondence::{fast_exact_search, paper_exact_search};
use crate::{BoxModel, metrics, robust, size_fit};

/// Peaks the paper's search fits (m).
pub const PAPER_M: usize = 5;

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
pub fn fit_and_score(
    model: &BoxModel,
    truth: &Isometry3<f64>,
    points: &[Point3<f64>],
    scores: &[f64],
) -> Vec<(Method, Result<Scores, String>)> {
    let truth_corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth * c).collect();
    // `fitted` and `fitted_pose` give the paper's error (corner sets, so axis labels do not
    // matter); `estimate` is the pose in the true model's axis labels for the pose metrics.
    let score = |fitted: &BoxModel, fitted_pose: &Isometry3<f64>, estimate: &Isometry3<f64>, start: Instant| -> Result<Scores, String> {
        let fit_time_us = start.elapsed().as_secs_f64() * 1e6;
        let text = |e: crate::GeometryError| e.to_string();
        Ok(Scores {
            paper_error: metrics::paper_error(fitted, fitted_pose, &truth_corners).map_err(text)?,
            mssd_m: metrics::mssd(model, estimate, truth).map_err(text)?,
            add_s_m: metrics::add_s(model, estimate, truth).map_err(text)?,
            rotation_error_deg: metrics::rotation_error_deg(model, estimate, truth).map_err(text)?,
            translation_error_m: metrics::translation_error(estimate, truth).map_err(text)?,
            fit_time_us,
        })
    };
    Method::ALL
        .into_iter()
        .map(|method| {
            let start = Instant::now();
            let outcome = match method {
                Method::PaperExact => paper_exact_search(model, points, scores, PAPER_M)
                    .map_err(|e| e.to_string())
                    .and_then(|f| score(model, &f.pose, &f.pose, start)),
                Method::FastExact => fast_exact_search(model, points, scores, PAPER_M)
                    .map_err(|e| e.to_string())
                    .and_then(|f| score(model, &f.pose, &f.pose, start)),
                Method::Robust => robust::robust_fit(model, points, &robust::RobustParams::for_box(model))
                    .map_err(|e| e.to_string())
                    .and_then(|f| score(model, &f.pose, &f.pose, start)),
                Method::SizeAndPose => size_fit::fit_pose_and_size(points, &size_fit::SizeFitParams::default())
                    .map_err(|e| e.to_string())
                    .and_then(|f| score(&f.model, &f.pose, &relabel_axes(&f.pose, truth), start)),
            };
            (method, outcome)
        })
        .collect()
}

/// A box of unknown size has no preferred axis labels: the size fit may call the true x axis
/// its z. Of the 24 proper signed axis permutations of the fitted frame, returns the one whose
/// axes best align with the true ones, so that the pose metrics compare like with like.
pub fn relabel_axes(fitted: &Isometry3<f64>, truth: &Isometry3<f64>) -> Isometry3<f64> {
    let (fitted_axes, true_axes) = (fitted.rotation.to_rotation_matrix(), truth.rotation.to_rotation_matrix());
    let mut best = (f64::NEG_INFINITY, *fitted);
    for perm in [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]] {
        for signs in 0..8 {
            let relabel = Matrix3::from_fn(|r, c| if perm[c] == r { if signs >> c & 1 == 1 { -1.0 } else { 1.0 } } else { 0.0 });
            if relabel.determinant() < 0.0 {
                continue;
            }
            let candidate = fitted_axes.matrix() * relabel;
            let alignment = (candidate.transpose() * true_axes.matrix()).trace();
            if alignment > best.0 {
                best = (alignment, Isometry3::from_parts(fitted.translation, UnitQuaternion::from_matrix(&candidate)));
            }
        }
    }
    best.1
}
