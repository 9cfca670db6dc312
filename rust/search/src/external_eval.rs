//! Another perception system scored on a dataset's boxes (`boxpose eval --sut`): per box, its
//! answer through `boxpose-sut/1` scored as the own pipeline's fits are, the rows of
//! `eval.parquet` (method `external`, null where the system reports nothing of the kind) and the
//! shares of `summary.json`.

use std::sync::Arc;
use std::time::Instant;

use boxpose_data::arrow::array::{ArrayRef, BooleanArray, Float64Array, Int32Array, StringArray};
use boxpose_data::{Frame, Instance};
use boxpose_geometry::BoxModel;
use boxpose_geometry::pipeline::{FitOutcome, Scores};
use boxpose_learn::evaluation::CORNER_RECALL_RADIUS_M;
use boxpose_learn::fit_table::leading_columns;
use nalgebra::{Point3, Vector3};

use crate::Result;
use crate::external::{Answer, ExternalSut};
use crate::sut::score_external;

/// The `method` of an external system's rows.
pub const METHOD: &str = "external";

/// One box and what the system made of it.
pub struct ExternalRow {
    pub scene_id: i64,
    pub frame_id: i32,
    pub object_id: i32,
    pub diameter_m: f64,
    /// Err: the system broke the protocol, crashed or timed out on this box (counted apart).
    pub outcome: std::result::Result<FitOutcome, String>,
    /// Whether the answer carried a confidence.
    pub confidence_given: bool,
    /// Wall time of the call, the system's own time and the transfer.
    pub seconds: f64,
    /// True corners with a reported peak within [`CORNER_RECALL_RADIUS_M`].
    pub corners_found: usize,
}

impl ExternalRow {
    fn scores(&self) -> Option<&Scores> {
        match &self.outcome {
            Ok(FitOutcome::Scored(s)) => Some(s),
            _ => None,
        }
    }
}

/// Asks `system` for `instance` of `frame` (with its ground-truth box as the crop when
/// `crop_gt`, else none: the system finds the box) and scores the answer.
pub fn ask(
    system: &mut ExternalSut,
    frame: &Frame,
    instance: &Instance,
    crop_gt: bool,
) -> Result<ExternalRow> {
    let crop = if crop_gt { instance.visible_bbox } else { None };
    let start = Instant::now();
    let answer = system.perceive(frame.scene_id, frame, instance, crop);
    let seconds = start.elapsed().as_secs_f64();
    let (outcome, confidence_given, peaks) = match answer {
        Ok(answer) => {
            let confidence_given = matches!(
                answer,
                Answer::Found {
                    confidence: Some(_),
                    ..
                }
            );
            let (outcome, peaks) = score_external(answer, instance)?;
            (Ok(outcome), confidence_given, peaks)
        }
        Err(reason) => (Err(reason), false, Vec::new()),
    };
    Ok(ExternalRow {
        scene_id: instance.scene_id,
        frame_id: instance.frame_id,
        object_id: instance.object_id,
        diameter_m: BoxModel::new(Vector3::from(instance.size))?.diameter(),
        outcome,
        confidence_given,
        seconds,
        corners_found: corners_found(instance, &peaks),
    })
}

/// True corners with a reported peak within [`CORNER_RECALL_RADIUS_M`].
fn corners_found(instance: &Instance, peaks: &[[f64; 3]]) -> usize {
    instance
        .corners_camera
        .iter()
        .filter(|c| {
            peaks
                .iter()
                .any(|p| (Point3::from(*p) - Point3::from(**c)).norm() < CORNER_RECALL_RADIUS_M)
        })
        .count()
}

/// The columns of [`boxpose_data::schema::EVAL`]: the metrics of every answered pose; null where
/// an external system reports nothing of the kind (the margin, noise scale, inliers, mirror
/// ambiguity, the heatmap).
pub fn columns(rows: &[ExternalRow]) -> Vec<ArrayRef> {
    let absent = || -> ArrayRef { Arc::new(Float64Array::new_null(rows.len())) };
    let leading: Vec<_> = rows
        .iter()
        .map(|r| {
            let key = (r.scene_id, r.frame_id, r.object_id);
            (key, METHOD, r.diameter_m, r.scores())
        })
        .collect();
    let mut columns = leading_columns(&leading);
    let rest: Vec<ArrayRef> = vec![
        // the whole call: the system's own time and the transfer of the frame
        Arc::new(
            rows.iter()
                .map(|r| Some(1e6 * r.seconds))
                .collect::<Float64Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| {
                    r.scores()
                        .filter(|_| r.confidence_given)
                        .map(|s| s.confidence)
                        .filter(|c| c.is_finite())
                })
                .collect::<Float64Array>(),
        ),
        absent(),
        absent(),
        Arc::new(Int32Array::new_null(rows.len())),
        Arc::new(BooleanArray::new_null(rows.len())),
        Arc::new(
            rows.iter()
                .map(|r| match &r.outcome {
                    Ok(FitOutcome::Scored(_)) => None,
                    Ok(FitOutcome::Failed(reason)) => Some(reason.clone()),
                    Ok(FitOutcome::NotDetected) => Some("not found by the system".to_string()),
                    Err(reason) => Some(format!("system under test: {reason}")),
                })
                .collect::<StringArray>(),
        ),
        absent(),
        Arc::new(
            rows.iter()
                .map(|r| r.corners_found as i32)
                .collect::<Int32Array>(),
        ),
    ];
    columns.extend(rest);
    columns
}

/// What `summary.json` holds for an external system: the learning targets' shares (a box not
/// found, not fitted or not answered fails) and why boxes were not scored.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ExternalSummary {
    pub system: String,
    pub instances: usize,
    pub cube_mssd_recall_010: f64,
    pub cube_mssd_recall_005: f64,
    pub mssd_recall_010: f64,
    pub not_found: usize,
    pub fit_failed: usize,
    pub system_errors: usize,
    pub restarts: usize,
    pub mean_seconds_per_call: f64,
}

impl ExternalSummary {
    /// The summary of a non-empty set of rows of `system`.
    pub fn of(rows: &[ExternalRow], system: &ExternalSut) -> Self {
        let n = rows.len();
        let share = |pass: &dyn Fn(&Scores, f64) -> bool| {
            rows.iter()
                .filter(|r| r.scores().is_some_and(|s| pass(s, r.diameter_m)))
                .count() as f64
                / n as f64
        };
        let count = |kind: fn(&std::result::Result<FitOutcome, String>) -> bool| {
            rows.iter().filter(|r| kind(&r.outcome)).count()
        };
        ExternalSummary {
            system: system.name.clone(),
            instances: n,
            cube_mssd_recall_010: share(&|s, d| s.cube_mssd_m < 0.1 * d),
            cube_mssd_recall_005: share(&|s, d| s.cube_mssd_m < 0.05 * d),
            mssd_recall_010: share(&|s, d| s.mssd_m < 0.1 * d),
            not_found: count(|o| matches!(o, Ok(FitOutcome::NotDetected))),
            fit_failed: count(|o| matches!(o, Ok(FitOutcome::Failed(_)))),
            system_errors: count(|o| o.is_err()),
            restarts: system.restarts,
            mean_seconds_per_call: rows.iter().map(|r| r.seconds).sum::<f64>() / n as f64,
        }
    }
}
