//! Scores of the network on ground-truth instances: the heatmap loss, corner recall, and every
//! pose fit's metrics; and the crops they are scored on, from the ground truth or the segmenter.
//! Shared by validation during training, `boxpose eval` and the counterexample search.

use std::path::Path;
use std::sync::Arc;

use boxpose_data::arrow::array::{ArrayRef, Float64Array, Int32Array};
use boxpose_data::{Dataset, Frame, Instance};
use boxpose_geometry::BoxModel;
use boxpose_geometry::metrics;
use boxpose_geometry::pipeline::{self, FitOutcome, Method, Scores};
use nalgebra::{Isometry3, Point3, Vector3};

use crate::LearnError;
use crate::config::NetworkConfig;
use crate::data;
use crate::fit_table::{self, FitRow};
use crate::inference::{self, BoxQuery, CropRequest, KeypointModel, Perception};
use crate::segmentation::{self, Detection, SegmenterModel};

/// A true corner counts as found when a back-projected peak lies within this distance (metres).
pub const CORNER_RECALL_RADIUS_M: f64 = 0.02;

/// How the network did on one instance.
pub struct InstanceEval {
    /// The true box's side lengths and diagonal.
    pub size_m: [f64; 3],
    pub diameter_m: f64,
    /// The segmenter did not find the box: no heatmap, every fit failed.
    pub missed: bool,
    /// Mean squared error of the heatmap against the target.
    pub heatmap_mse: f64,
    /// True corners with a peak within [`CORNER_RECALL_RADIUS_M`], of 8.
    pub corners_found: usize,
    pub fits: Vec<(Method, FitOutcome)>,
}

/// The box's true pose in the camera frame.
pub fn true_pose(instance: &Instance) -> Isometry3<f64> {
    pipeline::isometry(
        instance.camera_box.quat_wxyz,
        instance.camera_box.translation,
    )
}

/// Scores one instance's perception (its heatmap and every fit of [`Method::ALL`]) against the
/// instance's truth and the crop's `target` heatmap.
pub(crate) fn evaluate_perception(
    instance: &Instance,
    perception: &Perception,
    target: &[f32],
) -> Result<InstanceEval, LearnError> {
    let model = BoxModel::new(Vector3::from(instance.size))?;
    let heatmap_mse = perception
        .heatmap
        .iter()
        .zip(target)
        .map(|(p, t)| ((p - t) as f64).powi(2))
        .sum::<f64>()
        / perception.heatmap.len() as f64;
    let points = &perception.points;
    let corners_found = instance
        .corners_camera
        .iter()
        .filter(|c| {
            points
                .iter()
                .any(|p| (p - Point3::from(**c)).norm() < CORNER_RECALL_RADIUS_M)
        })
        .count();
    let truth = true_pose(instance);
    let fits = perception
        .fits
        .iter()
        .map(|run| (run.method, run.score(&model, &truth, points)))
        .collect();
    Ok(InstanceEval {
        size_m: instance.size,
        diameter_m: model.diameter(),
        missed: false,
        heatmap_mse,
        corners_found,
        fits,
    })
}

/// An instance the segmenter missed: no corner found, every fit a failure.
pub(crate) fn missed_instance(instance: &Instance) -> Result<InstanceEval, LearnError> {
    let model = BoxModel::new(Vector3::from(instance.size))?;
    Ok(InstanceEval {
        size_m: instance.size,
        diameter_m: model.diameter(),
        missed: true,
        heatmap_mse: f64::NAN,
        corners_found: 0,
        fits: Method::ALL
            .into_iter()
            .map(|m| (m, FitOutcome::NotDetected))
            .collect(),
    })
}

/// Aggregates of many [`InstanceEval`]s. Every recall counts a failed fit or a missed box as a
/// miss. "cube MSSD" is [`metrics::cube_mssd`], the primary correctness metric (the corners' real
/// displacement); "MSSD" the exact-symmetry one, which also asks for the right quarter turn.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub instances: usize,
    pub heatmap_mse: f64,
    /// Fraction of true corners found.
    pub corner_recall: f64,
    /// Fraction of instances whose robust fit (known size) has cube MSSD below 0.05 / 0.1 of the
    /// box's diameter.
    pub robust_cube_mssd_recall_005: f64,
    pub robust_cube_mssd_recall_010: f64,
    /// The same with the exact-symmetry MSSD.
    pub robust_mssd_recall_005: f64,
    pub robust_mssd_recall_010: f64,
    /// BOP's average recall over 0.05…0.50 of the diameter ([`metrics::average_recall`]) of the
    /// robust fit's cube MSSD and exact MSSD.
    pub robust_ar_cube_mssd: f64,
    pub robust_ar_mssd: f64,
    /// The pose-and-size fit (size unknown): cube MSSD and MSSD recalls (for a fitted size the two
    /// agree: [`pipeline::Fitted::mssd`]), and the share with 3D IoU above 0.5 / 0.7 / 0.9.
    pub size_cube_mssd_recall_005: f64,
    pub size_cube_mssd_recall_010: f64,
    pub size_mssd_recall_005: f64,
    pub size_mssd_recall_010: f64,
    pub size_iou_recall_050: f64,
    pub size_iou_recall_070: f64,
    pub size_iou_recall_090: f64,
    /// Boxes whose three sides all differ pairwise by at least [`DISTINCT_SIDES_M`], and the share
    /// of them whose robust fit has exact MSSD below 0.1 d: where the orientation is visible in
    /// the box's shape, so the exact metric is a fair target.
    pub distinct_sides_instances: usize,
    pub robust_mssd_recall_010_distinct_sides: f64,
    /// Boxes with two sides within [`DISTINCT_SIDES_M`] of each other, and the share of them whose
    /// robust fit has the right quarter turn (exact MSSD below 0.1 d): what only a texture cue
    /// (e.g. tape along the longer side) can decide.
    pub near_square_instances: usize,
    pub robust_right_quarter_turn_near_square: f64,
    /// Median of the paper's error of the paper's own search.
    pub paper_error_median: f64,
}

impl Summary {
    /// The summary as (name, value) pairs: the columns of a run's history.csv.
    pub fn named(&self) -> Vec<(String, f64)> {
        [
            ("val_instances", self.instances as f64),
            ("heatmap_mse", self.heatmap_mse),
            ("corner_recall", self.corner_recall),
            (
                "robust_cube_mssd_recall_005",
                self.robust_cube_mssd_recall_005,
            ),
            (
                "robust_cube_mssd_recall_010",
                self.robust_cube_mssd_recall_010,
            ),
            ("robust_mssd_recall_005", self.robust_mssd_recall_005),
            ("robust_mssd_recall_010", self.robust_mssd_recall_010),
            ("robust_ar_cube_mssd", self.robust_ar_cube_mssd),
            ("robust_ar_mssd", self.robust_ar_mssd),
            ("size_cube_mssd_recall_005", self.size_cube_mssd_recall_005),
            ("size_cube_mssd_recall_010", self.size_cube_mssd_recall_010),
            ("size_mssd_recall_005", self.size_mssd_recall_005),
            ("size_mssd_recall_010", self.size_mssd_recall_010),
            ("size_iou_recall_050", self.size_iou_recall_050),
            ("size_iou_recall_070", self.size_iou_recall_070),
            ("size_iou_recall_090", self.size_iou_recall_090),
            (
                "distinct_sides_instances",
                self.distinct_sides_instances as f64,
            ),
            (
                "robust_mssd_recall_010_distinct_sides",
                self.robust_mssd_recall_010_distinct_sides,
            ),
            ("near_square_instances", self.near_square_instances as f64),
            (
                "robust_right_quarter_turn_near_square",
                self.robust_right_quarter_turn_near_square,
            ),
            ("paper_error_median", self.paper_error_median),
        ]
        .into_iter()
        .map(|(name, value)| (name.to_string(), value))
        .collect()
    }
}

/// Per instance, `metric` of its `method` fit (+∞ where the fit failed or the box was missed).
fn per_instance(
    evals: &[InstanceEval],
    method: Method,
    metric: fn(&Scores, f64) -> f64,
) -> Vec<f64> {
    evals
        .iter()
        .map(|e| {
            e.fits
                .iter()
                .find(|(m, _)| *m == method)
                .and_then(|(_, outcome)| outcome.scores())
                .map_or(f64::INFINITY, |s| metric(s, e.diameter_m))
        })
        .collect()
}

/// Two sides of a box closer than this (metres) leave its quarter turns to texture cues.
pub const DISTINCT_SIDES_M: f64 = 0.01;

/// Whether every two sides of a box of `size` differ by at least [`DISTINCT_SIDES_M`].
fn has_distinct_sides(size: [f64; 3]) -> bool {
    [(0, 1), (1, 2), (0, 2)]
        .iter()
        .all(|&(a, b)| (size[a] - size[b]).abs() >= DISTINCT_SIDES_M)
}

/// Fraction of `values` below `threshold`.
fn share_below(values: &[f64], threshold: f64) -> f64 {
    values.iter().filter(|&&v| v < threshold).count() as f64 / values.len().max(1) as f64
}

/// The mean, or NaN for no values (every box missed has no heatmap to score).
fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.fold((0.0, 0usize), |(sum, count), v| (sum + v, count + 1));
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

pub fn summarize(evals: &[InstanceEval]) -> Summary {
    let n = evals.len().max(1) as f64;
    let mut paper_errors: Vec<f64> = evals
        .iter()
        .filter_map(|e| {
            e.fits
                .iter()
                .find(|(m, _)| *m == Method::PaperExact)
                .and_then(|(_, s)| s.scores())
                .map(|s| s.paper_error)
        })
        .collect();
    paper_errors.sort_by(f64::total_cmp);
    let cube = |method| per_instance(evals, method, |s, d| s.cube_mssd_m / d);
    let exact = |method| per_instance(evals, method, |s, d| s.mssd_m / d);
    let (robust_cube, robust_exact) = (cube(Method::Robust), exact(Method::Robust));
    let (size_cube, size_exact) = (cube(Method::SizeAndPose), exact(Method::SizeAndPose));
    let (distinct, near_square): (Vec<_>, Vec<_>) = robust_exact
        .iter()
        .zip(evals)
        .map(|(&error, e)| (error, has_distinct_sides(e.size_m)))
        .partition(|&(_, distinct)| distinct);
    let errors = |pairs: Vec<(f64, bool)>| pairs.into_iter().map(|(e, _)| e).collect::<Vec<_>>();
    let (distinct, near_square) = (errors(distinct), errors(near_square));
    // 1 − IoU, so that a failed fit (+∞) is a miss like the distances' misses.
    let size_iou_gap = per_instance(evals, Method::SizeAndPose, |s, _| 1.0 - s.iou_3d);
    Summary {
        instances: evals.len(),
        heatmap_mse: mean(evals.iter().filter(|e| !e.missed).map(|e| e.heatmap_mse)),
        corner_recall: evals
            .iter()
            .map(|e| e.corners_found as f64 / 8.0)
            .sum::<f64>()
            / n,
        robust_cube_mssd_recall_005: share_below(&robust_cube, 0.05),
        robust_cube_mssd_recall_010: share_below(&robust_cube, 0.1),
        robust_mssd_recall_005: share_below(&robust_exact, 0.05),
        robust_mssd_recall_010: share_below(&robust_exact, 0.1),
        robust_ar_cube_mssd: metrics::average_recall(&robust_cube),
        robust_ar_mssd: metrics::average_recall(&robust_exact),
        size_cube_mssd_recall_005: share_below(&size_cube, 0.05),
        size_cube_mssd_recall_010: share_below(&size_cube, 0.1),
        size_mssd_recall_005: share_below(&size_exact, 0.05),
        size_mssd_recall_010: share_below(&size_exact, 0.1),
        size_iou_recall_050: share_below(&size_iou_gap, 0.5),
        size_iou_recall_070: share_below(&size_iou_gap, 0.3),
        size_iou_recall_090: share_below(&size_iou_gap, 0.1),
        distinct_sides_instances: distinct.len(),
        robust_mssd_recall_010_distinct_sides: share_below(&distinct, 0.1),
        near_square_instances: near_square.len(),
        robust_right_quarter_turn_near_square: share_below(&near_square, 0.1),
        paper_error_median: paper_errors
            .get(paper_errors.len() / 2)
            .copied()
            .unwrap_or(f64::NAN),
    }
}

/// Where the keypoint network's crops come from, as every command and a search run name it
/// (`--crops gt|predicted`; `gt`/`predicted` in run.json).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Crops {
    /// Around each ground-truth box's visible bounding box, at its mask's median depth: the
    /// keypoint network and the fit alone.
    Gt,
    /// Around each box the instance segmenter finds (matched to the truth at mask IoU ≥ 0.5), at
    /// its predicted mask's median depth; eval and the search count a box it misses as failed.
    Predicted,
}

/// Where the keypoint network's crops come from, with the segmenter that makes them.
#[derive(Clone, Copy)]
pub enum CropSource<'a> {
    /// Each box's ground-truth visible mask and box.
    GroundTruth,
    /// The segmenter's detection matched to each box (COCO's matching at mask IoU 0.5).
    Segmenter(&'a SegmenterModel),
}

/// The crops of some instances of a frame, and the segmenter's detections when it ran.
pub struct FrameCrops {
    /// Per instance asked for, its crop; None for a box the segmenter did not find.
    pub crops: Vec<Option<CropRequest>>,
    pub detections: Option<Vec<Detection>>,
    /// Per instance asked for, the index of the detection matched to it (with the segmenter).
    matched: Vec<Option<usize>>,
}

impl FrameCrops {
    /// One box's crop on `frame` from the segmenter's detection matched to it (carried to
    /// `frame` when it was found in another view: [`Detection::carried_to`]); no crop when the
    /// segmenter did not find the box.
    pub fn of_detection(config: &NetworkConfig, frame: &Frame, found: Option<Detection>) -> Self {
        let crop = found
            .as_ref()
            .and_then(|d| CropRequest::around(frame, config, d.bbox, |i| d.mask[i]));
        Self {
            crops: vec![crop],
            matched: vec![found.is_some().then_some(0)],
            detections: Some(found.into_iter().collect()),
        }
    }

    /// Whether a pixel (row-major index) of `frame` is the box `instance`, the `k`th asked for,
    /// as its crop saw it: the ground-truth visible mask, or the mask of the segmenter's
    /// detection matched to it (nothing, for a box it did not find).
    pub fn mask_of<'a>(
        &'a self,
        frame: &'a Frame,
        instance: &Instance,
        k: usize,
    ) -> impl Fn(usize) -> bool + 'a {
        let detection = self
            .detections
            .as_ref()
            .map(|detections| self.matched[k].map(|d| &detections[d]));
        let label = u16::try_from(instance.object_id + 1).ok();
        move |pixel| match detection {
            Some(found) => found.is_some_and(|d| d.mask.get(pixel) == Some(&true)),
            None => label.is_some() && frame.instance_mask.get(pixel).copied() == label,
        }
    }
}

/// The segmenter's detections in `frame`, and per instance of `instances` the index of the one
/// matched to it (COCO's matching at mask IoU 0.5).
fn segment_and_match(
    segmenter: &SegmenterModel,
    frame: &Frame,
    instances: &[&Instance],
) -> Result<(Vec<Detection>, Vec<Option<usize>>), LearnError> {
    let detections = segmenter.segment(&[frame])?.remove(0);
    let found = segmentation::match_detections(frame, &detections, 0.5);
    let matched = instances
        .iter()
        .map(|instance| {
            frame
                .instances
                .iter()
                .position(|i| i.object_id == instance.object_id)
                .map(|index| found[index])
                .ok_or_else(|| {
                    LearnError::Data(format!(
                        "object {} is not in this frame",
                        instance.object_id
                    ))
                })
        })
        .collect::<Result<Vec<_>, LearnError>>()?;
    Ok((detections, matched))
}

/// The segmenter's detection matched to `instance` in `frame`, if it found the box.
pub fn detection_of(
    segmenter: &SegmenterModel,
    frame: &Frame,
    instance: &Instance,
) -> Result<Option<Detection>, LearnError> {
    let (mut detections, matched) = segment_and_match(segmenter, frame, &[instance])?;
    Ok(matched[0].map(|d| detections.swap_remove(d)))
}

/// The crops of `instances` (of `frame`) for the keypoint network, from `source`.
pub fn instance_crops(
    config: &NetworkConfig,
    frame: &Frame,
    instances: &[&Instance],
    source: CropSource,
) -> Result<FrameCrops, LearnError> {
    let CropSource::Segmenter(segmenter) = source else {
        let crops = instances
            .iter()
            .map(|instance| {
                CropRequest::of_instance(frame, config, instance)
                    .map(Some)
                    .ok_or_else(|| {
                        LearnError::Data(format!(
                            "scene {} frame {} object {}: no visible pixel with a depth to crop",
                            frame.scene_id, frame.frame_id, instance.object_id
                        ))
                    })
            })
            .collect::<Result<_, _>>()?;
        return Ok(FrameCrops {
            matched: vec![None; instances.len()],
            crops,
            detections: None,
        });
    };
    let (detections, matched) = segment_and_match(segmenter, frame, instances)?;
    let crops = matched
        .iter()
        .map(|found| {
            found.and_then(|d| {
                let detection = &detections[d];
                CropRequest::around(frame, config, detection.bbox, |i| detection.mask[i])
            })
        })
        .collect();
    Ok(FrameCrops {
        crops,
        detections: Some(detections),
        matched,
    })
}

/// One frame evaluated: each chosen instance's scores, and the segmenter's detections.
pub struct FrameEvaluation {
    pub evals: Vec<InstanceEval>,
    pub detections: Option<Vec<Detection>>,
}

/// Evaluates the keypoint network on `instances` of `frame`, on crops from `crops` (a box the
/// segmenter missed scores as missed), `batch_size` crops per forward pass: every fit of
/// [`Method::ALL`], perceived by [`inference::perceive`] (mirror ties settled with the frame's
/// depth image); with `refine_depth`, each known-size fit then laid on the depth image of the
/// box's own mask, the one its crop came from ([`FrameCrops::mask_of`];
/// [`boxpose_geometry::pipeline::FitRun::refine_with_depth`], as `boxpose search
/// --refine-depth`).
pub fn evaluate_frame(
    model: &KeypointModel,
    frame: &Frame,
    instances: &[&Instance],
    crops: CropSource,
    batch_size: usize,
    refine_depth: bool,
) -> Result<FrameEvaluation, LearnError> {
    let found = instance_crops(&model.config, frame, instances, crops)?;
    let crops = &found.crops;
    let queries = instances
        .iter()
        .zip(crops)
        .filter_map(|(instance, crop)| {
            let crop = (*crop)?;
            Some(
                BoxModel::new(Vector3::from(instance.size)).map(|known| BoxQuery {
                    crop,
                    known_box: Some(known),
                }),
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut perceptions = inference::perceive(model, frame, &queries, &Method::ALL, batch_size)?;
    if refine_depth {
        let depth = data::depth_view(frame);
        // the perceptions are the found instances', in order
        let found_instances = instances
            .iter()
            .enumerate()
            .filter(|&(k, _)| crops[k].is_some());
        for (perception, (k, instance)) in perceptions.iter_mut().zip(found_instances) {
            for fit in &mut perception.fits {
                fit.refine_with_depth(
                    &perception.points,
                    &depth,
                    found.mask_of(frame, instance, k),
                );
            }
        }
    }
    let mut perceptions = perceptions.into_iter();
    let evals = instances
        .iter()
        .zip(crops)
        .map(|(instance, crop)| match crop {
            Some(_) => {
                let perception = perceptions
                    .next()
                    .expect("one perception per found instance");
                let target =
                    data::target_heatmap(&model.config, &perception.grid, &instance.corners_camera)
                        .map_err(|e| {
                            LearnError::Data(format!(
                                "scene {} frame {}: a box's target heatmap: {e}",
                                frame.scene_id, frame.frame_id
                            ))
                        })?;
                evaluate_perception(instance, &perception, &target)
            }
            None => missed_instance(instance),
        })
        .collect::<Result<_, _>>()?;
    Ok(FrameEvaluation {
        evals,
        detections: found.detections,
    })
}

/// Which boxes of a dataset [`evaluate_dataset`] evaluates, and how (`boxpose eval`'s options).
#[derive(Debug, Clone, Copy)]
pub struct DatasetOptions {
    /// Only the held-out scenes (scene_id % N == 0).
    pub held_out: Option<u32>,
    /// Boxes less visible than this are not evaluated.
    pub min_visible_fraction: f32,
    /// The perception reads the frames' simulated sensor depth.
    pub sensor_depth: bool,
    /// Crops per forward pass.
    pub batch_size: usize,
    /// Known-size fits laid on the depth image ([`evaluate_frame`]).
    pub refine_depth: bool,
}

impl DatasetOptions {
    /// Whether the scene's boxes are evaluated.
    pub fn evaluates_scene(&self, scene_id: i64) -> bool {
        self.held_out
            .is_none_or(|modulus| data::is_held_out(scene_id, i64::from(modulus)))
    }
}

/// A dataset evaluated: a row per box and fit, each box's evaluation, and the segmenter's
/// detections scored (empty with ground-truth crops).
pub struct DatasetEvaluation {
    pub fit_rows: Vec<FitRow>,
    pub evals: Vec<InstanceEval>,
    pub detections: segmentation::DetectionScorer,
}

/// Every chosen box of `dataset` through [`evaluate_frame`], on the segmenter's crops when one is
/// given; frames stream through one at a time, the segmenter's AP keeps only overlaps.
/// `progress(done, total)` counts the evaluated scenes' instances.
pub fn evaluate_dataset(
    model: &KeypointModel,
    segmenter: Option<&SegmenterModel>,
    dataset: &Dataset,
    options: &DatasetOptions,
    mut progress: impl FnMut(u64, u64),
) -> Result<DatasetEvaluation, LearnError> {
    let frames = dataset.frames()?;
    let total = frames.instance_count(|scene| options.evaluates_scene(scene)) as u64;
    progress(0, total);
    let mut done = 0;
    let mut out = DatasetEvaluation {
        fit_rows: Vec::new(),
        evals: Vec::new(),
        detections: segmentation::DetectionScorer::default(),
    };
    for frame in frames {
        let mut frame = frame?;
        if !options.evaluates_scene(frame.scene_id) {
            continue;
        }
        data::perceived_depth(&mut frame, options.sensor_depth, dataset.root())?;
        let frame = &frame;
        let chosen: Vec<_> = frame
            .instances
            .iter()
            .filter(|i| data::is_target(i, options.min_visible_fraction))
            .collect();
        let crops = segmenter.map_or(CropSource::GroundTruth, CropSource::Segmenter);
        let evaluated = evaluate_frame(
            model,
            frame,
            &chosen,
            crops,
            options.batch_size,
            options.refine_depth,
        )?;
        if let Some(detections) = &evaluated.detections {
            out.detections.add(frame, detections);
        }
        for (instance, eval) in chosen.iter().zip(evaluated.evals) {
            out.fit_rows
                .extend(eval.fits.iter().map(|(method, outcome)| FitRow {
                    scene_id: instance.scene_id,
                    frame_id: instance.frame_id,
                    object_id: instance.object_id,
                    method: *method,
                    diameter_m: eval.diameter_m,
                    outcome: outcome.clone(),
                }));
            out.evals.push(eval);
        }
        done += frame.instances.len() as u64;
        progress(done, total);
    }
    Ok(out)
}

impl DatasetEvaluation {
    /// `eval.parquet`: the fit rows with each instance's heatmap MSE and corners found beside
    /// them (the EVAL schema).
    pub fn write_table(&self, path: &Path) -> Result<(), LearnError> {
        let rows = &self.fit_rows;
        let per_instance = rows.len() / self.evals.len().max(1);
        let mut columns = fit_table::columns(rows);
        let instance = |i: usize| &self.evals[i / per_instance];
        columns.push(Arc::new(
            (0..rows.len())
                .map(|i| Some(instance(i).heatmap_mse).filter(|_| !instance(i).missed))
                .collect::<Float64Array>(),
        ) as ArrayRef);
        columns.push(Arc::new(
            (0..rows.len())
                .map(|i| instance(i).corners_found as i32)
                .collect::<Int32Array>(),
        ) as ArrayRef);
        boxpose_data::write_table(path, &boxpose_data::schema::EVAL, columns)?;
        Ok(())
    }
}
