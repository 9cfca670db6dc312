//! `boxpose predict`'s boxes: where each comes from (a ground-truth box, a segmenter detection or
//! a given bounding box) and its crop, the pose-and-size fit reported of its peaks with the fit's
//! confidence, and its two written forms: the columns of `predictions.parquet` (schema
//! `PREDICTIONS`) and the boxes of `predictions.json` ([`Document`]). Every box goes through
//! [`inference::perceive`], the pipeline of `boxpose eval` and the search.

use std::sync::Arc;

use boxpose_data::Frame;
use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, ListArray, StringArray,
};
use boxpose_data::arrow::datatypes::{Float32Type, Float64Type, Int32Type};
use boxpose_geometry::adaptive::FitConfidence;
use boxpose_geometry::pipeline::{Fitted, Method};
use boxpose_geometry::{BoxModel, GeometryError};
use nalgebra::{Isometry3, Point3};
use serde::Serialize;

use crate::LearnError;
use crate::config::NetworkConfig;
use crate::inference::{self, BoxQuery, CropRequest, KeypointModel, Perception};
use crate::segmentation::{self, SegmenterModel};

/// A box to predict: where it came from, and its crop.
#[derive(Debug, Clone, Copy)]
pub struct Target {
    /// The true box it is (a ground-truth crop, or a detection matched to one).
    pub object_id: Option<i32>,
    /// x_min, y_min, x_max, y_max in pixels (max exclusive).
    pub bbox: [i32; 4],
    pub crop: CropRequest,
}

/// One target per ground-truth box with a visible box and depth.
pub fn gt_targets(frame: &Frame, config: &NetworkConfig) -> Vec<Target> {
    frame
        .instances
        .iter()
        .filter_map(|instance| {
            Some(Target {
                object_id: Some(instance.object_id),
                bbox: instance.visible_bbox?,
                crop: CropRequest::of_instance(frame, config, instance)?,
            })
        })
        .collect()
}

/// The boxes the segmenter finds; each is matched to a true instance (mask IoU ≥ 0.5) when the
/// frame has ground truth, for the overlay and the printed error.
pub fn predicted_targets(
    frame: &Frame,
    config: &NetworkConfig,
    segmenter: &SegmenterModel,
) -> Result<Vec<Target>, LearnError> {
    let detections = segmenter.segment(&[frame])?.remove(0);
    let found = segmentation::match_detections(frame, &detections, 0.5);
    Ok(detections
        .iter()
        .enumerate()
        .filter_map(|(d, detection)| {
            let crop = CropRequest::around(frame, config, detection.bbox, |i| detection.mask[i])?;
            let object_id = found
                .iter()
                .position(|f| *f == Some(d))
                .map(|i| frame.instances[i].object_id);
            Some(Target {
                object_id,
                bbox: detection.bbox,
                crop,
            })
        })
        .collect())
}

/// A target around a given bounding box (max exclusive), with no mask: the reference depth is
/// the median inside the box. None when no pixel inside has a depth.
pub fn bbox_target(frame: &Frame, config: &NetworkConfig, bbox: [i32; 4]) -> Option<Target> {
    let width = frame.width;
    let inside = |i: usize| {
        let (x, y) = ((i % width) as i32, (i / width) as i32);
        (bbox[0]..bbox[2]).contains(&x) && (bbox[1]..bbox[3]).contains(&y)
    };
    Some(Target {
        object_id: None,
        bbox,
        crop: CropRequest::around(frame, config, bbox, inside)?,
    })
}

/// How wide the target's box is at its reference depth (metres), when that makes it implausible
/// for the network: wider than the heatmap's whole depth range or narrower than a tenth of it
/// (`true` for wider). A depth image read in the wrong unit does that (BOP's 0.1 mm units read as
/// millimetres put a box 10× too far, so 10× too large). None when plausible, and always for a
/// network whose depth axis scales with the crop (any box size fits it).
pub fn implausible_width(
    frame: &Frame,
    target: &Target,
    config: &NetworkConfig,
) -> Option<(f64, bool)> {
    if config.depth_scale_crop_m.is_some() {
        return None;
    }
    let [near, far] = config.depth_range_m;
    let depth_range = far - near;
    let [x0, y0, x1, y1] = target.bbox;
    let across = (f64::from(x1 - x0) / frame.intrinsics.fx)
        .max(f64::from(y1 - y0) / frame.intrinsics.fy)
        * target.crop.z_ref;
    if across > depth_range {
        Some((across, true))
    } else if across < depth_range / 10.0 {
        Some((across, false))
    } else {
        None
    }
}

/// A box's fit, or why there is none.
pub type FitOutcome = Result<BoxFit, String>;

/// One box's pose-and-size fit, with its confidence.
#[derive(Debug, Clone)]
pub struct BoxFit {
    pub model: BoxModel,
    pub pose: Isometry3<f64>,
    /// Per peak: whether the fit counts it as an inlier.
    pub inliers: Vec<bool>,
    /// Root mean square of the inliers' distances to their nearest fitted corner (metres).
    pub inlier_rms: f64,
    pub confidence: FitConfidence,
}

impl BoxFit {
    /// What `predict` reports of a size-and-pose fit of `points` (its confidence: its own for the
    /// robust fit, the noise-adaptive assessment of its box for least squares).
    fn of(fitted: &Result<Fitted, GeometryError>, points: &[Point3<f64>]) -> Result<Self, String> {
        let fitted = fitted.as_ref().map_err(ToString::to_string)?;
        let inliers_of_size_fit = "a size-and-pose fit says which peaks are inliers";
        Ok(Self {
            model: fitted.model,
            pose: fitted.pose,
            inliers: fitted.inliers().expect(inliers_of_size_fit),
            inlier_rms: fitted.inlier_rms().expect(inliers_of_size_fit),
            confidence: fitted.confidence(points).map_err(|e| e.to_string())?,
        })
    }

    pub fn corners(&self) -> [Point3<f64>; 8] {
        self.model.corners().map(|c| self.pose * c)
    }

    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|b| **b).count()
    }
}

/// Every target perceived with the size-and-pose fit `method` (mirror ties settled with the
/// frame's depth image), and the fit of each (Err: why there is none).
pub fn predict(
    model: &KeypointModel,
    frame: &Frame,
    targets: &[Target],
    method: Method,
) -> Result<(Vec<Perception>, Vec<FitOutcome>), LearnError> {
    let queries: Vec<BoxQuery> = targets
        .iter()
        .map(|t| BoxQuery {
            crop: t.crop,
            known_box: None,
        })
        .collect();
    let perceptions = inference::perceive(model, frame, &queries, &[method], 16)?;
    let fits = perceptions
        .iter()
        .map(|p| BoxFit::of(&p.fits[0].fitted, &p.points))
        .collect();
    Ok((perceptions, fits))
}

/// The columns of `predictions.parquet`, one row per box; the fit's columns are null where it
/// failed (`fit_error` says why). `confidence_inliers` counts the peaks the noise-adaptive cost
/// takes as inliers (for the robust fit the same as `inlier_count`; least squares counts every
/// peak in `inlier_count`). `size_fit` names the fit.
pub fn columns(
    frame: &Frame,
    targets: &[Target],
    perceptions: &[Perception],
    outcomes: &[Result<BoxFit, String>],
    size_fit: &str,
) -> Vec<ArrayRef> {
    let fits: Vec<Option<&BoxFit>> = outcomes.iter().map(|f| f.as_ref().ok()).collect();
    let f64_list = |values: Vec<Option<Vec<f64>>>| -> ArrayRef {
        Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(
            values
                .into_iter()
                .map(|v| v.map(|v| v.into_iter().map(Some).collect::<Vec<_>>())),
        ))
    };
    let fit_f64 = |get: fn(&BoxFit) -> f64| -> ArrayRef {
        Arc::new(fits.iter().map(|f| f.map(get)).collect::<Float64Array>())
    };
    let fit_i32 = |get: fn(&BoxFit) -> i32| -> ArrayRef {
        Arc::new(fits.iter().map(|f| f.map(get)).collect::<Int32Array>())
    };
    vec![
        Arc::new(Int64Array::from(vec![frame.scene_id; targets.len()])),
        Arc::new(Int32Array::from(vec![frame.frame_id; targets.len()])),
        Arc::new(targets.iter().map(|t| t.object_id).collect::<Int32Array>()),
        Arc::new(ListArray::from_iter_primitive::<Int32Type, _, _>(
            targets.iter().map(|t| Some(t.bbox.map(Some))),
        )),
        Arc::new(
            targets
                .iter()
                .map(|t| t.crop.z_ref)
                .collect::<Float64Array>(),
        ),
        f64_list(
            fits.iter()
                .map(|f| {
                    f.map(|f| {
                        let q = f.pose.rotation.quaternion();
                        vec![q.w, q.i, q.j, q.k]
                    })
                })
                .collect(),
        ),
        f64_list(
            fits.iter()
                .map(|f| f.map(|f| f.pose.translation.vector.as_slice().to_vec()))
                .collect(),
        ),
        f64_list(
            fits.iter()
                .map(|f| f.map(|f| f.model.size().as_slice().to_vec()))
                .collect(),
        ),
        f64_list(
            fits.iter()
                .map(|f| f.map(|f| f.corners().iter().flat_map(|c| [c.x, c.y, c.z]).collect()))
                .collect(),
        ),
        f64_list(
            perceptions
                .iter()
                .map(|p| Some(p.points.iter().flat_map(|c| [c.x, c.y, c.z]).collect()))
                .collect(),
        ),
        Arc::new(ListArray::from_iter_primitive::<Float32Type, _, _>(
            perceptions
                .iter()
                .map(|p| Some(p.peaks.iter().map(|k| Some(k.score)).collect::<Vec<_>>())),
        )),
        fit_i32(|f| f.inlier_count() as i32),
        fit_f64(|f| f.inlier_rms),
        Arc::new(StringArray::from(vec![size_fit; targets.len()])),
        fit_f64(|f| f.confidence.confidence),
        Arc::new(
            fits.iter()
                // no other box hypothesis: an infinite margin, written as null (the readers refuse ±∞)
                .map(|f| {
                    f.map(|f| f.confidence.margin_nats)
                        .filter(|m| m.is_finite())
                })
                .collect::<Float64Array>(),
        ),
        fit_i32(|f| f.confidence.inliers as i32),
        fit_f64(|f| f.confidence.noise_scale_m),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.confidence.mirror_ambiguous))
                .collect::<BooleanArray>(),
        ),
        Arc::new(
            outcomes
                .iter()
                .map(|f| f.as_ref().err().cloned())
                .collect::<StringArray>(),
        ),
    ]
}

/// `predictions.json`: one frame's boxes, the same facts as the Parquet table's rows (serialized
/// by the binary; a non-finite `margin_nats`, no other box hypothesis, is written as null).
#[derive(Debug, Serialize)]
pub struct Document {
    pub scene_id: i64,
    pub frame_id: i32,
    pub boxes: Vec<DocumentBox>,
}

/// A box of [`Document`]: its target, its peaks, and its fit or why there is none.
#[derive(Debug, Serialize)]
pub struct DocumentBox {
    pub object_id: Option<i32>,
    pub bbox: [i32; 4],
    pub reference_depth_m: f64,
    pub peaks_camera_m: Vec<[f64; 3]>,
    /// Widened to f64, as the Parquet column's float32 reads in pandas.
    pub peak_scores: Vec<f64>,
    pub fit: Option<DocumentFit>,
    pub fit_error: Option<String>,
}

/// A fit of [`DocumentBox`].
#[derive(Debug, Serialize)]
pub struct DocumentFit {
    pub size_fit: String,
    pub pose_quat_wxyz: [f64; 4],
    pub pose_translation_m: [f64; 3],
    pub size_m: [f64; 3],
    pub corners_camera_m: [[f64; 3]; 8],
    pub inliers: Vec<bool>,
    pub inlier_rms_m: f64,
    pub confidence: DocumentConfidence,
}

/// [`FitConfidence`]'s fields, as `predictions.json` writes them.
#[derive(Debug, Serialize)]
pub struct DocumentConfidence {
    pub confidence: f64,
    pub margin_nats: f64,
    pub inliers: usize,
    pub noise_scale_m: f64,
    pub mirror_ambiguous: bool,
}

impl From<FitConfidence> for DocumentConfidence {
    fn from(c: FitConfidence) -> Self {
        Self {
            confidence: c.confidence,
            margin_nats: c.margin_nats,
            inliers: c.inliers,
            noise_scale_m: c.noise_scale_m,
            mirror_ambiguous: c.mirror_ambiguous,
        }
    }
}

/// The [`Document`] of `predict`'s outputs for one frame; `size_fit` names the fit.
pub fn document(
    frame: &Frame,
    targets: &[Target],
    perceptions: &[Perception],
    outcomes: &[Result<BoxFit, String>],
    size_fit: &str,
) -> Document {
    let xyz = |c: &Point3<f64>| [c.x, c.y, c.z];
    let boxes = targets
        .iter()
        .zip(perceptions.iter().zip(outcomes))
        .map(|(t, (p, outcome))| DocumentBox {
            object_id: t.object_id,
            bbox: t.bbox,
            reference_depth_m: t.crop.z_ref,
            peaks_camera_m: p.points.iter().map(xyz).collect(),
            peak_scores: p.peaks.iter().map(|k| f64::from(k.score)).collect(),
            fit: outcome.as_ref().ok().map(|fit| {
                let q = fit.pose.rotation.quaternion();
                DocumentFit {
                    size_fit: size_fit.to_string(),
                    pose_quat_wxyz: [q.w, q.i, q.j, q.k],
                    pose_translation_m: fit.pose.translation.vector.into(),
                    size_m: fit.model.size().into(),
                    corners_camera_m: fit.corners().map(|c| xyz(&c)),
                    inliers: fit.inliers.clone(),
                    inlier_rms_m: fit.inlier_rms,
                    confidence: fit.confidence.into(),
                }
            }),
            fit_error: outcome.as_ref().err().cloned(),
        })
        .collect();
    Document {
        scene_id: frame.scene_id,
        frame_id: frame.frame_id,
        boxes,
    }
}
