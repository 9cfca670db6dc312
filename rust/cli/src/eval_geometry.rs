//! `boxpose eval-geometry`: the heatmap → pose stage (paper steps 5–7) on a rendered dataset's
//! ground truth, with the paper's failure modes injected on demand.
//!
//! For every instance it draws the heatmap a perfect network would output — a Gaussian at each
//! true corner, jittered by `--noise-m` — in a crop around the box, optionally adds confident
//! outlier peaks, then runs NMS, back-projection and each pose fit, and scores them against the
//! true pose (`boxpose_geometry::synthetic`; this module draws the noise and writes the table).

use std::path::PathBuf;

use anyhow::Context;
use boxpose_data::{Dataset, Instance, Intrinsics};
use boxpose_geometry::BoxModel;
use boxpose_geometry::heatmap::VoxelCoord;
use boxpose_geometry::{pipeline, synthetic};

use boxpose_learn::fit_table::{self, FitRow};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder with rendered frames.
    dataset: PathBuf,
    /// Output Parquet file (a file path, not a folder): one row per instance and method.
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

pub fn run(args: &Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.resolution >= 8,
        "--resolution {} is too coarse (use at least 8)",
        args.resolution
    );
    // checked before the work: `eval --out` is a folder, this one a file
    anyhow::ensure!(
        !args.out.is_dir(),
        "--out {} is a folder: eval-geometry writes one Parquet file, so give its path (e.g. --out {})",
        args.out.display(),
        args.out.join("eval_geometry.parquet").display()
    );
    // its own earlier table is replaced; any other file (another command's table, a manifest)
    // is not this command's to overwrite
    if args.out.exists() {
        boxpose_data::read_shard(&args.out, &boxpose_data::schema::EVAL_GEOMETRY).map_err(|e| {
            anyhow::anyhow!(
                "--out {} exists and is not an eval-geometry table ({e}): choose a new path for --out",
                args.out.display()
            )
        })?;
    }
    let dataset = Dataset::open(&args.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let frames = dataset.frames()?;
    let total = frames.instance_count(|_| true);
    let bar = ProgressBar::new(total as u64).with_style(ProgressStyle::with_template(
        "fitting {bar:30} {pos}/{len} instances [{elapsed_precise}<{eta_precise}]",
    )?);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut rows = Vec::new();
    for frame in frames {
        let frame = &frame?;
        for instance in &frame.instances {
            bar.inc(1);
            if instance.visible_fraction < args.min_visible_fraction {
                continue;
            }
            let scored =
                evaluate(args, &frame.intrinsics, instance, &mut rng).with_context(|| {
                    format!(
                        "scene {} frame {} object {}",
                        instance.scene_id, instance.frame_id, instance.object_id
                    )
                })?;
            rows.extend(scored);
        }
    }
    bar.finish_and_clear();
    anyhow::ensure!(
        !rows.is_empty(),
        "{}: no instance is visible enough to evaluate",
        args.dataset.display()
    );
    boxpose_data::write_table(
        &args.out,
        &boxpose_data::schema::EVAL_GEOMETRY,
        fit_table::columns(&rows),
    )?;
    print_summary(args, &rows);
    println!("per-instance metrics: {}", args.out.display());
    Ok(())
}

/// The instance's fits on a perfect network's heatmap: its true corners jittered by `--noise-m`,
/// with `--outliers` spurious peaks placed uniformly in the crop.
fn evaluate(
    args: &Args,
    k: &Intrinsics,
    instance: &Instance,
    rng: &mut ChaCha8Rng,
) -> anyhow::Result<Vec<FitRow>> {
    let model = BoxModel::new(Vector3::from(instance.size))?;
    let truth = pipeline::isometry(
        instance.camera_box.quat_wxyz,
        instance.camera_box.translation,
    );
    let grid = synthetic::crop_grid(
        [k.fx, k.fy, k.cx, k.cy],
        &instance.corners_px,
        instance.camera_box.translation[2],
        model.diameter(),
        args.resolution,
    );
    let noise = Normal::new(0.0, args.noise_m.max(0.0))?;
    let corners: Vec<Point3<f64>> = instance
        .corners_camera
        .iter()
        .map(|c| Point3::from(*c) + Vector3::from_fn(|_, _| noise.sample(rng)))
        .collect();
    let n = args.resolution as f64;
    let outliers: Vec<VoxelCoord> = (0..args.outliers)
        .map(|_| VoxelCoord {
            z_bin: rng.random_range(0.0..n),
            v: rng.random_range(0.0..n),
            u: rng.random_range(0.0..n),
        })
        .collect();
    let fits = synthetic::fit_synthetic_heatmap(
        &model,
        &truth,
        &grid,
        args.resolution,
        &corners,
        &outliers,
    )?;
    Ok(fits
        .into_iter()
        .map(|(method, outcome)| FitRow {
            scene_id: instance.scene_id,
            frame_id: instance.frame_id,
            object_id: instance.object_id,
            method,
            diameter_m: model.diameter(),
            outcome,
        })
        .collect())
}

fn print_summary(args: &Args, rows: &[FitRow]) {
    println!(
        "heatmap → pose on ground truth: corner noise {} m, {} outlier peak(s), {}³ voxels",
        args.noise_m, args.outliers, args.resolution
    );
    crate::fit_summary::print(rows);
}
