//! Instance segmentation (paper step 3, where the paper uses Mask R-CNN), bottom-up in the
//! manner of Panoptic-DeepLab: one network over the whole RGBD frame outputs, at 1/4 of its input
//! resolution, a foreground logit, an object-centre heatmap and every pixel's offset to its
//! object's centre. Foreground pixels vote for a centre; each voted peak of the centre heatmap is
//! one box, with its mask, bounding box and score. A model folder holds `segmenter.toml` and
//! `model.bpk`.

use std::path::Path;

use boxpose_data::{Frame, Intrinsics};
use boxpose_geometry::detection::{
    ImageDetections, average_precision, bbox_iou, coco_average_precision, greedy_match, mask_iou,
};
use burn::prelude::*;
use burn::tensor::activation::log_sigmoid;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::LearnError;
use crate::config::{self, AugmentConfig, Backbone, DataConfig, OptimizerConfig};
use crate::data::{self, InstanceSet};
use crate::loader::ExampleSource;
use crate::model::ResNetDeconv;
use crate::model_dir::{check_model_dir, check_same_network, load_model_dir, save_model_dir};
use crate::training::Task;

pub(crate) const SEGMENTER_FILE: &str = "segmenter.toml";
/// Output channels: foreground logit, centre heatmap, offset to the centre (x, y) in output pixels.
const OUTPUTS: usize = 4;
/// Target channels: the outputs' targets and the mask of pixels whose offset is supervised.
const TARGETS: usize = 5;
/// Frames per forward pass of the segmenter at inference and validation.
const SEGMENT_BATCH: usize = 4;

/// What the segmenter sees and how its output becomes instances.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmenterConfig {
    pub backbone: Backbone,
    /// The frame is resized to this (multiples of 32); the output is a quarter of it.
    pub input_width: usize,
    pub input_height: usize,
    /// Standard deviation of the target centre Gaussians, output pixels.
    pub centre_sigma: f64,
    /// Loss weights of the centre heatmap (MSE) and the offsets (L1, output pixels) beside the
    /// foreground's binary cross-entropy.
    pub centre_weight: f64,
    pub offset_weight: f64,
    /// A pixel is foreground above this probability; a centre is a local maximum above this.
    pub foreground_threshold: f32,
    pub centre_threshold: f32,
    /// Instances with fewer output pixels are dropped.
    pub min_pixels: usize,
    /// The size frames are resized to at inference (multiples of 32), when not the training
    /// input's. The weights are convolutional: read larger than trained at, they keep more of the
    /// touching boxes of dense bins apart, but lose some of what they learnt at the training
    /// scale elsewhere (pallets, floors; docs/learning.md, "The reading size"). Training and its
    /// validation use the input size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inference_width: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inference_height: Option<usize>,
}

impl SegmenterConfig {
    /// Whether weights trained with `trained` can start a run that trains `self`: the backbone
    /// and the input size must agree; the loss settings (centre σ, loss weights) and the
    /// decoding thresholds may differ, because the weights fit any of them.
    pub fn can_fine_tune_from(&self, trained: &SegmenterConfig) -> bool {
        self.backbone == trained.backbone
            && self.input_width == trained.input_width
            && self.input_height == trained.input_height
    }

    /// The configuration inference runs with: the input resized to the inference size, if one
    /// is set.
    pub fn for_inference(&self) -> SegmenterConfig {
        let mut config = self.clone();
        if let (Some(width), Some(height)) = (self.inference_width, self.inference_height) {
            config.input_width = width;
            config.input_height = height;
        }
        config
    }

    pub fn output_size(&self) -> [usize; 2] {
        [self.input_width / 4, self.input_height / 4]
    }

    pub fn validate(&self) -> Result<(), LearnError> {
        if self.input_width == 0
            || !self.input_width.is_multiple_of(32)
            || self.input_height == 0
            || !self.input_height.is_multiple_of(32)
        {
            return Err(LearnError::Config(format!(
                "input {}×{} must be positive multiples of 32",
                self.input_width, self.input_height
            )));
        }
        match (self.inference_width, self.inference_height) {
            (None, None) => {}
            (Some(w), Some(h))
                if w > 0 && w.is_multiple_of(32) && h > 0 && h.is_multiple_of(32) => {}
            (w, h) => {
                return Err(LearnError::Config(format!(
                    "inference_width {w:?} and inference_height {h:?}: give both, positive \
                     multiples of 32, or neither"
                )));
            }
        }
        if !(self.centre_sigma > 0.0) {
            return Err(LearnError::Config("centre_sigma must be positive".into()));
        }
        if !((0.0..=1.0).contains(&self.foreground_threshold)
            && (0.0..=1.0).contains(&self.centre_threshold))
        {
            return Err(LearnError::Config(format!(
                "foreground_threshold {} and centre_threshold {} must lie in [0, 1]",
                self.foreground_threshold, self.centre_threshold
            )));
        }
        if self.min_pixels == 0 {
            return Err(LearnError::Config(
                "min_pixels must be at least 1: an instance needs a pixel".into(),
            ));
        }
        Ok(())
    }
}

/// `boxpose train-segmenter`'s TOML file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmenterTrainConfig {
    pub segmenter: SegmenterConfig,
    pub augment: AugmentConfig,
    pub optimizer: OptimizerConfig,
    pub data: DataConfig,
}

impl SegmenterTrainConfig {
    pub fn load(path: &Path) -> Result<Self, LearnError> {
        config::read_config(path, Self::validate)
    }

    pub fn validate(&self) -> Result<(), LearnError> {
        self.segmenter.validate()?;
        self.augment.validate()?;
        if self.augment.rotation_deg != 0.0 {
            return Err(LearnError::Config(format!(
                "[augment] rotation_deg = {}: the segmenter's whole-frame input does not rotate \
                 (only the keypoint network's crops do); remove it or set 0",
                self.augment.rotation_deg
            )));
        }
        if self.augment.sensor_depth != 0.0 {
            return Err(LearnError::Config(format!(
                "[augment] sensor_depth = {}: only the keypoint network's crops read the sensor \
                 depth in training; remove it or set 0",
                self.augment.sensor_depth
            )));
        }
        self.optimizer.validate()?;
        self.data.validate()
    }
}

/// One found box: its mask over the full frame (row-major), bounding box and score.
#[derive(Debug, Clone)]
pub struct Detection {
    pub mask: Vec<bool>,
    /// (x_min, y_min, x_max, y_max), max exclusive, full-frame pixels.
    pub bbox: [i32; 4],
    pub score: f32,
}

impl Detection {
    /// This detection, found in `found_in`, as it lies in `to`: a frame from the same camera pose
    /// with other intrinsics (the same view rendered at another resolution, or a region of it).
    /// A pixel of `to` is in the mask when the `found_in` pixel its centre falls in is; the box
    /// is `found_in`'s box carried through the intrinsics and rounded outwards, so it may reach
    /// past the edges of a region (where the mask, which `to` cannot hold, ends).
    pub fn carried_to(&self, found_in: &Frame, to: &Frame) -> Detection {
        let (a, b) = (&found_in.intrinsics, &to.intrinsics);
        let bbox = carried_bbox(self.bbox, a, b);
        let source = |p: usize, (c_b, f_b): (f64, f64), (c_a, f_a): (f64, f64), n: usize| {
            let q = ((p as f64 - c_b) / f_b * f_a + c_a).round();
            (q >= 0.0 && q < n as f64).then_some(q as usize)
        };
        let mut mask = vec![false; to.width * to.height];
        for y in 0..to.height {
            let Some(v) = source(y, (b.cy, b.fy), (a.cy, a.fy), found_in.height) else {
                continue;
            };
            for x in 0..to.width {
                if let Some(u) = source(x, (b.cx, b.fx), (a.cx, a.fx), found_in.width) {
                    mask[y * to.width + x] = self.mask[v * found_in.width + u];
                }
            }
        }
        Detection {
            mask,
            bbox,
            score: self.score,
        }
    }
}

/// A pixel box (x_min, y_min, x_max, y_max; max exclusive) of one view, carried to another view
/// from the same camera pose with intrinsics `to` (another resolution, or a region of it) and
/// rounded outwards.
pub fn carried_bbox(bbox: [i32; 4], from: &Intrinsics, to: &Intrinsics) -> [i32; 4] {
    // pixel-edge coordinates (pixel i spans [i, i + 1]); the intrinsics count from centres
    let edge = |e: i32, (c_a, f_a): (f64, f64), (c_b, f_b): (f64, f64)| {
        (f64::from(e) - 0.5 - c_a) / f_a * f_b + c_b + 0.5
    };
    let (x, y) = (
        ((from.cx, from.fx), (to.cx, to.fx)),
        ((from.cy, from.fy), (to.cy, to.fy)),
    );
    [
        edge(bbox[0], x.0, x.1).floor() as i32,
        edge(bbox[1], y.0, y.1).floor() as i32,
        edge(bbox[2], x.0, x.1).ceil() as i32,
        edge(bbox[3], y.0, y.1).ceil() as i32,
    ]
}

/// Image pixels per input pixel, for a frame resized to the segmenter's input.
fn input_step(config: &SegmenterConfig, frame: &Frame) -> [f64; 2] {
    [
        frame.width as f64 / config.input_width as f64,
        frame.height as f64 / config.input_height as f64,
    ]
}

/// The frame resized to the input, depth relative to the frame's median depth.
pub(crate) fn frame_input(
    config: &SegmenterConfig,
    frame: &Frame,
    augment: Option<(&AugmentConfig, &mut ChaCha8Rng)>,
) -> Vec<f32> {
    let whole = data::CropWindow {
        x0: 0.0,
        y0: 0.0,
        side: frame.width.max(frame.height) as f64,
    };
    let z_ref = data::reference_depth(frame, &whole, |_| false).unwrap_or(1.0);
    data::resample_input(
        frame,
        [0.0, 0.0],
        input_step(config, frame),
        [config.input_width, config.input_height],
        (z_ref, data::DEPTH_SCALE_M),
        None,
        augment,
    )
}

/// Object label (object_id + 1, 0 = none) at the centre of each output pixel.
fn output_labels(config: &SegmenterConfig, frame: &Frame) -> Vec<u16> {
    let [w, h] = config.output_size();
    let [sx, sy] = input_step(config, frame);
    let mut labels = vec![0u16; w * h];
    for v in 0..h {
        let y = data::nearest_source(v, 4.0 * sy, 1.0, frame.height);
        for u in 0..w {
            let x = data::nearest_source(u, 4.0 * sx, 1.0, frame.width);
            labels[v * w + u] = frame.instance_mask[y * frame.width + x];
        }
    }
    labels
}

/// Targets `[5, H/4, W/4]`: foreground, centre Gaussians at each visible box's mask centroid,
/// offsets (x, y) from each foreground pixel to its box's centroid, and the offset weight.
pub fn frame_targets(config: &SegmenterConfig, frame: &Frame) -> Vec<f32> {
    let [w, h] = config.output_size();
    let plane = w * h;
    let labels = output_labels(config, frame);
    let max_label = labels.iter().copied().max().unwrap_or(0) as usize;
    let mut sums = vec![(0.0f64, 0.0f64, 0usize); max_label + 1];
    for (i, &label) in labels.iter().enumerate() {
        if label > 0 {
            let s = &mut sums[label as usize];
            s.0 += (i % w) as f64;
            s.1 += (i / w) as f64;
            s.2 += 1;
        }
    }
    let centroids: Vec<Option<(f64, f64)>> = sums
        .iter()
        .map(|&(x, y, n)| (n > 0).then(|| (x / n as f64, y / n as f64)))
        .collect();
    let mut target = vec![0.0f32; TARGETS * plane];
    let two_sigma_sq = 2.0 * config.centre_sigma * config.centre_sigma;
    for (i, &label) in labels.iter().enumerate() {
        let (u, v) = ((i % w) as f64, (i / w) as f64);
        let mut centre = 0.0f64;
        for &(cx, cy) in centroids.iter().flatten() {
            centre = centre.max((-((u - cx).powi(2) + (v - cy).powi(2)) / two_sigma_sq).exp());
        }
        target[plane + i] = centre as f32;
        if let Some((cx, cy)) = centroids
            .get(label as usize)
            .copied()
            .flatten()
            .filter(|_| label > 0)
        {
            target[i] = 1.0;
            target[2 * plane + i] = (cx - u) as f32;
            target[3 * plane + i] = (cy - v) as f32;
            target[4 * plane + i] = 1.0;
        }
    }
    target
}

/// Groups one output `[4, H/4, W/4]` into instances on the full frame.
pub fn decode(config: &SegmenterConfig, frame: &Frame, output: &[f32]) -> Vec<Detection> {
    let [w, h] = config.output_size();
    let plane = w * h;
    let sigmoid = |x: f32| 1.0 / (1.0 + (-x).exp());
    let centre = &output[plane..2 * plane];
    let mut centres = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let value = centre[v * w + u];
            if value < config.centre_threshold {
                continue;
            }
            let is_peak = (v.saturating_sub(1)..(v + 2).min(h)).all(|vv| {
                (u.saturating_sub(1)..(u + 2).min(w)).all(|uu| centre[vv * w + uu] <= value)
            });
            if is_peak {
                centres.push((u as f64, v as f64, value));
            }
        }
    }
    // every foreground pixel joins the centre nearest to where its offset points
    let mut owner = vec![usize::MAX; plane];
    let mut counts = vec![0usize; centres.len()];
    for i in 0..plane {
        if centres.is_empty() || sigmoid(output[i]) < config.foreground_threshold {
            continue;
        }
        let (x, y) = (
            (i % w) as f64 + output[2 * plane + i] as f64,
            (i / w) as f64 + output[3 * plane + i] as f64,
        );
        let nearest = (0..centres.len())
            .min_by(|&a, &b| {
                let d = |k: usize| (centres[k].0 - x).powi(2) + (centres[k].1 - y).powi(2);
                d(a).total_cmp(&d(b))
            })
            .expect("at least one centre");
        owner[i] = nearest;
        counts[nearest] += 1;
    }
    let [sx, sy] = input_step(config, frame);
    let mut detections = Vec::new();
    for (k, &(_, _, score)) in centres.iter().enumerate() {
        if counts[k] < config.min_pixels {
            continue;
        }
        let mut mask = vec![false; frame.width * frame.height];
        let mut bbox = [i32::MAX, i32::MAX, i32::MIN, i32::MIN];
        for y in 0..frame.height {
            let v = data::nearest_source(y, 1.0, 4.0 * sy, h);
            for x in 0..frame.width {
                let u = data::nearest_source(x, 1.0, 4.0 * sx, w);
                if owner[v * w + u] == k {
                    mask[y * frame.width + x] = true;
                    bbox = [
                        bbox[0].min(x as i32),
                        bbox[1].min(y as i32),
                        bbox[2].max(x as i32 + 1),
                        bbox[3].max(y as i32 + 1),
                    ];
                }
            }
        }
        detections.push(Detection { mask, bbox, score });
    }
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    detections
}

/// A trained segmenter on one device.
pub struct SegmenterModel {
    pub config: SegmenterConfig,
    pub net: ResNetDeconv,
    pub device: Device,
}

impl SegmenterModel {
    /// Loads `dir/segmenter.toml` and `dir/model.bpk`.
    pub fn load(dir: &Path, device: Device) -> Result<Self, LearnError> {
        let (config, net) = load_model_dir(
            dir,
            SEGMENTER_FILE,
            SegmenterConfig::validate,
            |c: &SegmenterConfig| ResNetDeconv::new(c.backbone, OUTPUTS, &device),
        )?;
        Ok(Self {
            config: config.for_inference(),
            net,
            device,
        })
    }

    /// Checks that `dir` holds a segmenter [`load`](Self::load) would read (a valid
    /// segmenter.toml and the weights file), without loading its weights.
    pub fn check_folder(dir: &Path) -> Result<(), LearnError> {
        check_model_dir(dir, SEGMENTER_FILE, SegmenterConfig::validate).map(|_| ())
    }

    /// Writes the model folder (segmenter.toml, model.bpk) atomically.
    pub fn save(
        config: &SegmenterConfig,
        net: &ResNetDeconv,
        dir: &Path,
    ) -> Result<(), LearnError> {
        save_model_dir(dir, SEGMENTER_FILE, config, net)
    }

    /// The boxes found in each frame.
    pub fn segment(&self, frames: &[&Frame]) -> Result<Vec<Vec<Detection>>, LearnError> {
        let (w, h) = (self.config.input_width, self.config.input_height);
        let mut out = Vec::with_capacity(frames.len());
        for chunk in frames.chunks(SEGMENT_BATCH) {
            let flat: Vec<f32> = chunk
                .iter()
                .flat_map(|f| frame_input(&self.config, f, None))
                .collect();
            let output = self.net.forward(Tensor::<4>::from_data(
                TensorData::new(flat, [chunk.len(), 4, h, w]),
                &self.device,
            ));
            let values: Vec<f32> = output
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| LearnError::Backend(format!("{e:?}")))?;
            if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
                return Err(LearnError::Backend(format!(
                    "the segmenter output a non-finite value ({bad}): corrupt weights?"
                )));
            }
            let per_frame = values.len() / chunk.len();
            out.extend(
                chunk
                    .iter()
                    .zip(values.chunks(per_frame))
                    .map(|(frame, output)| decode(&self.config, frame, output)),
            );
        }
        Ok(out)
    }
}

/// Mask and bounding-box AP of detections against a frame's true visible instances.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct SegmentationScores {
    pub mask_ap50: f64,
    /// Mean over IoU thresholds 0.50, 0.55, …, 0.95 (COCO's AP).
    pub mask_ap: f64,
    pub bbox_ap50: f64,
    pub bbox_ap: f64,
    pub true_instances: usize,
    pub detections: usize,
}

/// A ground-truth instance for matching: (object id, full-frame mask, bounding box x0, y0, x1, y1).
pub(crate) type TrueMask = (i32, Vec<bool>, [i32; 4]);

/// True instances a detector is asked to find: every box with a visible pixel.
pub(crate) fn true_masks(frame: &Frame) -> Vec<TrueMask> {
    frame
        .instances
        .iter()
        .filter_map(|i| {
            let bbox = i.visible_bbox?;
            let label = i.mask_label();
            Some((
                i.object_id,
                frame.instance_mask.iter().map(|&m| m == label).collect(),
                bbox,
            ))
        })
        .collect()
}

/// Mask and box AP over frames scored one at a time (COCO's definitions,
/// [`boxpose_geometry::detection`]): it keeps each detection's score and its overlaps with the
/// frame's true instances, not the masks, so a dataset can stream through.
#[derive(Debug, Default)]
pub struct DetectionScorer {
    masks: Vec<ImageDetections>,
    boxes: Vec<ImageDetections>,
}

impl DetectionScorer {
    /// Adds one frame's detections, matched against its true visible instances.
    pub fn add(&mut self, frame: &Frame, detections: &[Detection]) {
        let truths = true_masks(frame);
        let scores: Vec<f32> = detections.iter().map(|d| d.score).collect();
        let overlaps = |overlap: &dyn Fn(&Detection, &TrueMask) -> f64| ImageDetections {
            scores: scores.clone(),
            ious: detections
                .iter()
                .map(|d| truths.iter().map(|g| overlap(d, g)).collect())
                .collect(),
            true_count: truths.len(),
        };
        self.masks.push(overlaps(&|d, g| mask_iou(&d.mask, &g.1)));
        self.boxes.push(overlaps(&|d, g| bbox_iou(&d.bbox, &g.2)));
    }

    /// AP50 and COCO's AP over every frame added.
    pub fn scores(&self) -> SegmentationScores {
        SegmentationScores {
            mask_ap50: average_precision(&self.masks, 0.5),
            mask_ap: coco_average_precision(&self.masks),
            bbox_ap50: average_precision(&self.boxes, 0.5),
            bbox_ap: coco_average_precision(&self.boxes),
            true_instances: self.masks.iter().map(|i| i.true_count).sum(),
            detections: self.masks.iter().map(|i| i.scores.len()).sum(),
        }
    }
}

/// [`DetectionScorer`] over frames in memory.
pub fn score_detections(frames: &[&Frame], detections: &[Vec<Detection>]) -> SegmentationScores {
    let mut scorer = DetectionScorer::default();
    for (frame, detections) in frames.iter().zip(detections) {
        scorer.add(frame, detections);
    }
    scorer.scores()
}

/// The segmenter's task: whole frames of the training scenes.
pub struct SegmenterTask {
    pub config: SegmenterTrainConfig,
    pub set: InstanceSet,
}

impl SegmenterTask {
    pub fn load(config: SegmenterTrainConfig) -> Result<Self, LearnError> {
        config.validate()?;
        let set = InstanceSet::load(&config.data)?;
        Ok(Self { config, set })
    }
}

impl ExampleSource for SegmenterTask {
    fn train_items(&self) -> usize {
        self.set.train_frames.len()
    }

    fn training_example(
        &self,
        item: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<(Vec<f32>, Vec<f32>), LearnError> {
        let frame = self.set.frame(self.set.train_frames[item])?;
        let input = frame_input(
            &self.config.segmenter,
            &frame,
            Some((&self.config.augment, rng)),
        );
        Ok((input, frame_targets(&self.config.segmenter, &frame)))
    }
}

impl Task for SegmenterTask {
    fn input_shape(&self) -> [usize; 3] {
        [
            4,
            self.config.segmenter.input_height,
            self.config.segmenter.input_width,
        ]
    }

    fn target_shape(&self) -> [usize; 3] {
        let [w, h] = self.config.segmenter.output_size();
        [TARGETS, h, w]
    }

    fn network(&self, device: &Device) -> ResNetDeconv {
        ResNetDeconv::new(self.config.segmenter.backbone, OUTPUTS, device)
    }

    /// Binary cross-entropy of the foreground, plus weighted MSE of the centre heatmap, plus the
    /// weighted L1 error of the offsets over foreground pixels.
    fn loss(&self, output: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let c = &self.config.segmenter;
        let channel = |t: &Tensor<4>, k: usize| t.clone().narrow(1, k, 1);
        let (logit, fg) = (channel(&output, 0), channel(&target, 0));
        let bce = (fg.clone() * log_sigmoid(logit.clone())
            + (fg.neg() + 1.0) * log_sigmoid(logit.neg()))
        .neg()
        .mean();
        let centre = (channel(&output, 1) - channel(&target, 1))
            .powi_scalar(2)
            .mean();
        let weight = channel(&target, 4);
        let offset_error = (output.narrow(1, 2, 2) - target.narrow(1, 2, 2)).abs() * weight.clone();
        let offset = offset_error.sum() / (weight.sum() * 2.0 + 1.0);
        bce + centre * c.centre_weight + offset * c.offset_weight
    }

    fn validate(&self, net: &ResNetDeconv) -> Result<Vec<(String, f64)>, LearnError> {
        let device = net.devices().into_iter().next().unwrap_or_default();
        let model = SegmenterModel {
            config: self.config.segmenter.clone(),
            net: net.clone(),
            device,
        };
        if self.set.val_frames.is_empty() {
            return Err(LearnError::Data(format!(
                "no held-out frame: no scene has scene_id % {} == 0",
                self.config.data.val_modulus
            )));
        }
        let mut scorer = DetectionScorer::default();
        for chunk in self.set.val_frames.chunks(SEGMENT_BATCH) {
            let frames = chunk
                .iter()
                .map(|&f| self.set.frame(f))
                .collect::<Result<Vec<_>, _>>()?;
            let frames: Vec<&Frame> = frames.iter().map(|f| f.as_ref()).collect();
            for (frame, detections) in frames.iter().zip(model.segment(&frames)?) {
                scorer.add(frame, &detections);
            }
        }
        let s = scorer.scores();
        Ok(vec![
            ("mask_ap50".into(), s.mask_ap50),
            ("mask_ap".into(), s.mask_ap),
            ("bbox_ap50".into(), s.bbox_ap50),
            ("bbox_ap".into(), s.bbox_ap),
            (
                "detections_per_true".into(),
                s.detections as f64 / s.true_instances.max(1) as f64,
            ),
        ])
    }

    fn save_model(&self, net: &ResNetDeconv, dir: &Path) -> Result<(), LearnError> {
        SegmenterModel::save(&self.config.segmenter, net, dir)
    }

    fn check_same_network(&self, dir: &Path) -> Result<(), LearnError> {
        check_same_network(
            dir,
            SEGMENTER_FILE,
            &self.config.segmenter,
            SegmenterConfig::can_fine_tune_from,
        )
    }
}

/// For each of the frame's instances, the detection (index into `detections`) that found it:
/// COCO's matching ([`greedy_match`]) on mask IoU at `threshold`.
pub fn match_detections(
    frame: &Frame,
    detections: &[Detection],
    threshold: f64,
) -> Vec<Option<usize>> {
    let masks: Vec<Vec<bool>> = frame
        .instances
        .iter()
        .map(|i| {
            frame
                .instance_mask
                .iter()
                .map(|&m| m == i.mask_label())
                .collect()
        })
        .collect();
    let ious: Vec<Vec<f64>> = detections
        .iter()
        .map(|d| masks.iter().map(|mask| mask_iou(mask, &d.mask)).collect())
        .collect();
    let scores: Vec<f32> = detections.iter().map(|d| d.score).collect();
    let mut found = vec![None; frame.instances.len()];
    for (d, instance) in greedy_match(&ious, &scores, threshold)
        .into_iter()
        .enumerate()
    {
        if let Some(i) = instance {
            found[i] = Some(d);
        }
    }
    found
}
