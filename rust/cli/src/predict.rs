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
use std::sync::Arc;

use anyhow::{Context, bail};
use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, ListArray, StringArray,
};
use boxpose_data::arrow::datatypes::{Float32Type, Float64Type, Int32Type};
use boxpose_data::{Dataset, Frame, Intrinsics};
use boxpose_geometry::adaptive::FitConfidence;
use boxpose_geometry::pipeline::{Fitted, Method};
use boxpose_geometry::{BoxModel, GeometryError};
use boxpose_learn::backend::BackendKind;
use boxpose_learn::evaluation::true_pose;
use boxpose_learn::inference::{self, BoxQuery, CropRequest, KeypointModel, Perception};
use boxpose_learn::segmentation::{self, SegmenterModel};
use nalgebra::{Isometry3, Point3};
use serde_json::json;

use crate::plots::{self, OverlayBox};

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Crops {
    /// Around each ground-truth box's visible bounding box, at its mask's median depth.
    Gt,
    /// Around each box the instance segmenter finds, at its predicted mask's median depth.
    Predicted,
}

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
    #[arg(long, default_value = "models/segmenter-slim")]
    segmenter: PathBuf,
    /// An 8-bit RGB PNG to predict on instead of a dataset frame.
    #[arg(long, requires_all = ["depth", "intrinsics"], conflicts_with = "dataset")]
    rgb: Option<PathBuf>,
    /// Its depth: a 16-bit PNG (0 = no measurement), the same size, in units of --depth-scale
    /// millimetres.
    #[arg(long)]
    depth: Option<PathBuf>,
    /// Millimetres per unit of the --depth PNG, as BOP's depth_scale: 1 for a PNG in
    /// millimetres; `boxpose export bop` writes 0.1 (see its scene_camera.json).
    #[arg(long, default_value_t = 1.0)]
    depth_scale: f64,
    /// Its intrinsics: fx,fy,cx,cy in pixels.
    #[arg(long, value_delimiter = ',')]
    intrinsics: Option<Vec<f64>>,
    /// A box to crop: x_min,y_min,x_max,y_max in pixels (repeat for several boxes).
    #[arg(long, value_delimiter = ',', action = clap::ArgAction::Append)]
    bbox: Vec<i32>,
    /// Trained model folder (network.toml + model.bpk).
    #[arg(long, default_value = "models/keypoint-slim")]
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

/// One box's fit, with its confidence.
struct Fit {
    model: BoxModel,
    pose: Isometry3<f64>,
    /// Per peak: whether the fit counts it as an inlier.
    inliers: Vec<bool>,
    /// Root mean square of the inliers' distances to their nearest fitted corner (metres).
    inlier_rms: f64,
    confidence: FitConfidence,
}

impl Fit {
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

    fn corners(&self) -> [Point3<f64>; 8] {
        self.model.corners().map(|c| self.pose * c)
    }

    fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|b| **b).count()
    }
}

/// A box to predict: where it came from, and its crop.
struct Target {
    object_id: Option<i32>,
    bbox: [i32; 4],
    crop: CropRequest,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    // its own earlier predictions are replaced
    let _claim =
        crate::output_folder::claim(&args.out, "--out", "predict", &["predictions.parquet"])?;
    let model = KeypointModel::load(&args.model, args.backend.device()?)?;
    let (frame, targets) = match (&args.dataset, &args.rgb) {
        (Some(dataset), None) => {
            let scene = args.scene.context("--scene is required with a dataset")?;
            let frame = find_frame(dataset, scene, args.frame)?;
            let targets = match args.crops {
                Crops::Gt => gt_targets(&frame, &model),
                Crops::Predicted => {
                    predicted_targets(&frame, &model, &args.segmenter, args.backend)?
                }
            };
            (frame, targets)
        }
        (None, Some(rgb)) => {
            anyhow::ensure!(
                args.depth_scale.is_finite() && args.depth_scale > 0.0,
                "--depth-scale {} must be a positive number of millimetres per PNG unit \
                 (1 for millimetres; BOP's depth_scale, 0.1 for `boxpose export bop`)",
                args.depth_scale
            );
            anyhow::ensure!(
                args.intrinsics.as_ref().is_none_or(|k| k.len() == 4),
                "--intrinsics takes 4 values: fx,fy,cx,cy"
            );
            anyhow::ensure!(
                args.bbox.len().is_multiple_of(4),
                "each --bbox takes 4 values: x_min,y_min,x_max,y_max"
            );
            let frame = frame_from_files(
                rgb,
                args.depth
                    .as_deref()
                    .context("--depth is required with --rgb")?,
                args.intrinsics
                    .as_deref()
                    .context("--intrinsics is required with --rgb")?,
                args.depth_scale,
            )?;
            if args.bbox.is_empty() {
                let targets = predicted_targets(&frame, &model, &args.segmenter, args.backend)?;
                warn_implausible_depths(&frame, &targets, &model, args.depth_scale);
                return finish(args, &model, frame, targets);
            }
            let targets = args
                .bbox
                .chunks(4)
                .map(|b| {
                    let bbox = [b[0], b[1], b[2], b[3]];
                    // no mask: the reference depth is the median inside the given box (max exclusive)
                    let width = frame.width;
                    let inside = |i: usize| {
                        let (x, y) = ((i % width) as i32, (i / width) as i32);
                        (bbox[0]..bbox[2]).contains(&x) && (bbox[1]..bbox[3]).contains(&y)
                    };
                    let crop = CropRequest::around(&frame, &model.config, bbox, inside)
                        .with_context(|| {
                            format!("--bbox {bbox:?} has no depth measurement inside")
                        })?;
                    Ok(Target {
                        object_id: None,
                        bbox,
                        crop,
                    })
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            warn_implausible_depths(&frame, &targets, &model, args.depth_scale);
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
    let queries: Vec<BoxQuery> = targets
        .iter()
        .map(|t| BoxQuery {
            crop: t.crop,
            known_box: None,
        })
        .collect();
    let predictions = inference::perceive(model, &frame, &queries, &[args.size_fit.method()], 16)?;
    let fits: Vec<Result<Fit, String>> = predictions
        .iter()
        .map(|p| Fit::of(&p.fits[0].fitted, &p.points))
        .collect();

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    write_parquet(
        &args.out.join("predictions.parquet"),
        &frame,
        &targets,
        &predictions,
        &fits,
        args.size_fit,
    )?;
    let json_path = args.out.join("predictions.json");
    boxpose_data::write_file_atomically(
        &json_path,
        serde_json::to_string_pretty(&to_json(
            &frame,
            &targets,
            &predictions,
            &fits,
            args.size_fit,
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
            fitted: fit.as_ref().ok().map(Fit::corners),
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

    println!("pose-and-size fit: {}", args.size_fit.name());
    for (t, (p, fit)) in targets.iter().zip(predictions.iter().zip(&fits)) {
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

fn gt_targets(frame: &Frame, model: &KeypointModel) -> Vec<Target> {
    frame
        .instances
        .iter()
        .filter_map(|instance| {
            Some(Target {
                object_id: Some(instance.object_id),
                bbox: instance.visible_bbox?,
                crop: CropRequest::of_instance(frame, &model.config, instance)?,
            })
        })
        .collect()
}

/// The boxes the segmenter finds; each is matched to a true instance (mask IoU ≥ 0.5) when the
/// frame has ground truth, for the overlay and the printed error.
fn predicted_targets(
    frame: &Frame,
    model: &KeypointModel,
    segmenter: &Path,
    backend: BackendKind,
) -> anyhow::Result<Vec<Target>> {
    let segmenter = SegmenterModel::load(segmenter, backend.device()?)?;
    let detections = segmenter.segment(&[frame])?.remove(0);
    let found = segmentation::match_detections(frame, &detections, 0.5);
    Ok(detections
        .iter()
        .enumerate()
        .filter_map(|(d, detection)| {
            let crop =
                CropRequest::around(frame, &model.config, detection.bbox, |i| detection.mask[i])?;
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

/// Warns about each box whose measured depth makes it implausible for the network: wider, at
/// that depth, than the heatmap's whole depth range, or narrower than a tenth of it. A depth PNG
/// read in the wrong unit does that (BOP's 0.1 mm units read as millimetres put a box 10× too
/// far, so 10× too large), and the fit then reports a confident pose that is far off. A network
/// whose depth axis scales with the crop fits boxes of any size, so it gets no such warning.
fn warn_implausible_depths(
    frame: &Frame,
    targets: &[Target],
    model: &KeypointModel,
    depth_scale: f64,
) {
    if model.config.depth_scale_crop_m.is_some() {
        // Its depth axis scales with the crop: any box size fits it, so none tells a misread unit.
        return;
    }
    let [near, far] = model.config.depth_range_m;
    let depth_range = far - near;
    for target in targets {
        let [x0, y0, x1, y1] = target.bbox;
        let z = target.crop.z_ref;
        let across = (f64::from(x1 - x0) / frame.intrinsics.fx)
            .max(f64::from(y1 - y0) / frame.intrinsics.fy)
            * z;
        let problem = if across > depth_range {
            "wider than"
        } else if across < depth_range / 10.0 {
            "under a tenth of"
        } else {
            continue;
        };
        eprintln!(
            "warning: the box in {target_bbox:?} is {across:.3} m across at its depth {z:.3} m \
             (read with --depth-scale {depth_scale} mm per unit): {problem} the network's depth \
             range ({depth_range:.2} m), so the depth is probably misread; is --depth-scale right? \
             (`boxpose export bop` writes 0.1: see its scene_camera.json)",
            target_bbox = target.bbox
        );
    }
}

/// A frame from an RGB PNG and a 16-bit depth PNG in units of `depth_scale` millimetres.
fn frame_from_files(
    rgb_path: &Path,
    depth_path: &Path,
    k: &[f64],
    depth_scale: f64,
) -> anyhow::Result<Frame> {
    let read = |path: &Path| -> anyhow::Result<(png::OutputInfo, Vec<u8>)> {
        let file =
            std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder
            .read_info()
            .with_context(|| format!("{}: not a PNG", path.display()))?;
        let mut buffer = vec![0; reader.output_buffer_size().context("image too large")?];
        let info = reader
            .next_frame(&mut buffer)
            .with_context(|| format!("{}: corrupt PNG", path.display()))?;
        buffer.truncate(info.buffer_size());
        Ok((info, buffer))
    };
    let (info, rgb) = read(rgb_path)?;
    anyhow::ensure!(
        info.color_type == png::ColorType::Rgb && info.bit_depth == png::BitDepth::Eight,
        "{}: expected an 8-bit RGB PNG, found {:?} at {:?} bits",
        rgb_path.display(),
        info.color_type,
        info.bit_depth
    );
    let (dinfo, depth_bytes) = read(depth_path)?;
    anyhow::ensure!(
        dinfo.color_type == png::ColorType::Grayscale && dinfo.bit_depth == png::BitDepth::Sixteen,
        "{}: expected a 16-bit greyscale PNG of depths (units of --depth-scale millimetres)",
        depth_path.display()
    );
    anyhow::ensure!(
        (dinfo.width, dinfo.height) == (info.width, info.height),
        "{} is {}×{} but {} is {}×{}",
        depth_path.display(),
        dinfo.width,
        dinfo.height,
        rgb_path.display(),
        info.width,
        info.height
    );
    let depth = depth_bytes
        .chunks(2)
        .map(|b| (f64::from(u16::from_be_bytes([b[0], b[1]])) * depth_scale / 1000.0) as f32)
        .collect();
    let (width, height) = (info.width as usize, info.height as usize);
    let intrinsics = Intrinsics {
        fx: k[0],
        fy: k[1],
        cx: k[2],
        cy: k[3],
    };
    Ok(Frame::from_images(
        -1,
        (width, height),
        intrinsics,
        rgb,
        depth,
        None,
    ))
}

/// The JSON of every box. A fit's `confidence.margin_nats` is null when no other box hypothesis
/// exists (an infinite margin).
fn to_json(
    frame: &Frame,
    targets: &[Target],
    predictions: &[Perception],
    fits: &[Result<Fit, String>],
    method: SizeFit,
) -> serde_json::Value {
    let boxes: Vec<_> = targets
        .iter()
        .zip(predictions.iter().zip(fits))
        .map(|(t, (p, fit))| {
            let fit = fit.as_ref().map(|fit| {
                let q = fit.pose.rotation.quaternion();
                let c = &fit.confidence;
                json!({
                    "size_fit": method.name(),
                    "pose_quat_wxyz": [q.w, q.i, q.j, q.k],
                    "pose_translation_m": fit.pose.translation.vector.as_slice(),
                    "size_m": fit.model.size().as_slice(),
                    "corners_camera_m": fit.corners().iter().map(|c| [c.x, c.y, c.z]).collect::<Vec<_>>(),
                    "inliers": fit.inliers,
                    "inlier_rms_m": fit.inlier_rms,
                    "confidence": {
                        "confidence": c.confidence,
                        "margin_nats": c.margin_nats,
                        "inliers": c.inliers,
                        "noise_scale_m": c.noise_scale_m,
                        "mirror_ambiguous": c.mirror_ambiguous,
                    },
                })
            });
            json!({
                "object_id": t.object_id,
                "bbox": t.bbox,
                "reference_depth_m": t.crop.z_ref,
                "peaks_camera_m": p.points.iter().map(|c| [c.x, c.y, c.z]).collect::<Vec<_>>(),
                "peak_scores": p.peaks.iter().map(|k| k.score).collect::<Vec<_>>(),
                "fit": fit.as_ref().ok(),
                "fit_error": fit.as_ref().err(),
            })
        })
        .collect();
    json!({ "scene_id": frame.scene_id, "frame_id": frame.frame_id, "boxes": boxes })
}

/// One row per box; the fit's columns are null where it failed (`fit_error` says why).
/// `confidence_inliers` counts the peaks the noise-adaptive cost takes as inliers (for the
/// robust fit the same as `inlier_count`; least squares counts every peak in `inlier_count`).
fn write_parquet(
    path: &Path,
    frame: &Frame,
    targets: &[Target],
    predictions: &[Perception],
    outcomes: &[Result<Fit, String>],
    method: SizeFit,
) -> anyhow::Result<()> {
    let fits: Vec<Option<&Fit>> = outcomes.iter().map(|f| f.as_ref().ok()).collect();
    let f64_list = |values: Vec<Option<Vec<f64>>>| -> ArrayRef {
        Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(
            values
                .into_iter()
                .map(|v| v.map(|v| v.into_iter().map(Some).collect::<Vec<_>>())),
        ))
    };
    let columns: Vec<ArrayRef> = vec![
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
            predictions
                .iter()
                .map(|p| Some(p.points.iter().flat_map(|c| [c.x, c.y, c.z]).collect()))
                .collect(),
        ),
        Arc::new(ListArray::from_iter_primitive::<Float32Type, _, _>(
            predictions
                .iter()
                .map(|p| Some(p.peaks.iter().map(|k| Some(k.score)).collect::<Vec<_>>())),
        )),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.inlier_count() as i32))
                .collect::<Int32Array>(),
        ),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.inlier_rms))
                .collect::<Float64Array>(),
        ),
        Arc::new(StringArray::from(vec![method.name(); targets.len()])),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.confidence.confidence))
                .collect::<Float64Array>(),
        ),
        Arc::new(
            fits.iter()
                // no other box hypothesis: an infinite margin, written as null (the readers refuse ±∞)
                .map(|f| {
                    f.map(|f| f.confidence.margin_nats)
                        .filter(|m| m.is_finite())
                })
                .collect::<Float64Array>(),
        ),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.confidence.inliers as i32))
                .collect::<Int32Array>(),
        ),
        Arc::new(
            fits.iter()
                .map(|f| f.map(|f| f.confidence.noise_scale_m))
                .collect::<Float64Array>(),
        ),
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
    ];
    boxpose_data::write_table(path, &boxpose_data::schema::PREDICTIONS, columns)?;
    Ok(())
}
