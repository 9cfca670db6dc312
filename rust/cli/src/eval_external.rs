//! `boxpose eval --sut SPEC`: another perception system over a dataset's boxes, through the
//! boxpose-sut/1 protocol (as `search --sut`), scored with the project's metrics into the same
//! `eval.parquet` as the own pipeline (method `external`), so that `eval compare` pairs the two
//! box by box.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use boxpose_data::arrow::array::{ArrayRef, BooleanArray, Float64Array, Int32Array, StringArray};
use boxpose_data::{Dataset, Instance};
use boxpose_geometry::BoxModel;
use boxpose_geometry::metrics::{PAPER_ERROR_THRESHOLD, normalized_paper_error};
use boxpose_geometry::pipeline::{FitOutcome, Scores};
use boxpose_learn::evaluation::CORNER_RECALL_RADIUS_M;
use boxpose_search::external::ExternalSut;
use boxpose_search_stats::stats::clopper_pearson;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Point3, Vector3};

use crate::fit_table;
use crate::plots;
use crate::predict::Crops;

/// The `method` of an external system's rows.
pub const METHOD: &str = "external";

/// One box and what the system made of it.
struct Row {
    scene_id: i64,
    frame_id: i32,
    object_id: i32,
    diameter_m: f64,
    /// Err: the system broke the protocol, crashed or timed out on this box (counted apart).
    outcome: Result<FitOutcome, String>,
    /// Whether the answer carried a confidence.
    confidence_given: bool,
    /// Wall time of the call, the system's own time and the transfer.
    seconds: f64,
    corners_found: usize,
}

/// Settings of one `eval --sut` run.
pub struct Settings<'a> {
    pub spec: &'a str,
    pub timeout: Duration,
    pub dataset: &'a Path,
    pub out: &'a Path,
    pub crops: Crops,
    pub min_visible_fraction: f32,
    pub held_out: Option<u32>,
}

pub fn run(settings: &Settings) -> anyhow::Result<()> {
    let dataset = Dataset::open(settings.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    // the system starts (and introduces itself) before the output folder is claimed: one that
    // cannot start leaves nothing behind
    let mut system = ExternalSut::start(settings.spec, settings.timeout)?;
    let _claim = crate::output_folder::claim(settings.out, "--out", "eval", &["eval.parquet"])?;
    let evaluated = |scene_id: i64| {
        settings
            .held_out
            .is_none_or(|modulus| boxpose_learn::data::is_held_out(scene_id, i64::from(modulus)))
    };
    let frames = dataset.frames()?;
    let total = frames.instance_count(evaluated);
    let bar = ProgressBar::new(total as u64).with_style(ProgressStyle::with_template(
        "asking {bar:30} {pos}/{len} instances [{elapsed_precise}<{eta_precise}]",
    )?);
    let mut rows = Vec::new();
    for frame in frames {
        let frame = &frame?;
        if !evaluated(frame.scene_id) {
            continue;
        }
        for instance in frame
            .instances
            .iter()
            .filter(|i| boxpose_learn::data::is_target(i, settings.min_visible_fraction))
        {
            let crop = match settings.crops {
                Crops::Gt => instance.visible_bbox,
                Crops::Predicted => None,
            };
            let start = Instant::now();
            let answer = system.perceive(frame.scene_id, frame, instance, crop);
            let seconds = start.elapsed().as_secs_f64();
            let (outcome, confidence_given, peaks) = match answer {
                Ok(answer) => {
                    let confidence_given = matches!(
                        answer,
                        boxpose_search::external::Answer::Found {
                            confidence: Some(_),
                            ..
                        }
                    );
                    let (outcome, peaks) = boxpose_search::sut::score_external(answer, instance)?;
                    (Ok(outcome), confidence_given, peaks)
                }
                Err(reason) => (Err(reason), false, Vec::new()),
            };
            rows.push(Row {
                scene_id: instance.scene_id,
                frame_id: instance.frame_id,
                object_id: instance.object_id,
                diameter_m: BoxModel::new(Vector3::from(instance.size))?.diameter(),
                outcome,
                confidence_given,
                seconds,
                corners_found: corners_found(instance, &peaks),
            });
        }
        bar.inc(frame.instances.len() as u64);
    }
    bar.finish_and_clear();
    anyhow::ensure!(
        !rows.is_empty(),
        "{}: no instance is visible enough to evaluate",
        settings.dataset.display()
    );

    std::fs::create_dir_all(settings.out)
        .with_context(|| format!("cannot create {}", settings.out.display()))?;
    boxpose_data::write_table(
        &settings.out.join("eval.parquet"),
        &boxpose_data::schema::EVAL,
        columns(&rows),
    )?;
    let summary = Summary::of(&rows, &system);
    boxpose_data::write_file_atomically(
        &settings.out.join("summary.json"),
        serde_json::to_string_pretty(&summary.to_json())?.as_bytes(),
    )?;
    for stale in ["segmentation.json", "paper_error_hist.png"] {
        crate::output_folder::remove_stale(&settings.out.join(stale))?;
    }
    let errors: Vec<f64> = rows
        .iter()
        .filter_map(|r| match &r.outcome {
            Ok(FitOutcome::Scored(s)) => Some(normalized_paper_error(s.paper_error, r.diameter_m)),
            _ => None,
        })
        .collect();
    let histogram = settings.out.join("paper_error_hist.png");
    if errors.iter().any(|e| *e > 0.0) {
        let title = format!(
            "paper's error of {} ({} instances)",
            system.name,
            rows.len()
        );
        plots::error_histogram(
            &histogram,
            &title,
            &[(system.name.as_str(), errors)],
            PAPER_ERROR_THRESHOLD,
        )?;
    }
    summary.print(&system.name, settings.dataset);
    println!(
        "per-instance metrics (method \"{METHOD}\"): {}",
        settings.out.join("eval.parquet").display()
    );
    Ok(())
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
fn columns(rows: &[Row]) -> Vec<ArrayRef> {
    fn scores(row: &Row) -> Option<&Scores> {
        match &row.outcome {
            Ok(FitOutcome::Scored(s)) => Some(s),
            _ => None,
        }
    }
    let absent = || -> ArrayRef { Arc::new(Float64Array::new_null(rows.len())) };
    let leading: Vec<_> = rows
        .iter()
        .map(|r| {
            let key = (r.scene_id, r.frame_id, r.object_id);
            (key, METHOD, r.diameter_m, scores(r))
        })
        .collect();
    let mut columns = fit_table::leading_columns(&leading);
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
                    scores(r)
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
struct Summary {
    system: String,
    instances: usize,
    cube_mssd_recall_010: f64,
    cube_mssd_recall_005: f64,
    mssd_recall_010: f64,
    not_found: usize,
    fit_failed: usize,
    system_errors: usize,
    restarts: usize,
    mean_seconds_per_call: f64,
}

impl Summary {
    fn of(rows: &[Row], system: &ExternalSut) -> Self {
        let n = rows.len();
        let share = |pass: &dyn Fn(&Scores, f64) -> bool| {
            rows.iter()
                .filter(|r| match &r.outcome {
                    Ok(FitOutcome::Scored(s)) => pass(s, r.diameter_m),
                    _ => false,
                })
                .count() as f64
                / n as f64
        };
        let count = |kind: fn(&Result<FitOutcome, String>) -> bool| {
            rows.iter().filter(|r| kind(&r.outcome)).count()
        };
        Summary {
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

    fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "system": self.system,
            "instances": self.instances,
            "cube_mssd_recall_010": self.cube_mssd_recall_010,
            "cube_mssd_recall_005": self.cube_mssd_recall_005,
            "mssd_recall_010": self.mssd_recall_010,
            "not_found": self.not_found,
            "fit_failed": self.fit_failed,
            "system_errors": self.system_errors,
            "restarts": self.restarts,
            "mean_seconds_per_call": self.mean_seconds_per_call,
        })
    }

    fn print(&self, name: &str, dataset: &Path) {
        println!(
            "{name} on {} ({} instances), 95 % Clopper–Pearson intervals:",
            dataset.display(),
            self.instances
        );
        let line = |what: &str, share: f64| {
            let hits = (share * self.instances as f64).round() as u64;
            let (low, high) = clopper_pearson(hits, self.instances as u64, 0.95);
            println!(
                "  {what}: {:.1} % [{:.1}, {:.1}] ({hits}/{})",
                100.0 * share,
                100.0 * low,
                100.0 * high,
                self.instances
            );
        };
        line("cube MSSD < 0.1 d", self.cube_mssd_recall_010);
        line("cube MSSD < 0.05 d", self.cube_mssd_recall_005);
        line("exact MSSD < 0.1 d", self.mssd_recall_010);
        println!(
            "  not found {}, fit failed {}, system errors {} (restarts {}); {:.3} s per call",
            self.not_found,
            self.fit_failed,
            self.system_errors,
            self.restarts,
            self.mean_seconds_per_call
        );
    }
}
