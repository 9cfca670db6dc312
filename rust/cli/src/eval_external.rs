//! `boxpose eval --sut SPEC`: another perception system over a dataset's boxes, through the
//! boxpose-sut/1 protocol (as `search --sut`), scored with the project's metrics into the same
//! `eval.parquet` as the own pipeline (method `external`), so that `eval compare` pairs the two
//! box by box.

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use boxpose_data::Dataset;
use boxpose_geometry::metrics::{PAPER_ERROR_THRESHOLD, normalized_paper_error};
use boxpose_geometry::pipeline::FitOutcome;
use boxpose_search::external::ExternalSut;
use boxpose_search::external_eval::{self, ExternalRow, ExternalSummary, METHOD};
use boxpose_search_stats::stats::clopper_pearson;
use indicatif::{ProgressBar, ProgressStyle};

use boxpose_learn::evaluation::Crops;
use boxpose_report::plots;

/// Settings of one `eval --sut` run.
pub struct Settings<'a> {
    pub spec: &'a str,
    pub timeout: Duration,
    pub dataset: &'a Path,
    pub out: &'a Path,
    pub crops: Crops,
    pub min_visible_fraction: f32,
    pub held_out: Option<u32>,
    /// Send the frames' simulated sensor depth instead of the exact one.
    pub sensor_depth: bool,
}

pub fn run(settings: &Settings) -> anyhow::Result<()> {
    let dataset = Dataset::open(settings.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    // the system starts (and introduces itself) before the output folder is claimed: one that
    // cannot start leaves nothing behind
    let mut system = ExternalSut::start(settings.spec, settings.timeout)?;
    let _claim =
        boxpose_data::output_folder::claim(settings.out, "--out", "eval", &["eval.parquet"])?;
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
        let mut frame = frame?;
        if !evaluated(frame.scene_id) {
            continue;
        }
        boxpose_learn::data::perceived_depth(&mut frame, settings.sensor_depth, settings.dataset)?;
        let frame = &frame;
        for instance in frame
            .instances
            .iter()
            .filter(|i| boxpose_learn::data::is_target(i, settings.min_visible_fraction))
        {
            let crop_gt = settings.crops == Crops::Gt;
            rows.push(external_eval::ask(&mut system, frame, instance, crop_gt)?);
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
        external_eval::columns(&rows),
    )?;
    let summary = ExternalSummary::of(&rows, &system);
    // through a Value: its keys sorted, as every summary.json
    let summary_json = serde_json::to_value(&summary)?;
    boxpose_data::write_file_atomically(
        &settings.out.join("summary.json"),
        serde_json::to_string_pretty(&summary_json)?.as_bytes(),
    )?;
    for stale in ["segmentation.json", "paper_error_hist.png"] {
        boxpose_data::output_folder::remove_stale(&settings.out.join(stale))?;
    }
    draw_histogram(
        &settings.out.join("paper_error_hist.png"),
        &rows,
        &system.name,
    )?;
    print_summary(&summary, settings.dataset);
    println!(
        "per-instance metrics (method \"{METHOD}\"): {}",
        settings.out.join("eval.parquet").display()
    );
    Ok(())
}

/// The paper's error of every scored box, normalised as in Fig. 6, as a histogram (none when no
/// box was scored with a positive error).
fn draw_histogram(histogram: &Path, rows: &[ExternalRow], name: &str) -> anyhow::Result<()> {
    let errors: Vec<f64> = rows
        .iter()
        .filter_map(|r| match &r.outcome {
            Ok(FitOutcome::Scored(s)) => Some(normalized_paper_error(s.paper_error, r.diameter_m)),
            _ => None,
        })
        .collect();
    if errors.iter().any(|e| *e > 0.0) {
        let title = format!("paper's error of {} ({} instances)", name, rows.len());
        plots::error_histogram(histogram, &title, &[(name, errors)], PAPER_ERROR_THRESHOLD)?;
    }
    Ok(())
}

/// The shares with their 95 % intervals and why boxes were not scored.
fn print_summary(summary: &ExternalSummary, dataset: &Path) {
    println!(
        "{} on {} ({} instances), 95 % Clopper–Pearson intervals:",
        summary.system,
        dataset.display(),
        summary.instances
    );
    let line = |what: &str, share: f64| {
        let hits = (share * summary.instances as f64).round() as u64;
        let (low, high) = clopper_pearson(hits, summary.instances as u64, 0.95);
        println!(
            "  {what}: {:.1} % [{:.1}, {:.1}] ({hits}/{})",
            100.0 * share,
            100.0 * low,
            100.0 * high,
            summary.instances
        );
    };
    line("cube MSSD < 0.1 d", summary.cube_mssd_recall_010);
    line("cube MSSD < 0.05 d", summary.cube_mssd_recall_005);
    line("exact MSSD < 0.1 d", summary.mssd_recall_010);
    println!(
        "  not found {}, fit failed {}, system errors {} (restarts {}); {:.3} s per call",
        summary.not_found,
        summary.fit_failed,
        summary.system_errors,
        summary.restarts,
        summary.mean_seconds_per_call
    );
}
