//! `boxpose eval-geometry`: the heatmap → pose stage (paper steps 5–7) on a rendered dataset's
//! ground truth, with the paper's failure modes injected on demand.
//!
//! For every instance it draws the heatmap a perfect network would output — a Gaussian at each
//! true corner, jittered by `--noise-m` — in a crop around the box, optionally adds confident
//! outlier peaks, then runs NMS, back-projection and each pose fit, and scores them against the
//! true pose. It isolates the geometry from the network: what fails here fails with any network.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use arrow::array::{ArrayRef, Float64Array, Int32Array, Int64Array, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;
use boxpose_data::{Dataset, Instance, Intrinsics};
use boxpose_geometry::heatmap::{
    self, CropTransform, DepthBins, HeatmapDims, NmsParams, PinholeIntrinsics, VoxelCoord, VoxelGrid,
};
use boxpose_geometry::{BoxModel, metrics, robust, size_fit};
use boxpose_geometry::correspondence::{fast_exact_search, paper_exact_search};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Gaussian width of the drawn peaks and of the NMS kernel, in voxels.
const PEAK_SIGMA_VOXELS: f64 = 1.5;
/// Crop and depth range extend this far beyond the box's projected corners / diameter.
const CROP_MARGIN: f64 = 1.2;
/// Score of a true corner's peak; outliers get 1.0, so they rank first, as in the paper's failures.
const CORNER_PEAK_SCORE: f32 = 0.8;
/// Peaks the paper's search fits (m).
const PAPER_M: usize = 5;

#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder with rendered frames.
    dataset: PathBuf,
    /// Output Parquet file: one row per instance and method.
    #[arg(long, default_value = "results/eval_geometry.parquet")]
    out: PathBuf,
    /// Standard deviation of the noise added to each true corner before drawing its peak (m).
    #[arg(long, default_value_t = 0.003)]
    noise_m: f64,
    /// Confident spurious peaks per instance (the paper's counterexamples had four).
    #[arg(long, default_value_t = 0)]
    outliers: usize,
    /// Heatmap voxels per axis (depth bins = height = width).
    #[arg(long, default_value_t = 64)]
    resolution: usize,
    /// Skip instances with a smaller visible fraction (a detector would not crop them).
    #[arg(long, default_value_t = 0.1)]
    min_visible_fraction: f32,
    /// Seed of the corner noise and outlier placement.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

struct Row {
    scene_id: i64,
    frame_id: i32,
    object_id: i32,
    method: &'static str,
    diameter_m: f64,
    outcome: Result<Scores, String>,
}

struct Scores {
    paper_error: f64,
    mssd_m: f64,
    add_s_m: f64,
    rotation_error_deg: f64,
    translation_error_m: f64,
    fit_time_us: f64,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    anyhow::ensure!(args.resolution >= 8, "--resolution {} is too coarse (use at least 8)", args.resolution);
    let dataset = Dataset::open(&args.dataset)?;
    let frames: Vec<_> = dataset.frames()?.collect::<Result<_, _>>()?;
    let total: usize = frames.iter().map(|f| f.instances.len()).sum();
    let bar = ProgressBar::new(total as u64).with_style(ProgressStyle::with_template(
        "fitting {bar:30} {pos}/{len} instances [{elapsed_precise}<{eta_precise}]",
    )?);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut rows = Vec::new();
    for frame in &frames {
        for instance in &frame.instances {
            bar.inc(1);
            if instance.visible_fraction < args.min_visible_fraction {
                continue;
            }
            let scored = evaluate(args, &frame.intrinsics, instance, &mut rng)
                .with_context(|| format!("scene {} frame {} object {}", instance.scene_id, instance.frame_id, instance.object_id))?;
            rows.extend(scored);
        }
    }
    bar.finish_and_clear();
    anyhow::ensure!(!rows.is_empty(), "{}: no instance is visible enough to evaluate", args.dataset.display());
    boxpose_data::write_parquet(&args.out, schema(), &[to_batch(&rows)?])?;
    print_summary(args, &rows);
    println!("per-instance metrics: {}", args.out.display());
    Ok(())
}

fn pose(quat_wxyz: [f64; 4], translation: [f64; 3]) -> Isometry3<f64> {
    let [w, x, y, z] = quat_wxyz;
    Isometry3::from_parts(Translation3::from(Vector3::from(translation)), UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)))
}

/// Crop (square, around the projected corners) and depth range (around the box centre) of the
/// heatmap, as the keypoint network's input crop would be.
fn voxel_grid(k: &Intrinsics, instance: &Instance, diameter: f64, resolution: usize) -> VoxelGrid {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &instance.corners_px {
        for a in 0..2 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let half = (hi[0] - lo[0]).max(hi[1] - lo[1]) / 2.0 * CROP_MARGIN + 1.0;
    let scale = 2.0 * half / resolution as f64;
    let depth_half = diameter / 2.0 * CROP_MARGIN;
    VoxelGrid {
        intrinsics: PinholeIntrinsics { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy },
        crop: CropTransform { x0: (lo[0] + hi[0]) / 2.0 - half + 0.5, y0: (lo[1] + hi[1]) / 2.0 - half + 0.5, sx: scale, sy: scale },
        depth: DepthBins { z_ref: instance.camera_box.translation[2], z_min: -depth_half, bin_size: 2.0 * depth_half / resolution as f64 },
    }
}

fn evaluate(args: &Args, k: &Intrinsics, instance: &Instance, rng: &mut ChaCha8Rng) -> anyhow::Result<Vec<Row>> {
    let model = BoxModel::new(Vector3::from(instance.size))?;
    let truth = pose(instance.camera_box.quat_wxyz, instance.camera_box.translation);
    let truth_corners: Vec<Point3<f64>> = instance.corners_camera.iter().map(|c| Point3::from(*c)).collect();
    let grid = voxel_grid(k, instance, model.diameter(), args.resolution);
    let n = args.resolution;
    let dims = HeatmapDims { depth: n, height: n, width: n };

    let noise = Normal::new(0.0, args.noise_m.max(0.0))?;
    let corners = truth_corners
        .iter()
        .map(|c| grid.project(&(c + Vector3::from_fn(|_, _| noise.sample(rng)))))
        .collect::<Result<Vec<_>, _>>()?;
    let outliers: Vec<VoxelCoord> = (0..args.outliers)
        .map(|_| VoxelCoord { z_bin: rng.random_range(0.0..n as f64), v: rng.random_range(0.0..n as f64), u: rng.random_range(0.0..n as f64) })
        .collect();
    let mut volume = heatmap::render_target_heatmap(dims, &corners, PEAK_SIGMA_VOXELS)?;
    volume.iter_mut().for_each(|v| *v *= CORNER_PEAK_SCORE);
    if !outliers.is_empty() {
        let spurious = heatmap::render_target_heatmap(dims, &outliers, PEAK_SIGMA_VOXELS)?;
        volume.iter_mut().zip(spurious).for_each(|(v, s)| *v = v.max(s));
    }

    let peaks = heatmap::non_maximum_suppression(&volume, dims, &NmsParams { count: 8, sigma: PEAK_SIGMA_VOXELS, refine_radius: 1 })?;
    let points = peaks.iter().map(|p| grid.back_project(&p.coord)).collect::<Result<Vec<_>, _>>()?;
    let scores: Vec<f64> = peaks.iter().map(|p| p.score as f64).collect();

    // `fitted` and `fitted_pose` give the paper's error (corner sets, so axis labels do not
    // matter); `estimate` is the pose in the true model's axis labels for the pose metrics.
    let score = |fitted: &BoxModel, fitted_pose: &Isometry3<f64>, estimate: &Isometry3<f64>, start: Instant| -> Result<Scores, String> {
        let fit_time_us = start.elapsed().as_secs_f64() * 1e6;
        Ok(Scores {
            paper_error: metrics::paper_error(fitted, fitted_pose, &truth_corners).map_err(|e| e.to_string())?,
            mssd_m: metrics::mssd(&model, estimate, &truth).map_err(|e| e.to_string())?,
            add_s_m: metrics::add_s(&model, estimate, &truth).map_err(|e| e.to_string())?,
            rotation_error_deg: metrics::rotation_error_deg(&model, estimate, &truth).map_err(|e| e.to_string())?,
            translation_error_m: metrics::translation_error(estimate, &truth).map_err(|e| e.to_string())?,
            fit_time_us,
        })
    };
    let mut methods: Vec<(&'static str, Result<Scores, String>)> = Vec::new();
    let start = Instant::now();
    let fit = paper_exact_search(&model, &points, &scores, PAPER_M).map_err(|e| e.to_string());
    methods.push(("paper_exact", fit.and_then(|f| score(&model, &f.pose, &f.pose, start))));
    let start = Instant::now();
    let fit = fast_exact_search(&model, &points, &scores, PAPER_M).map_err(|e| e.to_string());
    methods.push(("fast_exact", fit.and_then(|f| score(&model, &f.pose, &f.pose, start))));
    let start = Instant::now();
    let fit = robust::robust_fit(&model, &points, &robust::RobustParams::for_box(&model)).map_err(|e| e.to_string());
    methods.push(("robust", fit.and_then(|f| score(&model, &f.pose, &f.pose, start))));
    let start = Instant::now();
    let fit = size_fit::fit_pose_and_size(&points, &size_fit::SizeFitParams::default()).map_err(|e| e.to_string());
    methods.push(("size_and_pose", fit.and_then(|f| score(&f.model, &f.pose, &relabel_axes(&f.pose, &truth), start))));

    Ok(methods
        .into_iter()
        .map(|(method, outcome)| Row {
            scene_id: instance.scene_id,
            frame_id: instance.frame_id,
            object_id: instance.object_id,
            method,
            diameter_m: model.diameter(),
            outcome,
        })
        .collect())
}

/// A box of unknown size has no preferred axis labels: the size fit may call the true x axis
/// its z. Of the 24 proper signed axis permutations of the fitted frame, returns the one whose
/// axes best align with the true ones, so that the pose metrics compare like with like.
fn relabel_axes(fitted: &Isometry3<f64>, truth: &Isometry3<f64>) -> Isometry3<f64> {
    let (fitted_axes, true_axes) = (fitted.rotation.to_rotation_matrix(), truth.rotation.to_rotation_matrix());
    let mut best = (f64::NEG_INFINITY, *fitted);
    for perm in [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]] {
        for signs in 0..8 {
            let relabel = nalgebra::Matrix3::from_fn(|r, c| if perm[c] == r { if signs >> c & 1 == 1 { -1.0 } else { 1.0 } } else { 0.0 });
            if relabel.determinant() < 0.0 {
                continue;
            }
            let candidate = fitted_axes.matrix() * relabel;
            let alignment = (candidate.transpose() * true_axes.matrix()).trace();
            if alignment > best.0 {
                let rotation = UnitQuaternion::from_matrix(&candidate);
                best = (alignment, Isometry3::from_parts(fitted.translation, rotation));
            }
        }
    }
    best.1
}

fn schema() -> Arc<Schema> {
    let f64_field = |name: &str| Field::new(name, DataType::Float64, true);
    Arc::new(Schema::new(vec![
        Field::new("scene_id", DataType::Int64, false),
        Field::new("frame_id", DataType::Int32, false),
        Field::new("object_id", DataType::Int32, false),
        Field::new("method", DataType::Utf8, false),
        Field::new("diameter_m", DataType::Float64, false),
        f64_field("paper_error"),
        f64_field("mssd_m"),
        f64_field("add_s_m"),
        f64_field("rotation_error_deg"),
        f64_field("translation_error_m"),
        f64_field("fit_time_us"),
        Field::new("fit_error", DataType::Utf8, true),
    ]))
}

fn to_batch(rows: &[Row]) -> anyhow::Result<RecordBatch> {
    let metric = |get: fn(&Scores) -> f64| -> ArrayRef {
        Arc::new(rows.iter().map(|r| r.outcome.as_ref().ok().map(get)).collect::<Float64Array>())
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(rows.iter().map(|r| r.scene_id).collect::<Int64Array>()),
        Arc::new(rows.iter().map(|r| r.frame_id).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.object_id).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| Some(r.method)).collect::<StringArray>()),
        Arc::new(rows.iter().map(|r| r.diameter_m).collect::<Float64Array>()),
        metric(|s| s.paper_error),
        metric(|s| s.mssd_m),
        metric(|s| s.add_s_m),
        metric(|s| s.rotation_error_deg),
        metric(|s| s.translation_error_m),
        metric(|s| s.fit_time_us),
        Arc::new(rows.iter().map(|r| r.outcome.as_ref().err().map(String::as_str)).collect::<StringArray>()),
    ];
    Ok(RecordBatch::try_new(schema(), columns)?)
}

fn print_summary(args: &Args, rows: &[Row]) {
    println!(
        "heatmap → pose on ground truth: corner noise {} m, {} outlier peak(s), {}³ voxels",
        args.noise_m, args.outliers, args.resolution
    );
    println!("{:<14} {:>9} {:>11} {:>11} {:>13} {:>13} {:>12}", "method", "instances", "MSSD<0.05d", "MSSD<0.1d", "median MSSD", "mean error", "mean time");
    for method in ["paper_exact", "fast_exact", "robust", "size_and_pose"] {
        let of_method: Vec<&Row> = rows.iter().filter(|r| r.method == method).collect();
        let scored: Vec<(&Scores, f64)> = of_method.iter().filter_map(|r| r.outcome.as_ref().ok().map(|s| (s, r.diameter_m))).collect();
        if scored.is_empty() {
            println!("{method:<14} {:>9} every fit failed", of_method.len());
            continue;
        }
        let n = scored.len() as f64;
        let recall = |fraction: f64| scored.iter().filter(|(s, d)| s.mssd_m < fraction * d).count() as f64 / n;
        let mut mssd: Vec<f64> = scored.iter().map(|(s, _)| s.mssd_m).collect();
        mssd.sort_by(f64::total_cmp);
        println!(
            "{method:<14} {:>9} {:>10.1}% {:>10.1}% {:>11.4} m {:>13.6} {:>9.0} µs",
            of_method.len(),
            100.0 * recall(0.05),
            100.0 * recall(0.1),
            mssd[mssd.len() / 2],
            scored.iter().map(|(s, _)| s.paper_error).sum::<f64>() / n,
            scored.iter().map(|(s, _)| s.fit_time_us).sum::<f64>() / n,
        );
    }
}
