//! `boxpose eval`: the trained keypoint network over a dataset — per instance, the heatmap's
//! error, corner recall and every pose fit's metrics (Parquet), a summary table, and the paper's
//! Fig. 6: a log-scale histogram of the paper's error, as PNG.

use std::path::{Path, PathBuf};

use anyhow::Context;
use boxpose_data::Dataset;
use boxpose_geometry::metrics::{PAPER_ERROR_THRESHOLD, normalized_paper_error};
use boxpose_geometry::pipeline::Method;
use boxpose_learn::backend::BackendKind;
use boxpose_learn::evaluation::{self, Crops, DatasetEvaluation};
use boxpose_learn::inference::KeypointModel;
use boxpose_learn::segmentation::SegmenterModel;
use boxpose_search_stats::stats::clopper_pearson;
use indicatif::{ProgressBar, ProgressStyle};

use boxpose_report::plots;

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// Dataset folder with rendered frames.
    #[arg(required = true)]
    dataset: Option<PathBuf>,
    /// Trained model folder (network.toml + model.bpk), e.g. a run's model/ or models/<name>.
    #[arg(long, default_value = "models/keypoint-slim", value_parser = crate::shipped_path)]
    model: PathBuf,
    /// Output folder: eval.parquet, summary.json, paper_error_hist.png.
    #[arg(long, default_value = "results/eval")]
    out: PathBuf,
    /// Skip instances with a smaller visible fraction (a detector would not crop them).
    #[arg(long, default_value_t = 0.25)]
    min_visible_fraction: f32,
    /// Where the crops come from: ground-truth boxes, or the segmenter's (a box it misses
    /// counts as a failed fit), so that the errors of each stage can be told apart.
    #[arg(long, value_enum, default_value_t = Crops::Gt)]
    crops: Crops,
    /// Trained segmenter folder, for --crops predicted.
    #[arg(long, default_value = "models/segmenter-slim", value_parser = crate::shipped_path)]
    segmenter: PathBuf,
    /// Only the scenes a training run held out: scene_id % N == 0 (its config's val_modulus).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(2..))]
    held_out: Option<u32>,
    /// Half-width in voxels of the window averaged around each heatmap peak for its sub-voxel
    /// position (0: the voxel centre), instead of the model's `peak_refine_radius`.
    #[arg(long, value_name = "VOXELS")]
    peak_refine_radius: Option<usize>,
    /// Lay each known-size fit on the depth image (the points of the box's visible faces), the
    /// robust fit after the depth image chose among the poses its peaks allow, as `boxpose
    /// search --refine-depth` does.
    #[arg(long)]
    refine_depth: bool,
    /// Perceive the frames' simulated sensor depth (`sensor_depth_m_f32le`, rendered with the
    /// recipe's `[render] sensor_depth = true`) instead of the exact render depth, as `boxpose
    /// search --sensor-depth` does; poses are scored against the exact truth.
    #[arg(long)]
    sensor_depth: bool,
    /// Crops per forward pass.
    #[arg(long, default_value_t = 16)]
    batch_size: usize,
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
    /// Evaluate another perception system instead of this project's networks and fits, as
    /// `search --sut` does: `exec:COMMAND` (a long-lived process speaking boxpose-sut/1) or
    /// `python:MODULE:CALLABLE`. It gets each box's whole frame (with --crops gt its visible box
    /// and mask too) and answers a pose; its rows (method `external`) pair with an own `eval`
    /// run's in `eval compare --method robust,external`. A crash or timeout is counted apart.
    #[arg(long, value_name = "SPEC", conflicts_with_all = ["model", "segmenter", "peak_refine_radius", "refine_depth", "batch_size", "backend"])]
    sut: Option<String>,
    /// Seconds the --sut process may take to answer one box (or to start).
    #[arg(long, default_value_t = 60.0, value_name = "SECONDS", requires = "sut")]
    sut_timeout: f64,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Pair two `eval` runs of the same held-out frames box by box: each run's success rate
    /// (cube MSSD < FRACTION × diameter; a box not found or not fitted fails) with its 95 %
    /// interval, the boxes fixed and newly failing, and McNemar's exact p — as `search compare`
    /// does for search samples.
    #[command(after_help = "Example:
          boxpose eval datasets/generated/train_large --held-out 10 --model models/keypoint-slim --out results/before
          boxpose eval datasets/generated/train_large --held-out 10 --model runs/tuned/model --out results/after
          boxpose eval compare results/before results/after")]
    Compare {
        /// The `eval --out` folder before the change.
        before: PathBuf,
        /// The one after it.
        after: PathBuf,
        /// The fit compared: paper_exact, fast_exact, robust, size_and_pose, …, or external (an
        /// `eval --sut` run); BEFORE,AFTER compares two, e.g. `robust,external` for the own
        /// pipeline against another system on the same boxes.
        #[arg(long, default_value = "robust", value_name = "METHOD[,METHOD]")]
        method: String,
        /// A box succeeds when its cube MSSD is below this fraction of its diameter.
        #[arg(long, default_value_t = 0.1)]
        fraction: f64,
        /// Also write the comparison (with the fixed and new boxes) to this JSON file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

/// `eval compare`.
fn compare(
    before: &Path,
    after: &Path,
    method: &str,
    fraction: f64,
    json: Option<&Path>,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        fraction.is_finite() && fraction > 0.0,
        "--fraction {fraction} must be a positive number"
    );
    let (method_before, method_after) = method.split_once(',').unwrap_or((method, method));
    let outcomes = |folder: &Path, method: &str| {
        boxpose_search::compare::eval_outcomes(&folder.join("eval.parquet"), method, fraction)
            .with_context(|| {
                format!(
                    "{}: give the --out folder of a `boxpose eval` run",
                    folder.display()
                )
            })
    };
    let c = boxpose_search::compare::pair(
        &outcomes(before, method_before)?,
        &outcomes(after, method_after)?,
    );
    anyhow::ensure!(
        c.pairs > 0,
        "{} and {} share no box: were they run on the same dataset and --held-out?",
        before.display(),
        after.display()
    );
    let rate = |r: &boxpose_search::compare::Rate| {
        let succeeded = r.samples - r.failures;
        let (lo, hi) = clopper_pearson(succeeded, r.samples, 0.95);
        format!(
            "{:.1} % [{:.1}, {:.1}] ({succeeded} of {})",
            100.0 * succeeded as f64 / r.samples as f64,
            100.0 * lo,
            100.0 * hi,
            r.samples
        )
    };
    println!(
        "{} boxes paired ({} unpaired); success (cube MSSD < {fraction} d, {method}):",
        c.pairs, c.unpaired
    );
    println!("  before {}  {}", rate(&c.before), before.display());
    println!("  after  {}  {}", rate(&c.after), after.display());
    println!(
        "  fixed {} (failed before only), new {} (failed after only), failed both {}",
        c.fixed.len(),
        c.new.len(),
        c.failed_both
    );
    println!("  McNemar exact p = {:.3e}", c.mcnemar_p);
    if let Some(path) = json {
        boxpose_data::write_file_atomically(path, serde_json::to_string_pretty(&c)?.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(Command::Compare {
        before,
        after,
        method,
        fraction,
        json,
    }) = &args.command
    {
        return compare(before, after, method, *fraction, json.as_deref());
    }
    let dataset_path = args.dataset.as_deref().context("give a dataset folder")?;
    if let Some(spec) = &args.sut {
        return run_external(args, spec, dataset_path);
    }
    // its own earlier output is rewritten (its stale files removed below)
    let _claim = boxpose_data::output_folder::claim(&args.out, "--out", "eval", &["eval.parquet"])?;
    let mut model = KeypointModel::load(&args.model, args.backend.device()?)?;
    if let Some(radius) = args.peak_refine_radius {
        model.config.peak_refine_radius = radius;
    }
    let segmenter = match args.crops {
        Crops::Predicted => Some(SegmenterModel::load(
            &args.segmenter,
            args.backend.device()?,
        )?),
        Crops::Gt => None,
    };
    let dataset = Dataset::open(dataset_path)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let evaluated = evaluate(args, &model, segmenter.as_ref(), &dataset)?;
    anyhow::ensure!(
        !evaluated.evals.is_empty(),
        "{}: no instance is visible enough to evaluate",
        dataset_path.display()
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    evaluated.write_table(&args.out.join("eval.parquet"))?;
    let summary = evaluation::summarize(&evaluated.evals);
    boxpose_data::write_file_atomically(
        &args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    let histogram = write_histogram(args, dataset_path, &evaluated)?;
    let segmentation_json = args.out.join("segmentation.json");
    match &segmenter {
        Some(_) => boxpose_data::write_file_atomically(
            &segmentation_json,
            serde_json::to_string_pretty(&evaluated.detections.scores())?.as_bytes(),
        )?,
        None => boxpose_data::output_folder::remove_stale(&segmentation_json)?,
    }
    print_report(
        args,
        dataset_path,
        &evaluated,
        &summary,
        segmenter.is_some(),
    );
    match histogram {
        Some(path) => println!("error histogram (paper Fig. 6): {}", path.display()),
        None => println!("no fit succeeded: no error histogram"),
    }
    Ok(())
}

/// `eval --sut`: another system through the protocol instead of the own networks.
fn run_external(args: &Args, spec: &str, dataset: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.sut_timeout.is_finite() && args.sut_timeout > 0.0,
        "--sut-timeout {} must be a positive number of seconds",
        args.sut_timeout
    );
    crate::eval_external::run(&crate::eval_external::Settings {
        spec,
        timeout: std::time::Duration::from_secs_f64(args.sut_timeout),
        dataset,
        out: &args.out,
        crops: args.crops,
        min_visible_fraction: args.min_visible_fraction,
        held_out: args.held_out,
        sensor_depth: args.sensor_depth,
    })
}

/// Every chosen box of the dataset (the held-out scenes with --held-out), with a progress bar.
fn evaluate(
    args: &Args,
    model: &KeypointModel,
    segmenter: Option<&SegmenterModel>,
    dataset: &Dataset,
) -> anyhow::Result<DatasetEvaluation> {
    let options = evaluation::DatasetOptions {
        held_out: args.held_out,
        min_visible_fraction: args.min_visible_fraction,
        sensor_depth: args.sensor_depth,
        batch_size: args.batch_size,
        refine_depth: args.refine_depth,
    };
    let bar = ProgressBar::new(0).with_style(ProgressStyle::with_template(
        "evaluating {bar:30} {pos}/{len} instances [{elapsed_precise}<{eta_precise}]",
    )?);
    let evaluated =
        evaluation::evaluate_dataset(model, segmenter, dataset, &options, |done, total| {
            bar.set_length(total);
            bar.set_position(done);
        })?;
    bar.finish_and_clear();
    Ok(evaluated)
}

/// The histogram of the paper's error of three fits, normalised by the box's d²/3 so that the
/// paper's unit-box threshold marks the counterexamples for every box size; None (and an earlier
/// histogram removed) when no fit succeeded.
fn write_histogram(
    args: &Args,
    dataset_path: &Path,
    evaluated: &DatasetEvaluation,
) -> anyhow::Result<Option<PathBuf>> {
    let errors = |method: Method| -> Vec<f64> {
        evaluated
            .fit_rows
            .iter()
            .filter(|r| r.method == method)
            .filter_map(|r| {
                let scores = r.outcome.scores()?;
                Some(normalized_paper_error(scores.paper_error, r.diameter_m))
            })
            .collect()
    };
    let series = [
        ("paper's search", errors(Method::PaperExact)),
        ("robust fit", errors(Method::Robust)),
        ("size + pose fit", errors(Method::SizeAndPose)),
    ];
    let histogram = args.out.join("paper_error_hist.png");
    if !series.iter().any(|(_, e)| e.iter().any(|v| *v > 0.0)) {
        boxpose_data::output_folder::remove_stale(&histogram)?;
        return Ok(None);
    }
    let title = format!(
        "paper's error on {} ({} instances)",
        dataset_path
            .file_name()
            .unwrap_or_default()
            .to_string_lossy(),
        evaluated.evals.len()
    );
    plots::error_histogram(&histogram, &title, &series, PAPER_ERROR_THRESHOLD)?;
    Ok(Some(histogram))
}

/// What was evaluated, the segmenter's scores, corner recall, the fit table and the targets.
fn print_report(
    args: &Args,
    dataset_path: &Path,
    evaluated: &DatasetEvaluation,
    summary: &evaluation::Summary,
    with_segmenter: bool,
) {
    let evals = &evaluated.evals;
    let crops = match args.crops {
        Crops::Gt => "ground-truth crops",
        Crops::Predicted => "the segmenter's crops",
    };
    println!(
        "keypoint network {} on {} ({} instances, {crops})",
        args.model.display(),
        dataset_path.display(),
        evals.len()
    );
    if with_segmenter {
        let s = evaluated.detections.scores();
        println!(
            "segmenter {}: mask AP {:.3} (AP50 {:.3}), bbox AP {:.3} (AP50 {:.3}); {} detections for {} visible boxes; {} of {} evaluated boxes found",
            args.segmenter.display(),
            s.mask_ap,
            s.mask_ap50,
            s.bbox_ap,
            s.bbox_ap50,
            s.detections,
            s.true_instances,
            evals.iter().filter(|e| !e.missed).count(),
            evals.len()
        );
    }
    println!(
        "corner recall (peak within {:.0} mm): {:.1}%   heatmap MSE {:.3e}",
        evaluation::CORNER_RECALL_RADIUS_M * 1000.0,
        100.0 * summary.corner_recall,
        summary.heatmap_mse
    );
    crate::fit_summary::print(&evaluated.fit_rows);
    print_targets(summary);
    println!(
        "per-instance metrics: {}",
        args.out.join("eval.parquet").display()
    );
}

/// The learning targets' shares with their 95 % Clopper–Pearson intervals and counts.
fn print_targets(summary: &evaluation::Summary) {
    let line = |what: &str, share: f64, n: usize| {
        if n == 0 {
            println!("  {what}: no such box");
            return;
        }
        let hits = (share * n as f64).round() as u64;
        let (low, high) = clopper_pearson(hits, n as u64, 0.95);
        println!(
            "  {what}: {:.1} % [{:.1}, {:.1}] ({hits}/{n})",
            100.0 * share,
            100.0 * low,
            100.0 * high
        );
    };
    let n = summary.instances;
    println!("robust fit, 95 % Clopper–Pearson intervals:");
    line("cube MSSD < 0.1 d", summary.robust_cube_mssd_recall_010, n);
    line("cube MSSD < 0.05 d", summary.robust_cube_mssd_recall_005, n);
    line(
        "exact MSSD < 0.1 d, sides all ≥ 1 cm apart",
        summary.robust_mssd_recall_010_distinct_sides,
        summary.distinct_sides_instances,
    );
    line(
        "right quarter turn (exact MSSD < 0.1 d), two sides within 1 cm",
        summary.robust_right_quarter_turn_near_square,
        summary.near_square_instances,
    );
}
