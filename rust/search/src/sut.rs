//! The system under test, one sample end to end in one process: sampled inputs → scene rows →
//! MuJoCo settle → render (embedded Blender) → perception (keypoint network on a ground-truth or
//! segmenter crop, and a pose fit; or another system's process, [`crate::external`]) → metrics →
//! the failure predicate.

use std::time::Instant;

use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::{Frame, Instance, Intrinsics, Object, Scene};
use boxpose_geometry::BoxModel;
use boxpose_geometry::metrics::{PAPER_ERROR_THRESHOLD, normalized_paper_error};
use boxpose_geometry::pipeline::{FitOutcome, FitRun, Fitted, Method, Scores};
use boxpose_learn::data;
use boxpose_learn::evaluation::{self, CropSource, FrameCrops};
use boxpose_learn::inference::{self, BoxQuery, CropRequest, KeypointModel};
use boxpose_learn::segmentation::{SegmenterModel, carried_bbox};
use boxpose_physics::RecipePhysics;
use boxpose_render::{RenderRequest, Renderer};
use nalgebra::{Point3, Vector3};

use crate::error::{Result, SearchError};
use crate::external::{self, Answer, ExternalSut};
use crate::scene::{self, TARGET_OBJECT_ID};
use crate::space::SearchSpace;

/// Where the keypoint network's crop comes from (one enum for every command).
pub use boxpose_learn::evaluation::Crops;

/// When a sample counts as a failure of the pipeline.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "metric", rename_all = "snake_case")]
pub enum Predicate {
    /// The paper's: its error normalised by the box's squared edge length (diag² / 3) above
    /// `threshold` (the paper's 0.005 on a unit box), or the box not detected.
    PaperError { threshold: f64 },
    /// MSSD above `fraction` of the box's diameter, or the box not detected.
    Mssd { fraction: f64 },
    /// Cube-group corner MSSD ([`boxpose_geometry::metrics::cube_mssd`]) above `fraction` of the
    /// box's diameter, or the box not detected: a wrong pose by how far its corners really are.
    CubeMssd { fraction: f64 },
}

impl Default for Predicate {
    fn default() -> Self {
        Predicate::PaperError {
            threshold: PAPER_ERROR_THRESHOLD,
        }
    }
}

impl std::fmt::Display for Predicate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Predicate::PaperError { threshold } => write!(
                f,
                "the paper's error / (diag²/3) > {threshold}, or the box not found"
            ),
            Predicate::Mssd { fraction } => {
                write!(f, "MSSD > {fraction} × diameter, or the box not found")
            }
            Predicate::CubeMssd { fraction } => write!(
                f,
                "cube-group corner MSSD > {fraction} × diameter, or the box not found"
            ),
        }
    }
}

impl Predicate {
    /// Parses `paper` / `paper:T` / `mssd:F` / `cube-mssd:F` (F a fraction of the diameter).
    pub fn parse(text: &str) -> Result<Self, String> {
        let (metric, value) = text
            .split_once(':')
            .map_or((text, None), |(m, v)| (m, Some(v)));
        let number = |v: Option<&str>, default: f64| -> Result<f64, String> {
            let x = v.map_or(Ok(default), |v| {
                v.trim().parse::<f64>().map_err(|e| format!("'{v}': {e}"))
            })?;
            if x.is_finite() && x > 0.0 {
                Ok(x)
            } else {
                Err(format!("the threshold {x} must be finite and positive"))
            }
        };
        match metric {
            "paper" => Ok(Predicate::PaperError {
                threshold: number(value, PAPER_ERROR_THRESHOLD)?,
            }),
            "mssd" => Ok(Predicate::Mssd {
                fraction: number(value, 0.1)?,
            }),
            "cube-mssd" => Ok(Predicate::CubeMssd {
                fraction: number(value, 0.1)?,
            }),
            other => Err(format!(
                "unknown failure metric '{other}': use paper[:T], mssd[:F] or cube-mssd[:F]"
            )),
        }
    }

    /// The continuous score the cross-entropy levels are set on: log10(metric / threshold), so
    /// that a sample fails exactly when its score is > 0; +∞ when nothing was fitted.
    pub fn score(&self, metrics: &Metrics) -> f64 {
        let (value, threshold) = self.judge(
            metrics.paper_error_normalized,
            metrics.mssd_over_diameter,
            metrics.cube_mssd_over_diameter,
        );
        (value.max(1e-300) / threshold).log10()
    }

    /// Which of a sample's three errors (normalised paper error, MSSD / d, cube MSSD / d) this
    /// predicate judges, and its threshold.
    pub fn judge<T>(&self, paper_normalized: T, mssd: T, cube_mssd: T) -> (T, f64) {
        match *self {
            Predicate::PaperError { threshold } => (paper_normalized, threshold),
            Predicate::Mssd { fraction } => (mssd, fraction),
            Predicate::CubeMssd { fraction } => (cube_mssd, fraction),
        }
    }
}

/// The fits a search can put under test, by the names `--fit` takes (short forms of
/// [`Method::name`]).
pub const FITS: [(&str, Method); 4] = [
    ("paper", Method::PaperExact),
    ("fast", Method::FastExact),
    ("robust", Method::Robust),
    ("size", Method::SizeAndPose),
];

/// The `--fit` names, in [`FITS`]' order.
pub const FIT_NAMES: [&str; 4] = [FITS[0].0, FITS[1].0, FITS[2].0, FITS[3].0];

/// The fit the pipeline uses, as the CLI names it.
pub fn method_named(name: &str) -> Result<Method, String> {
    FITS.iter()
        .find(|(fit, _)| *fit == name)
        .map(|(_, method)| *method)
        .ok_or_else(|| format!("unknown fit '{name}': use {}", FIT_NAMES.join(", ")))
}

/// How far the fitted pose is from the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    /// The paper's error (mean squared distance of the fitted corners to the true ones), m².
    pub paper_error: f64,
    /// `paper_error` / (diag² / 3): 1 on a unit box's scale, so the paper's 0.005 applies to any box.
    pub paper_error_normalized: f64,
    pub mssd_over_diameter: f64,
    pub cube_mssd_over_diameter: f64,
    pub add_s_m: f64,
    pub rotation_error_deg: f64,
    pub translation_error_m: f64,
    /// The fit's own confidence (geometry `FitConfidence`); None when an external system gave
    /// none.
    pub confidence: Option<f64>,
    /// The fitted box's corners, camera frame.
    pub fitted_corners: [[f64; 3]; 8],
}

impl Metrics {
    fn of(scores: &Scores, size: [f64; 3]) -> Self {
        let diagonal = size.iter().map(|s| s * s).sum::<f64>().sqrt();
        Metrics {
            paper_error: scores.paper_error,
            paper_error_normalized: normalized_paper_error(scores.paper_error, diagonal),
            mssd_over_diameter: scores.mssd_m / diagonal,
            cube_mssd_over_diameter: scores.cube_mssd_m / diagonal,
            add_s_m: scores.add_s_m,
            rotation_error_deg: scores.rotation_error_deg,
            translation_error_m: scores.translation_error_m,
            confidence: Some(scores.confidence),
            fitted_corners: scores.fitted_corners,
        }
    }

    fn is_finite(&self) -> bool {
        [
            self.paper_error,
            self.paper_error_normalized,
            self.mssd_over_diameter,
            self.cube_mssd_over_diameter,
            self.add_s_m,
            self.rotation_error_deg,
            self.translation_error_m,
        ]
        .iter()
        .chain(self.confidence.iter())
        .chain(self.fitted_corners.iter().flatten())
        .all(|v| v.is_finite())
    }
}

/// Why a sample was not scored; such samples are counted (P(valid)) and never scored.
#[derive(Debug, Clone, PartialEq)]
pub enum Invalid {
    /// MuJoCo did not certify the drop stable (not settled in time, penetration, left support).
    NotStable(String),
    /// The target box is less visible than the evaluation's minimum (occluded or out of view).
    NotVisible { visible_fraction: f32 },
    /// An external system under test broke the protocol, crashed or timed out: neither a failure
    /// of the pipeline nor a pass, counted apart.
    SystemUnderTest(String),
}

impl std::fmt::Display for Invalid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Invalid::NotStable(reason) => write!(f, "not stable: {reason}"),
            Invalid::NotVisible { visible_fraction } => {
                write!(f, "target {:.0}% visible", 100.0 * visible_fraction)
            }
            Invalid::SystemUnderTest(reason) => write!(f, "system under test: {reason}"),
        }
    }
}

/// What the pipeline made of the target box.
// One value per sample, moved once: boxing the metrics would only add an allocation.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Perceived {
    /// Scored: the fit's metrics.
    Fitted(Metrics),
    /// Detected, but the fit failed (too few peaks, degenerate geometry): a failure.
    FitFailed(String),
    /// The segmenter did not find the box: a failure.
    NotDetected,
}

/// Seconds spent in each stage of one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageSeconds {
    pub settle: f64,
    pub render: f64,
    pub inference: f64,
    pub fit: f64,
}

/// One sample's result.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub result: std::result::Result<Perceived, Invalid>,
    pub seconds: StageSeconds,
    /// The settled scene (contract rows) and, when rendered, the frame and its instances.
    pub scene: Scene,
    pub objects: Vec<Object>,
    pub rendered: Option<(RecordBatch, RecordBatch)>,
    /// NMS peaks of the target, back-projected (camera frame, metres), best first.
    pub peaks: Vec<[f64; 3]>,
}

/// What a search run scores its samples with: one sample's inputs in, its outcome out. The
/// real pipeline is [`SystemUnderTest`]; a closed-form evaluator lets the run folder's resume,
/// shards, barriers and levels be tested without Blender or networks
/// (`rust/search/tests/run_folder.rs`).
pub trait Evaluate {
    /// Builds, settles, renders and perceives sample `scene_id` with `seed` (whatever the
    /// evaluator's stages are), and scores it.
    fn evaluate(
        &mut self,
        space: &SearchSpace,
        parameters: &crate::space::Parameters,
        scene_id: i64,
        seed: i64,
    ) -> Result<Outcome>;
}

/// Who finds the target and its pose.
// One per search process, never moved after it is made: boxing the networks would only add an
// indirection.
#[allow(clippy::large_enum_variant)]
pub enum Perceiver {
    /// This project's pipeline: the keypoint network on a ground-truth or segmenter crop, a fit.
    Own {
        model: KeypointModel,
        segmenter: Option<SegmenterModel>,
        method: Method,
    },
    /// Another system, a process speaking [`external::PROTOCOL`], on whole frames.
    External(ExternalSut),
}

/// Everything loaded once for a search: the renderer (one per process), the networks and the fit
/// or the external system.
pub struct SystemUnderTest {
    pub physics: RecipePhysics,
    renderer: Renderer,
    perceiver: Perceiver,
    pub crops: Crops,
    /// Targets less visible than this are not scored (as `boxpose eval`'s default).
    pub min_visible_fraction: f32,
    /// Render whole frames even for ground-truth crops (the reference the region renders are
    /// measured against).
    pub whole_frames: bool,
    /// Lay the fit on the depth image ([`FitRun::refine_with_depth`]).
    pub refine_depth: bool,
    /// Perceive the simulated sensor's depth instead of the exact render depth
    /// ([`boxpose_data::Frame::use_sensor_depth`]).
    pub sensor_depth: bool,
    /// With segmenter crops, render what the perception reads: the whole frame at the
    /// segmenter's input width, then the keypoint network's window around the detection at full
    /// resolution (instead of the whole frame at full resolution; `whole_frames` overrides it).
    pub two_resolutions: bool,
}

impl SystemUnderTest {
    pub fn new(
        space: &SearchSpace,
        renderer: Renderer,
        model: KeypointModel,
        segmenter: Option<SegmenterModel>,
        crops: Crops,
        method: Method,
    ) -> Result<Self> {
        if crops == Crops::Predicted && segmenter.is_none() {
            return Err(SearchError::Sample(
                "--crops predicted needs a segmenter".into(),
            ));
        }
        Ok(Self {
            physics: space.physics,
            renderer,
            perceiver: Perceiver::Own {
                model,
                segmenter,
                method,
            },
            crops,
            min_visible_fraction: 0.25,
            whole_frames: false,
            refine_depth: false,
            sensor_depth: false,
            two_resolutions: false,
        })
    }

    /// Another system under test: it gets whole frames (with ground-truth crops, the target's
    /// visible box and mask too) and answers with a pose.
    pub fn external(
        space: &SearchSpace,
        renderer: Renderer,
        system: ExternalSut,
        crops: Crops,
    ) -> Result<Self> {
        Ok(Self {
            physics: space.physics,
            renderer,
            perceiver: Perceiver::External(system),
            crops,
            min_visible_fraction: 0.25,
            whole_frames: true,
            refine_depth: false,
            sensor_depth: false,
            two_resolutions: false,
        })
    }
}

impl Evaluate for SystemUnderTest {
    /// Runs one sample: `parameters` (from z), scene `scene_id` with nuisance seed `seed`.
    fn evaluate(
        &mut self,
        space: &SearchSpace,
        parameters: &crate::space::Parameters,
        scene_id: i64,
        seed: i64,
    ) -> Result<Outcome> {
        let mut seconds = StageSeconds::default();
        let start = Instant::now();
        let mut sampled = scene::build(space, parameters, scene_id, seed)?;
        let settled = scene::settle(&mut sampled, &self.physics);
        seconds.settle = start.elapsed().as_secs_f64();
        let not_stable = match settled {
            Ok(outcome) => outcome.rejection.map(|r| r.to_string()),
            // a drop MuJoCo cannot integrate is a scene that does not settle, not a tool failure
            Err(SearchError::Physics(boxpose_physics::PhysicsError::Diverged {
                time_s,
                warning,
            })) => Some(format!("simulation diverged at {time_s:.3} s ({warning})")),
            Err(e) => return Err(e),
        };
        let mut outcome = Outcome {
            result: Err(Invalid::NotStable(String::new())),
            seconds,
            scene: sampled.scene.clone(),
            objects: sampled.objects.clone(),
            rendered: None,
            peaks: Vec::new(),
        };
        if let Some(reason) = not_stable {
            outcome.result = Err(Invalid::NotStable(reason));
            return Ok(outcome);
        }

        let scenes = Scene::to_batch(std::slice::from_ref(&sampled.scene));
        let objects = Object::to_batch(&sampled.objects);
        let start = Instant::now();
        self.renderer.load_scene(&scenes, &objects, scene_id)?;
        outcome.seconds.render = start.elapsed().as_secs_f64();
        let (frame, rendered, found) = match self.segmenter_width() {
            Some(width) => self.render_two_resolutions(scene_id, width, &mut outcome.seconds)?,
            None => {
                let start = Instant::now();
                let (frame, rendered) = self.render_frame(scene_id)?;
                outcome.seconds.render += start.elapsed().as_secs_f64();
                (frame, rendered, None)
            }
        };
        outcome.rendered = Some((rendered.frames, rendered.instances));
        let instance = target_instance(&frame)?;
        // two resolutions: the whole frame decided whether the target is visible enough
        if found.is_none() && !visible_enough(instance, self.min_visible_fraction) {
            outcome.result = Err(Invalid::NotVisible {
                visible_fraction: instance.visible_fraction,
            });
            return Ok(outcome);
        }
        let (perceived, peaks) = match &mut self.perceiver {
            Perceiver::Own {
                model,
                segmenter,
                method,
            } => {
                let found = match found {
                    Some(found) => found,
                    None => {
                        let crops = match segmenter {
                            Some(segmenter) if self.crops == Crops::Predicted => {
                                CropSource::Segmenter(segmenter)
                            }
                            _ => CropSource::GroundTruth,
                        };
                        let start = Instant::now();
                        let found =
                            evaluation::instance_crops(&model.config, &frame, &[instance], crops)?;
                        outcome.seconds.inference += start.elapsed().as_secs_f64();
                        found
                    }
                };
                let fit = FitChoice {
                    method: *method,
                    refine_depth: self.refine_depth,
                };
                let (perceived, peaks) =
                    perceive(model, fit, &found, &frame, instance, &mut outcome.seconds)?;
                (Ok(perceived), peaks)
            }
            Perceiver::External(system) => {
                let crop = match self.crops {
                    Crops::Gt => instance.visible_bbox,
                    Crops::Predicted => None,
                };
                let start = Instant::now();
                let answer = system.perceive(scene_id, &frame, instance, crop);
                outcome.seconds.inference = start.elapsed().as_secs_f64();
                match answer {
                    Ok(answer) => score_answer(answer, instance)?,
                    Err(reason) => (Err(Invalid::SystemUnderTest(reason)), Vec::new()),
                }
            }
        };
        outcome.result = perceived;
        outcome.peaks = peaks;
        Ok(outcome)
    }
}

/// The target's instance row in a render of a sample's scene.
fn target_instance(frame: &Frame) -> Result<&Instance> {
    frame
        .instances
        .iter()
        .find(|i| i.object_id == TARGET_OBJECT_ID)
        .ok_or_else(|| {
            SearchError::Sample(format!(
                "scene {}: the render has no instance row of the target",
                frame.scene_id
            ))
        })
}

/// Whether a target is scored: visible in at least `min_visible_fraction` of its projection.
fn visible_enough(instance: &Instance, min_visible_fraction: f32) -> bool {
    instance.visible_fraction >= min_visible_fraction && instance.visible_bbox.is_some()
}

impl SystemUnderTest {
    /// The width the segmenter reads frames at, when samples render at two resolutions.
    fn segmenter_width(&self) -> Option<u32> {
        match &self.perceiver {
            Perceiver::Own {
                segmenter: Some(segmenter),
                ..
            } if self.two_resolutions && self.crops == Crops::Predicted && !self.whole_frames => {
                u32::try_from(segmenter.config.input_width).ok()
            }
            _ => None,
        }
    }

    /// Segmenter crops from two renders of the loaded scene: the whole frame at the segmenter's
    /// input `width` (where a target too hidden to score, or one the segmenter misses, ends the
    /// sample), then — for a target it found — only the region the keypoint network reads at full
    /// resolution: the crop window around the detection, carried to the recipe's resolution
    /// ([`window_region`]), with the detection carried to it
    /// ([`boxpose_learn::segmentation::Detection::carried_to`]). The frame returned is the one
    /// the keypoint network reads, with its crop; the segmenter's time is inference.
    fn render_two_resolutions(
        &mut self,
        scene_id: i64,
        width: u32,
        seconds: &mut StageSeconds,
    ) -> Result<(Frame, boxpose_render::Rendered, Option<FrameCrops>)> {
        let sensor_depth = self.sensor_depth;
        let start = Instant::now();
        let whole = RenderRequest {
            width: Some(width),
            ..RenderRequest::default()
        };
        let (small, small_rendered) =
            render_once(&mut self.renderer, &whole, scene_id, sensor_depth)?;
        seconds.render += start.elapsed().as_secs_f64();
        let Perceiver::Own {
            model,
            segmenter: Some(segmenter),
            ..
        } = &self.perceiver
        else {
            unreachable!("segmenter_width is set only for the own pipeline with a segmenter");
        };
        let target = target_instance(&small)?;
        if !visible_enough(target, self.min_visible_fraction) {
            return Ok((small, small_rendered, None));
        }
        let start = Instant::now();
        let detection = evaluation::detection_of(segmenter, &small, target)?;
        seconds.inference += start.elapsed().as_secs_f64();
        let config = &model.config;
        let margin = config.crop_margin;
        let recipe_size = render_settings(&small_rendered.frames)?
            .get("scaled_from")
            .and_then(|v| serde_json::from_value::<[u32; 2]>(v.clone()).ok());
        let (detection, recipe_size) = match (detection, recipe_size) {
            (Some(detection), Some(size)) => (detection, size),
            // not found, or the recipe's frame is no wider than the segmenter's: no second render
            (other, _) => {
                let found = FrameCrops::of_detection(config, &small, other);
                return Ok((small, small_rendered, Some(found)));
            }
        };
        let start = Instant::now();
        let region = RenderRequest {
            crop: Some(window_region(
                &small.intrinsics,
                small.width,
                recipe_size,
                detection.bbox,
                margin,
            )),
            ..RenderRequest::default()
        };
        let (mut frame, mut rendered) =
            render_once(&mut self.renderer, &region, scene_id, sensor_depth)?;
        let mut carried = detection.carried_to(&small, &frame);
        // the region is the window's, so this holds unless rounding betrays it: then read the
        // whole frame rather than a window padded past the render
        if !window_inside_render(&rendered.frames, &frame, carried.bbox, margin)? {
            let whole = RenderRequest::default();
            (frame, rendered) = render_once(&mut self.renderer, &whole, scene_id, sensor_depth)?;
            carried = detection.carried_to(&small, &frame);
        }
        seconds.render += start.elapsed().as_secs_f64();
        let found = FrameCrops::of_detection(config, &frame, Some(carried));
        Ok((frame, rendered, Some(found)))
    }

    /// Renders the loaded scene: the whole frame for the segmenter; for ground-truth crops only
    /// the region the network's window reaches. That region is first the window of an unoccluded
    /// target (its projected box × the crop margin); when occlusion moves the visible box so that
    /// the window leaves it, the scene is rendered again with the region that holds any window
    /// (the projected box grown by the margin on every side).
    fn render_frame(&mut self, scene_id: i64) -> Result<(Frame, boxpose_render::Rendered)> {
        let margin = match &self.perceiver {
            Perceiver::Own { model, .. } => model.config.crop_margin,
            Perceiver::External(_) => 0.0,
        };
        let mut margins: &[f64] = match (&self.perceiver, self.crops) {
            (Perceiver::Own { .. }, Crops::Gt) if !self.whole_frames => &[margin, 1.0 + margin],
            _ => &[],
        };
        loop {
            let request = RenderRequest {
                crop_object: margins.first().map(|&m| (TARGET_OBJECT_ID, m)),
                ..RenderRequest::default()
            };
            let (frame, rendered) =
                render_once(&mut self.renderer, &request, scene_id, self.sensor_depth)?;
            let covered = match (
                request.crop_object,
                frame
                    .instances
                    .iter()
                    .find(|i| i.object_id == TARGET_OBJECT_ID)
                    .and_then(|i| i.visible_bbox),
            ) {
                (Some(_), Some(bbox)) => {
                    window_inside_render(&rendered.frames, &frame, bbox, margin)?
                }
                _ => true,
            };
            if covered || margins.len() <= 1 {
                return Ok((frame, rendered));
            }
            margins = &margins[1..];
        }
    }
}

/// The pixel region [x0, y0, x1, y1) of the recipe's `[width, height]` frame that the keypoint
/// network reads around `bbox`, a detection in a smaller render of the same view (`small`, its
/// intrinsics, `small_width` pixels across, the principal point at the centre as in the recipe's
/// frame): the crop window (`margin` × the detection's box carried to full resolution) plus
/// 2 pixels for the crop's resampling, clipped to the frame.
fn window_region(
    small: &Intrinsics,
    small_width: usize,
    [width, height]: [u32; 2],
    bbox: [i32; 4],
    margin: f64,
) -> [u32; 4] {
    let k = f64::from(width) / small_width as f64;
    let full = Intrinsics {
        fx: small.fx * k,
        fy: small.fy * k,
        cx: 0.5 * (f64::from(width) - 1.0),
        cy: 0.5 * (f64::from(height) - 1.0),
    };
    let window = data::CropWindow::around(carried_bbox(bbox, small, &full), margin);
    let clip = |v: f64, n: u32| v.clamp(0.0, f64::from(n)) as u32;
    let near = |v: f64| (v - 2.0).floor();
    let far = |v: f64| (v + window.side + 2.0).ceil();
    // a detection's window overlaps the frame, so each side keeps at least one pixel
    let (x0, y0) = (
        clip(near(window.x0), width - 1),
        clip(near(window.y0), height - 1),
    );
    let (x1, y1) = (clip(far(window.x0), width), clip(far(window.y0), height));
    [x0, y0, x1.max(x0 + 1), y1.max(y0 + 1)]
}

/// One render of the loaded scene as a frame, reading the sensor's depth when `sensor_depth`.
fn render_once(
    renderer: &mut Renderer,
    request: &RenderRequest,
    scene_id: i64,
    sensor_depth: bool,
) -> Result<(Frame, boxpose_render::Rendered)> {
    let request = RenderRequest {
        sensor_depth: sensor_depth.then_some(true),
        ..request.clone()
    };
    let rendered = renderer.render(&request)?;
    let source = std::path::PathBuf::from(format!("<render of sample scene {scene_id}>"));
    let mut frame = boxpose_data::decode_frames(&source, &rendered.frames, &rendered.instances)?
        .pop()
        .ok_or_else(|| {
            SearchError::Sample(format!("scene {scene_id}: the renderer returned no frame"))
        })?;
    if sensor_depth && !frame.use_sensor_depth() {
        return Err(SearchError::Sample(format!(
            "scene {scene_id}: the renderer returned no sensor depth"
        )));
    }
    Ok((frame, rendered))
}

/// The target through [`inference::perceive`], as `boxpose eval` and `boxpose predict` see it,
/// on its crop in `found`, with the fit under test scored against its truth.
fn perceive(
    model: &KeypointModel,
    fit: FitChoice,
    found: &FrameCrops,
    frame: &Frame,
    instance: &Instance,
    seconds: &mut StageSeconds,
) -> Result<(Perceived, Vec<[f64; 3]>)> {
    let start = Instant::now();
    let Some(crop) = found.crops[0] else {
        return Ok((Perceived::NotDetected, Vec::new()));
    };
    let known = BoxModel::new(Vector3::from(instance.size))?;
    let (mut run, points) = perceive_crop(model, fit.method, frame, crop, known)?;
    if fit.refine_depth {
        run.refine_with_depth(
            &points,
            &boxpose_learn::data::depth_view(frame),
            found.mask_of(frame, instance, 0),
        );
    }
    let fit = run;
    seconds.inference += start.elapsed().as_secs_f64() - fit.fit_time_us / 1e6;

    let start = Instant::now();
    let outcome = fit.score(&known, &evaluation::true_pose(instance), &points);
    seconds.fit = fit.fit_time_us / 1e6 + start.elapsed().as_secs_f64();
    Ok((
        perceived(outcome, instance.size, true),
        corner_list(&points),
    ))
}

/// The fit under test, and whether its pose is laid on the depth image.
#[derive(Debug, Clone, Copy)]
struct FitChoice {
    method: Method,
    refine_depth: bool,
}

/// This project's perception of one box on `crop`: the network, its NMS peaks back-projected
/// (camera frame), and `method`'s fit of a box of `known` size, its mirror tie settled with the
/// frame's depth ([`inference::perceive`]).
fn perceive_crop(
    model: &KeypointModel,
    method: Method,
    frame: &Frame,
    crop: CropRequest,
    known: BoxModel,
) -> Result<(FitRun, Vec<Point3<f64>>)> {
    let query = BoxQuery {
        crop,
        known_box: Some(known),
    };
    let mut perception = inference::perceive(model, frame, &[query], &[method], 1)?.remove(0);
    Ok((perception.fits.remove(0), perception.points))
}

fn corner_list(points: &[Point3<f64>]) -> Vec<[f64; 3]> {
    points.iter().map(|p| [p.x, p.y, p.z]).collect()
}

/// A fit's outcome for a box of true `size` as a sample's: scored metrics (a non-finite one is a fit that failed, named as
/// such: a committed sample must read back), a failed fit, or no box. `with_confidence`: the
/// fit's confidence is its own (false: an external system gave none).
fn perceived(outcome: FitOutcome, size: [f64; 3], with_confidence: bool) -> Perceived {
    match outcome {
        FitOutcome::Scored(s) => {
            let mut metrics = Metrics::of(&s, size);
            if !with_confidence {
                metrics.confidence = None;
            }
            match metrics {
                m if m.is_finite() => Perceived::Fitted(m),
                m => Perceived::FitFailed(format!("the fit's metrics are not finite: {m:?}")),
            }
        }
        FitOutcome::Failed(e) => Perceived::FitFailed(e),
        FitOutcome::NotDetected => Perceived::NotDetected,
    }
}

/// A sample's perception: scored (or failed), or not scored and why.
type ScoredOrInvalid = std::result::Result<Perceived, Invalid>;

/// An external system's answer scored against the target's truth as the own pipeline's fits are
/// (`boxpose eval --sut` writes these scores): the fit's outcome and the peaks it reported
/// (camera frame, metres; empty when it gave none).
pub fn score_external(answer: Answer, instance: &Instance) -> Result<(FitOutcome, Vec<[f64; 3]>)> {
    let known = BoxModel::new(Vector3::from(instance.size))?;
    Ok(match answer {
        Answer::NotFound => (FitOutcome::NotDetected, Vec::new()),
        Answer::FitFailed(reason) => (FitOutcome::Failed(reason), Vec::new()),
        Answer::Found {
            pose,
            size_m,
            confidence,
            peaks,
        } => {
            let estimate = match size_m {
                Some(size) => BoxModel::new(Vector3::from(size))?,
                None => known,
            };
            let fitted = Fitted::reported(
                estimate,
                pose,
                size_m.is_some(),
                confidence.unwrap_or(f64::NAN),
            );
            let outcome = fitted.score(0.0, &known, &evaluation::true_pose(instance), &[]);
            (outcome, peaks)
        }
    })
}

/// [`score_external`] as a search sample's perception.
fn score_answer(answer: Answer, instance: &Instance) -> Result<(ScoredOrInvalid, Vec<[f64; 3]>)> {
    let with_confidence = matches!(
        answer,
        Answer::Found {
            confidence: Some(_),
            ..
        }
    );
    let (outcome, peaks) = score_external(answer, instance)?;
    Ok((
        Ok(perceived(outcome, instance.size, with_confidence)),
        peaks,
    ))
}

/// The project's own pipeline as an external system (`boxpose sut-serve`, the protocol's
/// reference): one request with a ground-truth crop answered as the search's own path answers it.
pub fn own_answer(
    model: &KeypointModel,
    method: Method,
    request: &external::Request,
) -> Result<Answer> {
    let header = &request.header;
    let Some(bbox) = header.crop else {
        return Err(SearchError::Sample(
            "the own pipeline's server has no segmenter: run the search with --crops gt".into(),
        ));
    };
    let frame = &request.frame;
    let label = (header.target_object_id + 1) as u16;
    let Some(crop) = CropRequest::around(frame, &model.config, bbox, |i| {
        frame.instance_mask[i] == label
    }) else {
        return Ok(Answer::FitFailed(
            "no visible pixel with a depth to crop".into(),
        ));
    };
    let known = BoxModel::new(Vector3::from(header.box_size_m))?;
    let (fit, points) = perceive_crop(model, method, frame, crop, known)?;
    Ok(match fit.fitted {
        Ok(fitted) => Answer::Found {
            pose: fitted.pose,
            size_m: fitted.fits_size.then(|| fitted.model.size().into()),
            confidence: Some(fitted.confidence(&points)?.confidence),
            peaks: corner_list(&points),
        },
        Err(e) => Answer::FitFailed(e.to_string()),
    })
}

/// Whether the network's window around the visible `bbox` (crop-frame pixels) lies inside the
/// rendered region, or leaves it only where the full image ends as well (where a whole-frame
/// render clips it the same way). One pixel of slack on each side for bilinear resampling.
fn window_inside_render(
    frames: &RecordBatch,
    frame: &Frame,
    bbox: [i32; 4],
    margin: f64,
) -> Result<bool> {
    let settings = render_settings(frames)?;
    let numbers = |key: &str| -> Option<Vec<f64>> {
        settings
            .get(key)?
            .as_array()?
            .iter()
            .map(|v| v.as_f64())
            .collect()
    };
    let (Some(region), Some(image)) = (numbers("crop"), numbers("image_size")) else {
        return Ok(true); // the whole frame was rendered
    };
    let window = data::CropWindow::around(bbox, margin);
    let (w, h) = (frame.width as f64, frame.height as f64);
    let left = window.x0 - 1.0 >= 0.0 || region[0] <= 0.0;
    let top = window.y0 - 1.0 >= 0.0 || region[1] <= 0.0;
    let right = window.x0 + window.side + 1.0 <= w || region[2] >= image[0];
    let bottom = window.y0 + window.side + 1.0 <= h || region[3] >= image[1];
    Ok(left && top && right && bottom)
}

/// The `render_settings` of a render's one frame row.
fn render_settings(frames: &RecordBatch) -> Result<serde_json::Value> {
    use boxpose_data::arrow::array::AsArray;
    let settings = frames
        .column_by_name("render_settings")
        .map(|c| c.as_string::<i32>().value(0).to_string())
        .unwrap_or_default();
    serde_json::from_str(&settings)
        .map_err(|e| SearchError::Sample(format!("render_settings: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 640×480 frame rendered 320 wide: focal length 500 → 250, principal points at centres.
    const SMALL: Intrinsics = Intrinsics {
        fx: 250.0,
        fy: 250.0,
        cx: 159.5,
        cy: 119.5,
    };

    #[test]
    fn the_region_is_the_window_around_the_detection_at_full_resolution() {
        // [100, 140) × [80, 110) at 320 wide is [200, 280) × [160, 220) at 640: the window is
        // 1.25 × 80 = 100 pixels square around (240, 190), plus 2 pixels each side
        let region = window_region(&SMALL, 320, [640, 480], [100, 80, 140, 110], 1.25);
        assert_eq!(region, [188, 138, 292, 242]);
    }

    #[test]
    fn a_region_at_the_frames_edge_is_clipped_to_it() {
        // [0, 40)² at full resolution: the window [-5, 45)² loses what lies outside the frame
        assert_eq!(
            window_region(&SMALL, 320, [640, 480], [0, 0, 20, 20], 1.25),
            [0, 0, 47, 47]
        );
        assert_eq!(
            window_region(&SMALL, 320, [640, 480], [310, 230, 320, 240], 1.25),
            [615, 455, 640, 480]
        );
    }
}
