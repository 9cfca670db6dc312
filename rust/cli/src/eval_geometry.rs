//! `boxpose eval-geometry`: the heatmap → pose stage (paper steps 5–7) on a rendered dataset's
//! ground truth, with the paper's failure modes injected on demand.
//!
//! For every instance it draws the heatmap a perfect network would output — a Gaussian at each
//! true corner, jittered by `--noise-m` — in a crop around the box, optionally adds confident
//! outlier peaks, then runs NMS, back-projection and each pose fit, and scores them against the
//! true pose. It isolates the geometry from the network: what fails here fails with any network.

use std::path::PathBuf;

use anyhow::Context;
use boxpose_data::{Dataset, Instance, Intrinsics};
use boxpose_geometry::BoxModel;
use boxpose_geometry::heatmap::{
    self, CropTransform, DepthBins, HeatmapDims, NmsParams, PinholeIntrinsics, VoxelCoord,
    VoxelGrid,
};
use boxpose_geometry::pipeline;

use boxpose_learn::fit_table::{self, FitRow};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Gaussian width of the drawn peaks and of the NMS kernel, in voxels.
const PEAK_SIGMA_VOXELS: f64 = 1.5;
/// Crop and depth range extend this far beyond the box's projected corners / diameter.
const CROP_MARGIN: f64 = 1.2;
/// Score of a true corner's peak; outliers get 1.0, so they rank first, as in the paper's failures.
const CORNER_PEAK_SCORE: f32 = 0.8;

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
        intrinsics: PinholeIntrinsics {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
        },
        crop: CropTransform {
            x0: (lo[0] + hi[0]) / 2.0 - half + 0.5,
            y0: (lo[1] + hi[1]) / 2.0 - half + 0.5,
            sx: scale,
            sy: scale,
        },
        depth: DepthBins {
            z_ref: instance.camera_box.translation[2],
            z_min: -depth_half,
            bin_size: 2.0 * depth_half / resolution as f64,
        },
    }
}

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
    let truth_corners: Vec<Point3<f64>> = instance
        .corners_camera
        .iter()
        .map(|c| Point3::from(*c))
        .collect();
    let grid = voxel_grid(k, instance, model.diameter(), args.resolution);
    let n = args.resolution;
    let dims = HeatmapDims {
        depth: n,
        height: n,
        width: n,
    };

    let noise = Normal::new(0.0, args.noise_m.max(0.0))?;
    let corners = truth_corners
        .iter()
        .map(|c| grid.project(&(c + Vector3::from_fn(|_, _| noise.sample(rng)))))
        .collect::<Result<Vec<_>, _>>()?;
    let outliers: Vec<VoxelCoord> = (0..args.outliers)
        .map(|_| VoxelCoord {
            z_bin: rng.random_range(0.0..n as f64),
            v: rng.random_range(0.0..n as f64),
            u: rng.random_range(0.0..n as f64),
        })
        .collect();
    let mut volume = heatmap::render_target_heatmap(dims, &corners, PEAK_SIGMA_VOXELS)?;
    volume.iter_mut().for_each(|v| *v *= CORNER_PEAK_SCORE);
    if !outliers.is_empty() {
        let spurious = heatmap::render_target_heatmap(dims, &outliers, PEAK_SIGMA_VOXELS)?;
        volume
            .iter_mut()
            .zip(spurious)
            .for_each(|(v, s)| *v = v.max(s));
    }

    let peaks = heatmap::non_maximum_suppression(
        &volume,
        dims,
        &NmsParams {
            count: 8,
            sigma: PEAK_SIGMA_VOXELS,
            refine_radius: 1,
        },
    )?;
    let points = peaks
        .iter()
        .map(|p| grid.back_project(&p.coord))
        .collect::<Result<Vec<_>, _>>()?;
    let scores: Vec<f64> = peaks.iter().map(|p| p.score as f64).collect();

    // No image here (the peaks are synthetic), so no depth check of mirror ties.
    Ok(
        pipeline::fit_and_score(&model, &truth, &points, &scores, None)
            .into_iter()
            .map(|(method, outcome)| FitRow {
                scene_id: instance.scene_id,
                frame_id: instance.frame_id,
                object_id: instance.object_id,
                method,
                diameter_m: model.diameter(),
                outcome,
            })
            .collect(),
    )
}

fn print_summary(args: &Args, rows: &[FitRow]) {
    println!(
        "heatmap → pose on ground truth: corner noise {} m, {} outlier peak(s), {}³ voxels",
        args.noise_m, args.outliers, args.resolution
    );
    crate::fit_summary::print(rows);
}
