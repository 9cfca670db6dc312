//! Steps 6–7 together, the way every evaluation runs them: from back-projected peaks to each pose
//! fit and its scores against the true pose. One place, so `eval-geometry` (perfect heatmaps)
//! and `eval` (the network's heatmaps) score identically.

use std::time::Instant;

use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
};

use crate::adaptive::FitConfidence;
use crate::box_model::{CORNER_COUNT, corner_signs};
use crate::correspondence::{fast_exact_search, paper_exact_search};
use crate::depth::{self, DepthView};
use crate::{BoxModel, GeometryError, depth_refine, metrics, robust, size_fit};

/// Peaks the paper's search fits (m).
const PAPER_M: usize = 5;

/// A fit with more inliers than this keeps more than one peak off a face's mirror image, which the
/// depth image is not asked to overrule.
const MIRROR_FACE_MAX_INLIERS: usize = 5;

/// The pose fits compared; all but the two size-and-pose fits know the box's size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The paper's exhaustive correspondence search over the m best peaks.
    PaperExact,
    /// The same optimum by branch and bound.
    FastExact,
    /// Hypothesize-and-verify with the noise-adaptive cost ([`robust::adaptive_fit`]): survives
    /// outlier peaks with no threshold in box units.
    Robust,
    /// Pose and box size together, for a box of unknown size, by the same design
    /// ([`size_fit::robust_size_fit`]).
    SizeAndPose,
    /// The former robust fit: truncated least squares at a quarter of the shortest side
    /// ([`robust::robust_fit`]), kept for comparison.
    RobustFixedThreshold,
    /// The former size-and-pose fit: least-squares scaling ICP from principal axes
    /// ([`size_fit::fit_pose_and_size`] with default parameters), kept for comparison.
    SizeAndPoseLeastSquares,
}

impl Method {
    pub const ALL: [Method; 6] = [
        Method::PaperExact,
        Method::FastExact,
        Method::Robust,
        Method::SizeAndPose,
        Method::RobustFixedThreshold,
        Method::SizeAndPoseLeastSquares,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::PaperExact => "paper_exact",
            Method::FastExact => "fast_exact",
            Method::Robust => "robust",
            Method::SizeAndPose => "size_and_pose",
            Method::RobustFixedThreshold => "robust_fixed",
            Method::SizeAndPoseLeastSquares => "size_and_pose_ls",
        }
    }

    /// Whether the fit estimates the box's size rather than taking the known one.
    pub fn fits_size(self) -> bool {
        matches!(self, Method::SizeAndPose | Method::SizeAndPoseLeastSquares)
    }
}

/// What one fit returned: the box it fitted (the known model, or the fitted size) and its pose,
/// with the confidence the fit computed itself, if it does.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    pub model: BoxModel,
    pub pose: Isometry3<f64>,
    pub fits_size: bool,
    pub own_confidence: Option<FitConfidence>,
    /// Per point, the corner it is an inlier of, as the fit matched it; None for an outlier (the
    /// noise-adaptive fits and the least-squares size fit only).
    pub inlier_corners: Option<Vec<Option<usize>>>,
    /// Per point, its distance (metres) to the nearest corner of the fitted box, for the fits that
    /// have [`Self::inlier_corners`].
    pub residuals: Option<Vec<f64>>,
}

/// Per point, its corner if it is an inlier.
fn inlier_corners(inliers: &[bool], nearest_corners: &[usize]) -> Vec<Option<usize>> {
    inliers
        .iter()
        .zip(nearest_corners)
        .map(|(&inlier, &corner)| inlier.then_some(corner))
        .collect()
}

impl Fitted {
    /// The noise-adaptive fit of a box of known size.
    pub fn from_adaptive(model: &BoxModel, fit: &robust::AdaptiveFit) -> Self {
        Self {
            model: *model,
            pose: fit.pose,
            fits_size: false,
            own_confidence: Some(fit.confidence),
            inlier_corners: Some(inlier_corners(&fit.inliers, &fit.nearest_corners)),
            residuals: Some(fit.residuals.clone()),
        }
    }

    /// The noise-adaptive pose-and-size fit.
    pub fn from_robust_size(fit: &size_fit::RobustSizedFit) -> Self {
        Self {
            model: fit.model,
            pose: fit.pose,
            fits_size: true,
            own_confidence: Some(fit.confidence),
            inlier_corners: Some(inlier_corners(&fit.inliers, &fit.nearest_corners)),
            residuals: Some(fit.residuals.clone()),
        }
    }

    /// A pose another system reported (`boxpose search --sut`): its box (of the true size, or of
    /// the size it fitted) and its own confidence, NaN when it gave none; no per-point detail.
    pub fn reported(
        model: BoxModel,
        pose: Isometry3<f64>,
        fits_size: bool,
        confidence: f64,
    ) -> Self {
        Self {
            model,
            pose,
            fits_size,
            own_confidence: Some(FitConfidence {
                confidence,
                margin_nats: f64::NAN,
                inliers: 0,
                noise_scale_m: f64::NAN,
                mirror_ambiguous: false,
            }),
            inlier_corners: None,
            residuals: None,
        }
    }

    /// How far this fit is from the truth ([`Scores`]), `points` the peaks it was fitted to (for
    /// the confidence of the fits that do not assess themselves).
    pub fn score(
        &self,
        fit_time_us: f64,
        model: &BoxModel,
        truth: &Isometry3<f64>,
        points: &[Point3<f64>],
    ) -> FitOutcome {
        score_fitted(self, fit_time_us, model, truth, points).into()
    }

    /// Per point, whether the fit counts it as an inlier; None for the fits that do not say.
    pub fn inliers(&self) -> Option<Vec<bool>> {
        let corners = self.inlier_corners.as_ref()?;
        Some(corners.iter().map(Option::is_some).collect())
    }

    /// Root mean square of the inliers' distances to their nearest fitted corner (metres); None
    /// for the fits that do not say which points are inliers.
    pub fn inlier_rms(&self) -> Option<f64> {
        Some(robust::inlier_rms(
            self.residuals.as_ref()?,
            &self.inliers()?,
        ))
    }

    /// Settles a mirror tie with the depth image. Four inlier peaks on one face of the box fit the
    /// box and its mirror image through that face alike, so the peaks cannot choose, and a fifth
    /// peak near a corner of the mirror box (a depth flip of the detector) makes the wrong one
    /// win. The candidates are the mirror images through the plane of the inliers when they lie in
    /// one plane (`mirror_ambiguous`), and, for a fit with at most 5 inliers, through each face of
    /// the fitted box whose 4 corners all have an inlier peak. [`depth::resolve_mirror`] keeps the
    /// pose that agrees with `view`; the fit stays `mirror_ambiguous` only if the depth image
    /// cannot tell either.
    pub fn resolve_mirror(&mut self, points: &[Point3<f64>], view: &DepthView) {
        let (Some(confidence), Some(corners)) = (self.own_confidence, &self.inlier_corners) else {
            return;
        };
        let inliers: Vec<(Point3<f64>, usize)> = points
            .iter()
            .zip(corners)
            .filter_map(|(p, corner)| corner.map(|c| (*p, c)))
            .collect();
        let mut planes = Vec::new();
        if confidence.mirror_ambiguous {
            planes.push(inliers.iter().map(|(p, _)| *p).collect());
        }
        if inliers.len() <= MIRROR_FACE_MAX_INLIERS {
            planes.extend(faces_with_four_inliers(&inliers));
        }
        let tolerance = depth::depth_tolerance(confidence.noise_scale_m);
        let mut still_ambiguous = confidence.mirror_ambiguous;
        for plane in planes {
            let resolution =
                depth::resolve_mirror(&self.model, &self.pose, &plane, view, tolerance);
            if resolution.switched {
                self.pose = resolution.pose;
                if let Some(residuals) = &mut self.residuals {
                    *residuals = nearest_corner_distances(&self.model, &self.pose, points);
                }
                still_ambiguous = false;
                break;
            }
            if !resolution.still_ambiguous {
                still_ambiguous = false;
            }
        }
        if let Some(own) = &mut self.own_confidence {
            own.mirror_ambiguous = still_ambiguous;
        }
    }

    /// The fit's own confidence, or else the noise-adaptive assessment of its box on `points`
    /// ([`robust::assess_pose`] or [`size_fit::assess_sized_box`]).
    pub fn confidence(&self, points: &[Point3<f64>]) -> Result<FitConfidence, GeometryError> {
        match self.own_confidence {
            Some(c) => Ok(c),
            None if self.fits_size => size_fit::assess_sized_box(points, &self.model, &self.pose),
            None => robust::assess_pose(&self.model, points, &self.pose),
        }
    }

    /// MSSD against the true box: the BOP MSSD for a fit of known size, and for a fitted size
    /// the largest distance between its corners and the true ones under the axis labelling that
    /// matches them best (so a wrong size counts).
    pub fn mssd(&self, true_model: &BoxModel, truth: &Isometry3<f64>) -> f64 {
        if self.fits_size {
            let truth_corners: Vec<Point3<f64>> =
                true_model.corners().iter().map(|c| truth * c).collect();
            closest_labelling(&self.model, &self.pose, &truth_corners).2
        } else {
            metrics::mssd(true_model, &self.pose, truth).unwrap_or(f64::INFINITY)
        }
    }
}

/// Per point, its distance to the nearest corner of `model` at `pose`.
fn nearest_corner_distances(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    points: &[Point3<f64>],
) -> Vec<f64> {
    let corners = model.corners().map(|c| pose * c);
    points
        .iter()
        .map(|p| {
            corners
                .iter()
                .map(|c| (p - c).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// The inlier peaks of each face of the box whose 4 corners each have one, from (peak, corner).
fn faces_with_four_inliers(inliers: &[(Point3<f64>, usize)]) -> Vec<Vec<Point3<f64>>> {
    let mut at_corner: [Option<Point3<f64>>; CORNER_COUNT] = [None; CORNER_COUNT];
    for &(p, corner) in inliers {
        at_corner[corner] = Some(p);
    }
    let mut faces = Vec::new();
    for axis in 0..3 {
        for sign in [-1.0, 1.0] {
            let face: Option<Vec<Point3<f64>>> = (0..CORNER_COUNT)
                .filter(|&c| corner_signs(c)[axis] == sign)
                .map(|c| at_corner[c])
                .collect();
            faces.extend(face);
        }
    }
    faces
}

/// Runs one fit on `points` (with NMS `scores`, best first; only the paper's searches use them).
/// `known_box` is the box's true size, which every fit but the two size-and-pose fits needs.
pub fn fit_method(
    method: Method,
    known_box: Option<&BoxModel>,
    points: &[Point3<f64>],
    scores: &[f64],
) -> Result<Fitted, GeometryError> {
    let model = || {
        known_box.ok_or(GeometryError::InvalidParameter {
            name: "known_box",
            reason: "a fit of known size needs the box's size",
        })
    };
    let known = |pose: Isometry3<f64>| -> Result<Fitted, GeometryError> {
        Ok(Fitted {
            model: *model()?,
            pose,
            fits_size: false,
            own_confidence: None,
            inlier_corners: None,
            residuals: None,
        })
    };
    match method {
        Method::PaperExact => known(paper_exact_search(model()?, points, scores, PAPER_M)?.pose),
        Method::FastExact => known(fast_exact_search(model()?, points, scores, PAPER_M)?.pose),
        Method::Robust => Ok(Fitted::from_adaptive(
            model()?,
            &robust::adaptive_fit(model()?, points, &robust::AdaptiveParams::default())?,
        )),
        Method::RobustFixedThreshold => known(
            robust::robust_fit(model()?, points, &robust::RobustParams::for_box(model()?))?.pose,
        ),
        Method::SizeAndPose => Ok(Fitted::from_robust_size(&size_fit::robust_size_fit(
            points,
            &size_fit::RobustSizeParams::default(),
        )?)),
        Method::SizeAndPoseLeastSquares => {
            let fit = size_fit::fit_pose_and_size(points, &size_fit::SizeFitParams::default())?;
            Ok(Fitted {
                model: fit.model,
                pose: fit.pose,
                fits_size: true,
                own_confidence: None,
                inlier_corners: Some(inlier_corners(&fit.inliers, &fit.nearest_corners)),
                residuals: Some(fit.residuals),
            })
        }
    }
}

/// One fit as every caller runs it: [`fit_method`], then, given the frame's depth image
/// (`depth`), its mirror tie settled ([`Fitted::resolve_mirror`]), both timed.
#[derive(Debug, Clone)]
pub struct FitRun {
    pub method: Method,
    pub fitted: Result<Fitted, GeometryError>,
    /// Wall time of the fit and its mirror check, microseconds.
    pub fit_time_us: f64,
}

impl FitRun {
    /// Runs `method` on `points` (with NMS `scores`, best first); `known_box` as [`fit_method`].
    pub fn new(
        method: Method,
        known_box: Option<&BoxModel>,
        points: &[Point3<f64>],
        scores: &[f64],
        depth: Option<&DepthView>,
    ) -> Self {
        let start = Instant::now();
        let fitted = fit_method(method, known_box, points, scores).map(|mut fitted| {
            if let Some(view) = depth {
                fitted.resolve_mirror(points, view);
            }
            fitted
        });
        Self {
            method,
            fitted,
            fit_time_us: start.elapsed().as_secs_f64() * 1e6,
        }
    }
}

impl FitRun {
    /// Lays a known-size fit's pose on the depth image's points of the box's visible faces, on
    /// the pixels `belongs` marks as the box's (its mask; [`depth_refine::refine_with_depth`];
    /// `boxpose search --refine-depth`). The robust fit first lets the depth image choose among
    /// the poses its peaks allow: its search's best [`DEPTH_CANDIDATES`] different hypotheses
    /// ([`robust::adaptive_candidates`]), each laid on the depth image, are weighed by
    /// [`depth_refine::choose_with_depth`] against the fit's own. The peaks of a box occluded in a
    /// pile often fix no pose (four corners of one face), and the depth image tells the right one
    /// from poses that leave its mask unexplained or stand where the camera saw through. The
    /// paper's fits keep their own pose, only laid on the depth. A size fit, a failed fit, or a
    /// depth image that holds too little of the box leaves the fit as it was. The time counts in
    /// the fit's.
    pub fn refine_with_depth(
        &mut self,
        points: &[Point3<f64>],
        view: &DepthView,
        belongs: impl Fn(usize) -> bool,
    ) {
        let start = Instant::now();
        if let Ok(fitted) = &mut self.fitted
            && !fitted.fits_size
        {
            let model = fitted.model;
            let lay = |pose: Isometry3<f64>| {
                depth_refine::refine_with_depth(&model, &pose, view, &belongs)
                    .map_or(pose, |refined| refined.pose)
            };
            let mut pose = lay(fitted.pose);
            let search = robust::AdaptiveParams {
                refine_top: DEPTH_CANDIDATES,
                ..Default::default()
            };
            if self.method == Method::Robust
                && let Ok(others) = robust::adaptive_candidates(&model, points, &search)
            {
                let poses: Vec<Isometry3<f64>> = std::iter::once(pose)
                    .chain(others.into_iter().map(lay))
                    .collect();
                pose = poses[depth_refine::choose_with_depth(&model, &poses, view, &belongs)];
            }
            if pose != fitted.pose {
                fitted.pose = pose;
                if let Some(residuals) = &mut fitted.residuals {
                    *residuals = nearest_corner_distances(&model, &pose, points);
                }
            }
        }
        self.fit_time_us += start.elapsed().as_secs_f64() * 1e6;
    }
}

/// How many of the robust search's different hypotheses the depth image weighs against the fit's
/// pose ([`FitRun::refine_with_depth`]): twice the fit's own `refine_top`; 12 took 9 more of 457
/// boxes in the sensor-depth bins than 6 (docs/log/2026-12-06-depth-hypotheses.md).
pub const DEPTH_CANDIDATES: usize = 12;

/// A pose as the dataset stores it: a unit quaternion (w, x, y, z) and a translation in metres.
pub fn isometry(quat_wxyz: [f64; 4], translation: [f64; 3]) -> Isometry3<f64> {
    let [w, x, y, z] = quat_wxyz;
    Isometry3::from_parts(
        Translation3::from(Vector3::from(translation)),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

/// How far one fit is from the truth, and how far the fit trusts itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scores {
    /// [`metrics::paper_error`] of the fitted corners against the true ones.
    pub paper_error: f64,
    /// [`metrics::mssd`] for a fit of known size (the orientation-aware error: a quarter turn of a
    /// box with two nearly equal sides scores ≈ half its diameter); for a fitted size,
    /// [`Fitted::mssd`].
    pub mssd_m: f64,
    /// [`metrics::cube_mssd`] of the fitted box against the true one: the corners' real
    /// displacement, whatever the fit called them (the primary correctness metric).
    pub cube_mssd_m: f64,
    /// [`metrics::iou_3d`] of the fitted box (its own size for a size fit) and the true one.
    pub iou_3d: f64,
    pub add_s_m: f64,
    pub rotation_error_deg: f64,
    pub translation_error_m: f64,
    pub fit_time_us: f64,
    /// [`FitConfidence::confidence`] in [0, 1): the fit's own (`robust`, `size_and_pose`) or the
    /// noise-adaptive assessment of its pose (the others). Not counted in `fit_time_us`.
    pub confidence: f64,
    /// [`FitConfidence::margin_nats`].
    pub margin_nats: f64,
    /// [`FitConfidence::noise_scale_m`].
    pub noise_scale_m: f64,
    /// [`FitConfidence::inliers`].
    pub inliers: usize,
    /// [`FitConfidence::mirror_ambiguous`], after the depth image's say where the fit had one
    /// ([`Fitted::resolve_mirror`]).
    pub mirror_ambiguous: bool,
    /// The fitted box's 8 corners (its own size under its pose, in the model's corner order),
    /// in the frame of the points: what an overlay draws.
    pub fitted_corners: [[f64; 3]; 8],
}

/// What became of one pose fit of one box.
// Nearly every outcome is `Scored`, so boxing the scores would only add an allocation per fit.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum FitOutcome {
    /// The fit returned a pose, scored against the truth.
    Scored(Scores),
    /// The fit ran and failed: the geometry error (too few peaks, a degenerate set, …).
    Failed(String),
    /// No fit ran: the detector (the segmenter) did not find the box.
    NotDetected,
}

impl FitOutcome {
    /// The scores, when the fit returned a pose.
    pub fn scores(&self) -> Option<&Scores> {
        match self {
            Self::Scored(scores) => Some(scores),
            Self::Failed(_) | Self::NotDetected => None,
        }
    }

    /// Why there is no pose, as the result tables' `fit_error` column says it; None when scored.
    pub fn failure(&self) -> Option<&str> {
        match self {
            Self::Scored(_) => None,
            Self::Failed(error) => Some(error),
            Self::NotDetected => Some("not found by the segmenter"),
        }
    }
}

impl From<Result<Scores, GeometryError>> for FitOutcome {
    fn from(result: Result<Scores, GeometryError>) -> Self {
        match result {
            Ok(scores) => Self::Scored(scores),
            Err(e) => Self::Failed(e.to_string()),
        }
    }
}

/// Runs every [`Method`] on `points` (with NMS `scores`, best first) and scores each against the
/// true pose of `model` ([`FitRun::score`]). With the frame's depth image (`depth`), the
/// noise-adaptive fits settle mirror ties with it ([`Fitted::resolve_mirror`], counted in the
/// fit's time).
pub fn fit_and_score(
    model: &BoxModel,
    truth: &Isometry3<f64>,
    points: &[Point3<f64>],
    scores: &[f64],
    depth: Option<&DepthView>,
) -> Vec<(Method, FitOutcome)> {
    Method::ALL
        .iter()
        .map(|&method| {
            let run = FitRun::new(method, Some(model), points, scores, depth);
            (method, run.score(model, truth, points))
        })
        .collect()
}

impl FitRun {
    /// The fit's scores against the true pose of the true box `model`, from the `points` it
    /// fitted; a fit that failed gives its error instead.
    ///
    /// The size-known fits are scored with the true model. The size-and-pose fits are scored as
    /// the box they fitted: their MSSD compares their own corners with the true ones and their
    /// ADD-S their own surface points with the true box's ([`metrics::add_s_between`]), so a wrong
    /// size counts, and their rotation is taken in the axis labels that best match the true
    /// corners.
    pub fn score(
        &self,
        model: &BoxModel,
        truth: &Isometry3<f64>,
        points: &[Point3<f64>],
    ) -> FitOutcome {
        match &self.fitted {
            Ok(fitted) => fitted.score(self.fit_time_us, model, truth, points),
            Err(e) => FitOutcome::Failed(e.to_string()),
        }
    }
}

fn score_fitted(
    fitted: &Fitted,
    fit_time_us: f64,
    model: &BoxModel,
    truth: &Isometry3<f64>,
    points: &[Point3<f64>],
) -> Result<Scores, GeometryError> {
    let truth_corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth * c).collect();
    let confidence = fitted.confidence(points)?;
    let (mssd_m, add_s_m, rotation_error_deg) = if fitted.fits_size {
        let (relabelled, _, mssd_m) =
            closest_labelling(&fitted.model, &fitted.pose, &truth_corners);
        let add_s_m = metrics::add_s_between(&fitted.model, &fitted.pose, model, truth)?;
        (
            mssd_m,
            add_s_m,
            metrics::rotation_error_deg(model, &relabelled, truth)?,
        )
    } else {
        (
            metrics::mssd(model, &fitted.pose, truth)?,
            metrics::add_s(model, &fitted.pose, truth)?,
            metrics::rotation_error_deg(model, &fitted.pose, truth)?,
        )
    };
    Ok(Scores {
        paper_error: metrics::paper_error(&fitted.model, &fitted.pose, &truth_corners)?,
        mssd_m,
        cube_mssd_m: metrics::cube_mssd(&fitted.model, &fitted.pose, model, truth)?,
        iou_3d: metrics::iou_3d(&fitted.model, &fitted.pose, model, truth)?,
        add_s_m,
        rotation_error_deg,
        translation_error_m: metrics::translation_error(&fitted.pose, truth)?,
        fit_time_us,
        confidence: confidence.confidence,
        margin_nats: confidence.margin_nats,
        noise_scale_m: confidence.noise_scale_m,
        inliers: confidence.inliers,
        mirror_ambiguous: confidence.mirror_ambiguous,
        fitted_corners: std::array::from_fn(|i| {
            let c = fitted.pose * fitted.model.corners()[i];
            [c.x, c.y, c.z]
        }),
    })
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
    for perm in [
        [0, 1, 2],
        [1, 2, 0],
        [2, 0, 1],
        [0, 2, 1],
        [2, 1, 0],
        [1, 0, 2],
    ] {
        for signs in 0..8 {
            let relabel = Matrix3::from_fn(|r, c| {
                if perm[c] == r {
                    if signs >> c & 1 == 1 { -1.0 } else { 1.0 }
                } else {
                    0.0
                }
            });
            if relabel.determinant() < 0.0 {
                continue;
            }
            let candidate = Isometry3::from_parts(
                pose.translation,
                // a rotation times a signed permutation of determinant 1: exactly a rotation
                UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
                    axes.matrix() * relabel,
                )),
            );
            let size = Vector3::from_fn(|c, _| fitted.size()[perm[c]]);
            let corners: Vec<Point3<f64>> = (0..CORNER_COUNT)
                .map(|i| candidate * Point3::from(corner_signs(i).component_mul(&size) * 0.5))
                .collect();
            let worst = corners
                .iter()
                .zip(truth_corners)
                .map(|(c, t)| (c - t).norm())
                .fold(0.0, f64::max);
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
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 1.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 0.7),
        );
        let corners = model.corners().iter().map(|c| pose * c).collect();
        (model, pose, corners)
    }

    #[test]
    fn the_true_box_under_other_axis_labels_scores_zero() {
        let (_, pose, corners) = truth();
        // its axes named (y, z, x): sizes 0.2, 0.1, 0.3 along the true y, z and x axes
        let fitted = BoxModel::new(Vector3::new(0.2, 0.1, 0.3)).unwrap();
        let relabel = Matrix3::new(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let fitted_pose = Isometry3::from_parts(
            pose.translation,
            pose.rotation * UnitQuaternion::from_matrix(&relabel),
        );
        let (relabelled, _, mssd) = closest_labelling(&fitted, &fitted_pose, &corners);
        assert!(mssd < 1e-9, "{mssd}");
        assert!(relabelled.rotation.angle_to(&pose.rotation) < 1e-6);
    }

    #[test]
    fn a_box_turned_a_quarter_turn_is_not_excused_by_relabelling() {
        // the true sizes with the long side where the middle one should be: axes that a
        // relabelling aligns exactly with the true ones, corners up to 7 cm off
        let (model, pose, corners) = truth();
        let turned = Isometry3::from_parts(
            pose.translation,
            pose.rotation
                * UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        let (_, _, mssd) = closest_labelling(&model, &turned, &corners);
        assert!((mssd - 0.05 * 2f64.sqrt()).abs() < 1e-9, "{mssd}");
    }
}
