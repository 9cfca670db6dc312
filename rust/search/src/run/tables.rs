//! The run's tables: one row per sample (`samples`), its per-stage seconds (`timings`), their
//! Arrow form, and the counterexamples as dataset shards.

use std::path::Path;
use std::sync::Arc;

use boxpose_data::arrow::array::{
    Array, ArrayRef, AsArray, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array,
    ListArray, StringArray,
};
use boxpose_data::arrow::datatypes::{Float32Type, Float64Type, Int32Type, Int64Type};
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::schema::{self, SEARCH_SAMPLES, SEARCH_TIMINGS};
use boxpose_data::{Object, Scene};

use super::{IterationPlan, RunSettings};
use crate::error::Result;
use crate::space::SearchSpace;
use crate::sut::{Invalid, Outcome, Perceived, Predicate};

/// One row of the `samples` table (see [`schema::SEARCH_SAMPLES`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SampleRow {
    pub sample_id: i64,
    pub sampler: String,
    pub stage: String,
    pub iteration: i32,
    pub stratum: i32,
    pub seed: i64,
    pub z: Vec<f64>,
    pub params: Vec<f64>,
    pub log_nominal: f64,
    pub log_proposal: f64,
    pub log_weight: f64,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    pub target_visible_fraction: Option<f32>,
    pub detected: Option<bool>,
    pub fit_error: Option<String>,
    pub paper_error: Option<f64>,
    pub paper_error_normalized: Option<f64>,
    pub mssd_over_diameter: Option<f64>,
    pub cube_mssd_over_diameter: Option<f64>,
    pub add_s_m: Option<f64>,
    pub rotation_error_deg: Option<f64>,
    pub translation_error_m: Option<f64>,
    /// Null when not scored or nothing fitted (then +∞ for the cross-entropy levels).
    pub score: Option<f64>,
    pub fit_confidence: Option<f64>,
    pub failed: bool,
    pub peaks_camera_m: Option<Vec<f64>>,
    pub fitted_corners_camera_m: Option<Vec<f64>>,
}

impl SampleRow {
    /// Whether this sample fails under `predicate`, whichever predicate its run used: valid, and
    /// not found, not fitted, or the predicate's error above its threshold.
    pub fn fails_under(&self, predicate: &Predicate) -> bool {
        let (error, threshold) = predicate.judge(
            self.paper_error_normalized,
            self.mssd_over_diameter,
            self.cube_mssd_over_diameter,
        );
        self.valid
            && (self.detected == Some(false)
                || self.fit_error.is_some()
                || error.is_some_and(|e| e > threshold))
    }

    /// The score the cross-entropy levels use: NaN for an invalid sample (never an elite), +∞
    /// for a valid one with nothing fitted.
    pub fn level_score(&self) -> f64 {
        match (self.valid, self.score) {
            (false, _) => f64::NAN,
            (true, Some(s)) => s,
            (true, None) => f64::INFINITY,
        }
    }
}

/// Per-stage seconds of one sample (the `timings` table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimingRow {
    pub sample_id: i64,
    pub settle_s: f64,
    pub render_s: f64,
    pub inference_s: f64,
    pub fit_s: f64,
}

#[allow(clippy::too_many_arguments)]
pub(super) fn sample_row(
    sample_id: i64,
    settings: &RunSettings,
    plan: &IterationPlan,
    iteration: u32,
    stratum: u32,
    seed: i64,
    z: &[f64],
    space: &SearchSpace,
    parameters: &crate::space::Parameters,
    log_nominal: f64,
    log_proposal: f64,
    outcome: &Outcome,
) -> SampleRow {
    let params = space
        .dimensions
        .iter()
        .zip(z)
        .map(|(d, zi)| {
            if d.distribution.is_some() {
                parameters.values[&d.name]
            } else {
                *zi
            }
        })
        .collect();
    let visible = outcome.rendered.as_ref().and_then(|(_, instances)| {
        let ids = instances
            .column_by_name("object_id")?
            .as_primitive::<Int32Type>()
            .clone();
        let fractions = instances
            .column_by_name("visible_fraction")?
            .as_primitive::<Float32Type>()
            .clone();
        (0..ids.len())
            .find(|&i| ids.value(i) == crate::scene::TARGET_OBJECT_ID)
            .map(|i| fractions.value(i))
    });
    let mut row = SampleRow {
        sample_id,
        sampler: settings.sampler.name().into(),
        stage: plan.stage.clone(),
        iteration: iteration as i32,
        stratum: stratum as i32,
        seed,
        z: z.to_vec(),
        params,
        log_nominal,
        log_proposal,
        log_weight: log_nominal - log_proposal,
        valid: outcome.result.is_ok(),
        invalid_reason: outcome.result.as_ref().err().map(Invalid::to_string),
        target_visible_fraction: visible,
        detected: None,
        fit_error: None,
        paper_error: None,
        paper_error_normalized: None,
        mssd_over_diameter: None,
        cube_mssd_over_diameter: None,
        add_s_m: None,
        rotation_error_deg: None,
        translation_error_m: None,
        score: None,
        fit_confidence: None,
        failed: false,
        fitted_corners_camera_m: None,
        peaks_camera_m: outcome
            .result
            .is_ok()
            .then(|| outcome.peaks.iter().flatten().copied().collect()),
    };
    match &outcome.result {
        Err(_) => {}
        Ok(Perceived::NotDetected) => {
            row.detected = Some(false);
            row.failed = true;
        }
        Ok(Perceived::FitFailed(e)) => {
            row.detected = Some(true);
            row.fit_error = Some(e.clone());
            row.failed = true;
        }
        Ok(Perceived::Fitted(m)) => {
            let score = settings.predicate.score(m);
            row.detected = Some(true);
            row.paper_error = Some(m.paper_error);
            row.paper_error_normalized = Some(m.paper_error_normalized);
            row.mssd_over_diameter = Some(m.mssd_over_diameter);
            row.cube_mssd_over_diameter = Some(m.cube_mssd_over_diameter);
            row.add_s_m = Some(m.add_s_m);
            row.rotation_error_deg = Some(m.rotation_error_deg);
            row.translation_error_m = Some(m.translation_error_m);
            row.score = Some(score);
            row.fit_confidence = m.confidence;
            row.fitted_corners_camera_m =
                Some(m.fitted_corners.iter().flatten().copied().collect());
            row.failed = score > 0.0;
        }
    }
    row
}

fn f64_list<'a>(rows: impl Iterator<Item = Option<&'a Vec<f64>>>) -> ArrayRef {
    Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(
        rows.map(|r| r.map(|v| v.iter().map(|x| Some(*x)).collect::<Vec<_>>())),
    ))
}

/// `rows` as one batch of the `samples` table.
pub fn samples_batch(rows: &[SampleRow]) -> RecordBatch {
    let f = |get: fn(&SampleRow) -> Option<f64>| {
        Arc::new(rows.iter().map(get).collect::<Float64Array>()) as ArrayRef
    };
    let text = |get: fn(&SampleRow) -> Option<&str>| {
        Arc::new(rows.iter().map(get).collect::<StringArray>()) as ArrayRef
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(rows.iter().map(|r| r.sample_id).collect::<Int64Array>()),
        text(|r| Some(r.sampler.as_str())),
        text(|r| Some(r.stage.as_str())),
        Arc::new(rows.iter().map(|r| r.iteration).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.stratum).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.seed).collect::<Int64Array>()),
        f64_list(rows.iter().map(|r| Some(&r.z))),
        f64_list(rows.iter().map(|r| Some(&r.params))),
        f(|r| Some(r.log_nominal)),
        f(|r| Some(r.log_proposal)),
        f(|r| Some(r.log_weight)),
        Arc::new(rows.iter().map(|r| Some(r.valid)).collect::<BooleanArray>()),
        text(|r| r.invalid_reason.as_deref()),
        Arc::new(
            rows.iter()
                .map(|r| r.target_visible_fraction)
                .collect::<Float32Array>(),
        ),
        Arc::new(rows.iter().map(|r| r.detected).collect::<BooleanArray>()),
        text(|r| r.fit_error.as_deref()),
        f(|r| r.paper_error),
        f(|r| r.paper_error_normalized),
        f(|r| r.mssd_over_diameter),
        f(|r| r.cube_mssd_over_diameter),
        f(|r| r.add_s_m),
        f(|r| r.rotation_error_deg),
        f(|r| r.translation_error_m),
        f(|r| r.score),
        f(|r| r.fit_confidence),
        Arc::new(
            rows.iter()
                .map(|r| Some(r.failed))
                .collect::<BooleanArray>(),
        ),
        f64_list(rows.iter().map(|r| r.peaks_camera_m.as_ref())),
        f64_list(rows.iter().map(|r| r.fitted_corners_camera_m.as_ref())),
    ];
    RecordBatch::try_new(Arc::new(SEARCH_SAMPLES.arrow_schema()), columns)
        .expect("columns in contract order and types")
}

pub(super) fn timings_batch(rows: &[TimingRow]) -> RecordBatch {
    let f = |get: fn(&TimingRow) -> f64| {
        Arc::new(rows.iter().map(get).collect::<Float64Array>()) as ArrayRef
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(rows.iter().map(|r| r.sample_id).collect::<Int64Array>()),
        f(|r| r.settle_s),
        f(|r| r.render_s),
        f(|r| r.inference_s),
        f(|r| r.fit_s),
    ];
    RecordBatch::try_new(Arc::new(SEARCH_TIMINGS.arrow_schema()), columns)
        .expect("columns in contract order and types")
}

/// Reads one `samples` file (validated against the contract).
pub fn read_samples(path: &Path) -> Result<Vec<SampleRow>> {
    let mut rows = Vec::new();
    for batch in boxpose_data::read_shard(path, &SEARCH_SAMPLES)? {
        let col = |name: &str| batch.column_by_name(name).expect("validated").clone();
        let f64s = |name: &str| col(name).as_primitive::<Float64Type>().clone();
        let strings = |name: &str| col(name).as_string::<i32>().clone();
        let bools = |name: &str| col(name).as_boolean().clone();
        let lists = |name: &str| col(name).as_list::<i32>().clone();
        let (ids, sampler, stage) = (
            col("sample_id").as_primitive::<Int64Type>().clone(),
            strings("sampler"),
            strings("stage"),
        );
        let (iteration, stratum, seed) = (
            col("iteration").as_primitive::<Int32Type>().clone(),
            col("stratum").as_primitive::<Int32Type>().clone(),
            col("seed").as_primitive::<Int64Type>().clone(),
        );
        let (z, params, peaks) = (lists("z"), lists("params"), lists("peaks_camera_m"));
        let fitted = lists("fitted_corners_camera_m");
        let (lp, lq, lw) = (
            f64s("log_nominal"),
            f64s("log_proposal"),
            f64s("log_weight"),
        );
        let (valid, reason, visible, detected, fit_error) = (
            bools("valid"),
            strings("invalid_reason"),
            col("target_visible_fraction")
                .as_primitive::<Float32Type>()
                .clone(),
            bools("detected"),
            strings("fit_error"),
        );
        let metrics: Vec<_> = [
            "paper_error",
            "paper_error_normalized",
            "mssd_over_diameter",
            "cube_mssd_over_diameter",
            "add_s_m",
            "rotation_error_deg",
            "translation_error_m",
            "score",
            "fit_confidence",
        ]
        .iter()
        .map(|n| f64s(n))
        .collect();
        let failed = bools("failed");
        let list = |l: &ListArray, i: usize| {
            l.is_valid(i)
                .then(|| l.value(i).as_primitive::<Float64Type>().values().to_vec())
        };
        let opt = |a: &Float64Array, i: usize| a.is_valid(i).then(|| a.value(i));
        for i in 0..batch.num_rows() {
            rows.push(SampleRow {
                sample_id: ids.value(i),
                sampler: sampler.value(i).into(),
                stage: stage.value(i).into(),
                iteration: iteration.value(i),
                stratum: stratum.value(i),
                seed: seed.value(i),
                z: list(&z, i).unwrap_or_default(),
                params: list(&params, i).unwrap_or_default(),
                log_nominal: lp.value(i),
                log_proposal: lq.value(i),
                log_weight: lw.value(i),
                valid: valid.value(i),
                invalid_reason: reason.is_valid(i).then(|| reason.value(i).to_string()),
                target_visible_fraction: visible.is_valid(i).then(|| visible.value(i)),
                detected: detected.is_valid(i).then(|| detected.value(i)),
                fit_error: fit_error
                    .is_valid(i)
                    .then(|| fit_error.value(i).to_string()),
                paper_error: opt(&metrics[0], i),
                paper_error_normalized: opt(&metrics[1], i),
                mssd_over_diameter: opt(&metrics[2], i),
                cube_mssd_over_diameter: opt(&metrics[3], i),
                add_s_m: opt(&metrics[4], i),
                rotation_error_deg: opt(&metrics[5], i),
                translation_error_m: opt(&metrics[6], i),
                score: opt(&metrics[7], i),
                failed: failed.value(i),
                fit_confidence: opt(&metrics[8], i),
                peaks_camera_m: list(&peaks, i),
                fitted_corners_camera_m: list(&fitted, i),
            });
        }
    }
    Ok(rows)
}

pub(super) fn read_timings(path: &Path) -> Result<Vec<TimingRow>> {
    let mut rows = Vec::new();
    for batch in boxpose_data::read_shard(path, &SEARCH_TIMINGS)? {
        let f = |name: &str| {
            batch
                .column_by_name(name)
                .expect("validated")
                .as_primitive::<Float64Type>()
                .clone()
        };
        let ids = batch
            .column_by_name("sample_id")
            .expect("validated")
            .as_primitive::<Int64Type>()
            .clone();
        let (settle, render, inference, fit) =
            (f("settle_s"), f("render_s"), f("inference_s"), f("fit_s"));
        for i in 0..batch.num_rows() {
            rows.push(TimingRow {
                sample_id: ids.value(i),
                settle_s: settle.value(i),
                render_s: render.value(i),
                inference_s: inference.value(i),
                fit_s: fit.value(i),
            });
        }
    }
    Ok(rows)
}

/// Writes failing samples as a dataset shard per table (`boxpose render DIR --scene SAMPLE_ID`
/// re-renders one; `boxpose predict DIR --scene SAMPLE_ID` reruns the pipeline on it).
pub(super) fn write_counterexamples(dir: &Path, name: &str, outcomes: &[Outcome]) -> Result<()> {
    let scenes: Vec<Scene> = outcomes.iter().map(|o| o.scene.clone()).collect();
    let objects: Vec<Object> = outcomes.iter().flat_map(|o| o.objects.clone()).collect();
    let (frames, instances): (Vec<RecordBatch>, Vec<RecordBatch>) =
        outcomes.iter().filter_map(|o| o.rendered.clone()).unzip();
    boxpose_data::write_shard(dir, &schema::SCENES, name, &[Scene::to_batch(&scenes)])?;
    boxpose_data::write_shard(dir, &schema::OBJECTS, name, &[Object::to_batch(&objects)])?;
    boxpose_data::write_shard(dir, &schema::FRAMES, name, &frames)?;
    boxpose_data::write_shard(dir, &schema::INSTANCES, name, &instances)?;
    Ok(())
}
