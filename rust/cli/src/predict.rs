//! `boxpose predict`: an RGBD frame → per box: pose, size, the 8 fitted corners, the NMS peaks
//! with their scores and the fit's residual (Parquet and JSON), and an overlay PNG like the
//! paper's Fig. 5 (true box white, NMS peaks black, fitted box grey).
//!
//! The frame is a dataset row (`DATASET --scene S --frame F`) or files (`--rgb`, `--depth`,
//! `--intrinsics`). Boxes are cropped around the ground-truth boxes (`--crops gt`, dataset rows
//! only), around the boxes the segmenter finds (`--crops predicted`, and files without `--bbox`),
//! or around the bounding boxes given with `--bbox` (max exclusive).
//!
//! Each box goes through `inference::perceive`, the pipeline `boxpose eval` and the search run:
//! its peaks are fitted by the noise-adaptive pose-and-size fit (`size_and_pose` in eval's
//! tables, `--fit size` in the search; survives outlier peaks) or, with
//! `--size-fit least-squares`, by the former least-squares fit (`size_and_pose_ls`), for
//! comparison, and mirror ties are settled with the frame's depth image. Every fit comes with its
//! confidence (`adaptive::FitConfidence`: its own for the robust fit, the noise-adaptive
//! assessment of its box for least squares), printed and written in both tables.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use boxpose_data::{Dataset, Frame, Intrinsics};
use boxpose_geometry::pipeline::Method;
use boxpose_learn::backend::BackendKind;
use boxpose_learn::evaluation::{Crops, true_pose};
use boxpose_learn::inference::{KeypointModel, Perception};
use boxpose_learn::prediction::{self, BoxFit, Target};
use boxpose_learn::segmentation::SegmenterModel;
use nalgebra::Point3;

use boxpose_report::plots::{self, OverlayBox};

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SizeFit {
    /// Noise-adaptive hypotheses and refinement (`size_fit::robust_size_fit`): survives outlier
    /// peaks.
    Robust,
    /// The former least-squares scaling ICP (`size_fit::fit_pose_and_size`), for comparison.
    LeastSquares,
}

impl SizeFit {
    fn name(self) -> &'static str {
        match self {
            SizeFit::Robust => "robust",
            SizeFit::LeastSquares => "least-squares",
        }
    }

    fn method(self) -> Method {
        match self {
            SizeFit::Robust => Method::SizeAndPose,
            SizeFit::LeastSquares => Method::SizeAndPoseLeastSquares,
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder holding the frame (or give --rgb/--depth/--intrinsics instead).
    dataset: Option<PathBuf>,
    /// Scene of the frame in the dataset.
    #[arg(long, requires = "dataset")]
    scene: Option<i64>,
    /// Frame (view) of the scene.
    #[arg(long, default_value_t = 0)]
    frame: i32,
    /// How boxes are found: ground truth (dataset frames only) or the segmenter. Files use
    /// --bbox when given, else the segmenter.
    #[arg(long, value_enum, default_value_t = Crops::Gt)]
    crops: Crops,
    /// Trained segmenter folder, for --crops predicted.
    #[arg(long, default_value = "models/segmenter-slim", value_parser = crate::shipped_path)]
    segmenter: PathBuf,
    /// An 8-bit RGB PNG to predict on instead of a dataset frame.
    #[arg(long, requires_all = ["depth", "intrinsics"], conflicts_with = "dataset")]
    rgb: Option<PathBuf>,
    /// Its depth: a 16-bit PNG (0 = no measurement), the same size, in units of --depth-scale
    /// millimetres.
    #[arg(long)]
    depth: Option<PathBuf>,
    /// Millimetres per unit of the --depth PNG, as BOP's depth_scale. Default: a PNG in a BOP
    /// scene folder (`SCENE/depth/NNNNNN.png`, as `boxpose export bop` writes) takes its image's
    /// depth_scale from `SCENE/scene_camera.json`; any other PNG is read as millimetres (1).
    #[arg(long)]
    depth_scale: Option<f64>,
    /// Its intrinsics: fx,fy,cx,cy in pixels.
    #[arg(long, value_delimiter = ',')]
    intrinsics: Option<Vec<f64>>,
    /// A box to crop: x_min,y_min,x_max,y_max in pixels (repeat for several boxes).
    #[arg(long, value_delimiter = ',', action = clap::ArgAction::Append)]
    bbox: Vec<i32>,
    /// Trained model folder (network.toml + model.bpk).
    #[arg(long, default_value = "models/keypoint-slim", value_parser = crate::shipped_path)]
    model: PathBuf,
    /// Output folder: predictions.parquet, predictions.json, overlay.png.
    #[arg(long, default_value = "results/predict")]
    out: PathBuf,
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
    /// The pose-and-size fit of each box's peaks.
    #[arg(long, value_enum, default_value_t = SizeFit::Robust)]
    size_fit: SizeFit,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    // its own earlier predictions are replaced
    let _claim = boxpose_data::output_folder::claim(
        &args.out,
        "--out",
        "predict",
        &["predictions.parquet"],
    )?;
    let model = KeypointModel::load(&args.model, args.backend.device()?)?;
    let (frame, targets) = match (&args.dataset, &args.rgb) {
        (Some(dataset), None) => {
            let scene = args.scene.context("--scene is required with a dataset")?;
            let frame = find_frame(dataset, scene, args.frame)?;
            let targets = match args.crops {
                Crops::Gt => prediction::gt_targets(&frame, &model.config),
                Crops::Predicted => {
                    let segmenter = load_segmenter(&args.segmenter, args.backend)?;
                    prediction::predicted_targets(&frame, &model.config, &segmenter)?
                }
            };
            (frame, targets)
        }
        (None, Some(rgb)) => {
            let depth = args
                .depth
                .as_deref()
                .context("--depth is required with --rgb")?;
            let depth_scale = match args.depth_scale {
                Some(scale) => scale,
                None => boxpose_formats::bop_depth_scale(depth)?.unwrap_or(1.0),
            };
            anyhow::ensure!(
                depth_scale.is_finite() && depth_scale > 0.0,
                "--depth-scale {depth_scale} must be a positive number of millimetres per PNG unit \
                 (1 for millimetres; BOP's depth_scale, 0.1 for `boxpose export bop`)"
            );
            anyhow::ensure!(
                args.intrinsics.as_ref().is_none_or(|k| k.len() == 4),
                "--intrinsics takes 4 values: fx,fy,cx,cy"
            );
            anyhow::ensure!(
                args.bbox.len().is_multiple_of(4),
                "each --bbox takes 4 values: x_min,y_min,x_max,y_max"
            );
            let k = args
                .intrinsics
                .as_deref()
                .context("--intrinsics is required with --rgb")?;
            let intrinsics = Intrinsics {
                fx: k[0],
                fy: k[1],
                cx: k[2],
                cy: k[3],
            };
            let frame = boxpose_formats::read_rgbd(rgb, depth, intrinsics, depth_scale)?;
            if args.bbox.is_empty() {
                let segmenter = load_segmenter(&args.segmenter, args.backend)?;
                let targets = prediction::predicted_targets(&frame, &model.config, &segmenter)?;
                warn_implausible_depths(&frame, &targets, &model, depth_scale);
                return finish(args, &model, frame, targets);
            }
            let targets = args
                .bbox
                .chunks(4)
                .map(|b| {
                    let bbox = [b[0], b[1], b[2], b[3]];
                    prediction::bbox_target(&frame, &model.config, bbox)
                        .with_context(|| format!("--bbox {bbox:?} has no depth measurement inside"))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            warn_implausible_depths(&frame, &targets, &model, depth_scale);
            (frame, targets)
        }
        _ => bail!(
            "give a dataset folder with --scene (and --frame), or --rgb, --depth and --intrinsics"
        ),
    };
    finish(args, &model, frame, targets)
}

/// Predicts the targets' poses and writes every output.
fn finish(
    args: &Args,
    model: &KeypointModel,
    frame: Frame,
    targets: Vec<Target>,
) -> anyhow::Result<()> {
    anyhow::ensure!(!targets.is_empty(), "no box to predict in this frame");
    let (predictions, fits) = prediction::predict(model, &frame, &targets, args.size_fit.method())?;

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    boxpose_data::write_table(
        &args.out.join("predictions.parquet"),
        &boxpose_data::schema::PREDICTIONS,
        prediction::columns(&frame, &targets, &predictions, &fits, args.size_fit.name()),
    )?;
    let json_path = args.out.join("predictions.json");
    boxpose_data::write_file_atomically(
        &json_path,
        serde_json::to_string_pretty(&prediction::document(
            &frame,
            &targets,
            &predictions,
            &fits,
            args.size_fit.name(),
        ))?
        .as_bytes(),
    )?;

    let overlay_boxes: Vec<OverlayBox> = targets
        .iter()
        .zip(predictions.iter().zip(&fits))
        .map(|(t, (p, fit))| OverlayBox {
            truth: t
                .object_id
                .and_then(|id| frame.instances.iter().find(|i| i.object_id == id))
                .map(|i| i.corners_camera.map(Point3::from)),
            peaks: p.points.clone(),
            fitted: fit.as_ref().ok().map(BoxFit::corners),
        })
        .collect();
    let overlay = args.out.join("overlay.png");
    plots::overlay(
        &overlay,
        &frame.rgb,
        frame.width,
        frame.height,
        &frame.intrinsics,
        &overlay_boxes,
    )?;

    print_boxes(args, &frame, &targets, &predictions, &fits);
    println!(
        "predictions: {} and {}",
        args.out.join("predictions.parquet").display(),
        json_path.display()
    );
    println!(
        "overlay (true white, NMS peaks black, fitted grey): {}",
        overlay.display()
    );
    Ok(())
}

/// Per box: its fit's size, place, inliers and residual (with the distance to the true centre
/// when known) and its confidence, or why there is no pose.
fn print_boxes(
    args: &Args,
    frame: &Frame,
    targets: &[Target],
    predictions: &[Perception],
    fits: &[Result<BoxFit, String>],
) {
    println!("pose-and-size fit: {}", args.size_fit.name());
    for (t, (p, fit)) in targets.iter().zip(predictions.iter().zip(fits)) {
        let who = t
            .object_id
            .map_or(format!("bbox {:?}", t.bbox), |id| format!("object {id}"));
        match fit {
            Ok(fit) => {
                let size = fit.model.size();
                let at = fit.pose.translation.vector;
                let truth = t
                    .object_id
                    .and_then(|id| frame.instances.iter().find(|i| i.object_id == id));
                let error = truth.map_or(String::new(), |i| {
                    format!(
                        ", {:.1} mm from the true centre",
                        1000.0 * (at - true_pose(i).translation.vector).norm()
                    )
                });
                let c = &fit.confidence;
                println!(
                    "{who}: size {:.3}×{:.3}×{:.3} m at ({:.3}, {:.3}, {:.3}) m, {} of {} peaks inliers, residual {:.1} mm{error}",
                    size.x,
                    size.y,
                    size.z,
                    at.x,
                    at.y,
                    at.z,
                    fit.inlier_count(),
                    p.points.len(),
                    1000.0 * fit.inlier_rms
                );
                println!(
                    "    confidence {:.2} (margin {:.1} nats, {} inliers, noise {:.1} mm{})",
                    c.confidence,
                    c.margin_nats,
                    c.inliers,
                    1000.0 * c.noise_scale_m,
                    if c.mirror_ambiguous {
                        ", mirror-ambiguous"
                    } else {
                        ""
                    }
                );
            }
            Err(e) => println!("{who}: no pose ({e})"),
        }
    }
}

fn find_frame(dataset: &Path, scene: i64, frame_id: i32) -> anyhow::Result<Frame> {
    Dataset::open(dataset)?
        .frame(scene, frame_id)?
        .with_context(|| {
            format!(
                "{}: no frame {frame_id} of scene {scene} (`boxpose inspect` lists them)",
                dataset.display()
            )
        })
}

/// Warns about each box whose measured depth makes it implausible for the network
/// (`prediction::implausible_width`): the fit would report a confident pose that is far off.
fn warn_implausible_depths(
    frame: &Frame,
    targets: &[Target],
    model: &KeypointModel,
    depth_scale: f64,
) {
    let [near, far] = model.config.depth_range_m;
    for target in targets {
        let Some((across, wider)) = prediction::implausible_width(frame, target, &model.config)
        else {
            continue;
        };
        let problem = if wider {
            "wider than"
        } else {
            "under a tenth of"
        };
        eprintln!(
            "warning: the box in {target_bbox:?} is {across:.3} m across at its depth {z:.3} m \
             (read with --depth-scale {depth_scale} mm per unit): {problem} the network's depth \
             range ({depth_range:.2} m), so the depth is probably misread; is --depth-scale right? \
             (`boxpose export bop` writes 0.1: see its scene_camera.json)",
            target_bbox = target.bbox,
            z = target.crop.z_ref,
            depth_range = far - near
        );
    }
}

fn load_segmenter(path: &Path, backend: BackendKind) -> anyhow::Result<SegmenterModel> {
    Ok(SegmenterModel::load(path, backend.device()?)?)
}
