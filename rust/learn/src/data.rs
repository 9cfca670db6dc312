//! From the dataset contract to network tensors: per instance, a square RGBD crop around the box
//! (its visible bounding box enlarged by a margin, jittered for training), resized to the network
//! input and normalized, and the target: a 3D Gaussian at every ground-truth corner in the
//! (z-bin, v, u) volume. No burn here: examples are flat arrays ([`crate::loader`] batches them).

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use boxpose_data::{Dataset, Frame, FrameEntry, Instance, Intrinsics};
use boxpose_geometry::depth::DepthView;
use boxpose_geometry::heatmap::{
    self, CropTransform, DepthBins, HeatmapDims, PinholeIntrinsics, VoxelGrid,
};
use nalgebra::Point3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::LearnError;
use crate::config::{AugmentConfig, DataConfig, NetworkConfig};

/// RGB is normalized as (x/255 − mean)/std with these (a neutral grey; boxes are not ImageNet).
const RGB_MEAN: f32 = 0.5;
const RGB_STD: f32 = 0.25;
/// Depth enters the network as (z − z_ref)/DEPTH_SCALE_M, clamped to ±DEPTH_CLAMP; 0 where the
/// pixel has no depth. A keypoint crop whose depth axis scales with it
/// ([`NetworkConfig::depth_stretch`]) divides by DEPTH_SCALE_M times the stretch.
pub(crate) const DEPTH_SCALE_M: f32 = 0.1;
const DEPTH_CLAMP: f32 = 3.0;

/// A square window of the image, in pixel-index coordinates: it covers pixels x0..x0+side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CropWindow {
    pub x0: f64,
    pub y0: f64,
    pub side: f64,
}

impl CropWindow {
    /// The square around a bounding box `(x_min, y_min, x_max, y_max)` (max exclusive), its side
    /// the box's longer side times `margin`.
    pub fn around(bbox: [i32; 4], margin: f64) -> Self {
        Self::around_extent(bbox.map(f64::from), margin)
    }

    /// [`Self::around`] for an extent in continuous pixel coordinates (pixel i spans [i, i + 1]).
    fn around_extent([x_min, y_min, x_max, y_max]: [f64; 4], margin: f64) -> Self {
        let side = (x_max - x_min).max(y_max - y_min).max(1.0) * margin;
        let (cx, cy) = ((x_min + x_max) / 2.0, (y_min + y_max) / 2.0);
        Self {
            x0: cx - side / 2.0,
            y0: cy - side / 2.0,
            side,
        }
    }

    /// Training jitter: shift the centre by up to `shift`·side, scale the side by 1 ± `scale`.
    fn jittered(self, augment: &AugmentConfig, rng: &mut ChaCha8Rng) -> Self {
        let side = self.side * (1.0 + rng.random_range(-augment.scale..=augment.scale));
        let cx = self.x0
            + self.side / 2.0
            + self.side * rng.random_range(-augment.shift..=augment.shift);
        let cy = self.y0
            + self.side / 2.0
            + self.side * rng.random_range(-augment.shift..=augment.shift);
        Self {
            x0: cx - side / 2.0,
            y0: cy - side / 2.0,
            side,
        }
    }
}

/// The camera turned about its optical axis by an angle: camera points turn about the z axis, and
/// image positions about the principal point (through normalized coordinates, so that fx ≠ fy
/// stays exact). Depth along the axis, and so every pixel's depth and visibility, is unchanged:
/// the turned crop and its turned corners are a true view of the same box.
#[derive(Debug, Clone, Copy)]
pub(crate) struct InPlaneTurn {
    cos: f64,
    sin: f64,
    intrinsics: [f64; 4],
}

impl InPlaneTurn {
    pub(crate) fn new(intrinsics: &Intrinsics, angle_rad: f64) -> Self {
        Self {
            cos: angle_rad.cos(),
            sin: angle_rad.sin(),
            intrinsics: [intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy],
        }
    }

    /// A point in the turned camera's frame.
    pub(crate) fn point(&self, [x, y, z]: [f64; 3]) -> [f64; 3] {
        [self.cos * x - self.sin * y, self.sin * x + self.cos * y, z]
    }

    /// Where a position of the original image (pixel-index coordinates: pixel centres at
    /// integers, as the intrinsics have them) is in the turned one.
    fn turned_position(&self, uv: [f64; 2]) -> [f64; 2] {
        self.turn_pixel(uv, self.sin)
    }

    /// Where a position of the turned image comes from in the original one.
    fn original_position(&self, uv: [f64; 2]) -> [f64; 2] {
        self.turn_pixel(uv, -self.sin)
    }

    fn turn_pixel(&self, [u, v]: [f64; 2], sin: f64) -> [f64; 2] {
        let [fx, fy, cx, cy] = self.intrinsics;
        let (x, y) = ((u - cx) / fx, (v - cy) / fy);
        [
            cx + fx * (self.cos * x - sin * y),
            cy + fy * (sin * x + self.cos * y),
        ]
    }
}

/// What ties a crop's heatmap to the camera: the voxel grid of a window at reference depth z_ref.
pub fn voxel_grid(
    config: &NetworkConfig,
    intrinsics: &Intrinsics,
    window: &CropWindow,
    z_ref: f64,
) -> VoxelGrid {
    let scale = window.side / config.heatmap_size() as f64;
    let stretch = config.depth_stretch(intrinsics.fx, window.side, z_ref);
    let [near, far] = config.depth_range_m.map(|z| z * stretch);
    VoxelGrid {
        intrinsics: PinholeIntrinsics {
            fx: intrinsics.fx,
            fy: intrinsics.fy,
            cx: intrinsics.cx,
            cy: intrinsics.cy,
        },
        crop: CropTransform {
            x0: window.x0,
            y0: window.y0,
            sx: scale,
            sy: scale,
        },
        depth: DepthBins {
            z_ref,
            z_min: near,
            bin_size: (far - near) / config.depth_bins as f64,
        },
    }
}

pub(crate) fn heatmap_dims(config: &NetworkConfig) -> HeatmapDims {
    let n = config.heatmap_size();
    HeatmapDims {
        depth: config.depth_bins,
        height: n,
        width: n,
    }
}

/// The crop's reference depth: the median depth of the pixels inside the window that `belongs`
/// to the box (its mask, ground truth or predicted), or of all valid pixels of the window when
/// none does. `None` when the window has no depth at all.
pub(crate) fn reference_depth(
    frame: &Frame,
    window: &CropWindow,
    belongs: impl Fn(usize) -> bool,
) -> Option<f64> {
    let (x_lo, x_hi) = (
        window.x0.floor().max(0.0) as usize,
        ((window.x0 + window.side).ceil() as usize).min(frame.width),
    );
    let (y_lo, y_hi) = (
        window.y0.floor().max(0.0) as usize,
        ((window.y0 + window.side).ceil() as usize).min(frame.height),
    );
    let mut own = Vec::new();
    let mut any = Vec::new();
    for y in y_lo..y_hi {
        for x in x_lo..x_hi {
            let i = y * frame.width + x;
            let z = frame.depth[i];
            if z > 0.0 {
                any.push(z);
                if belongs(i) {
                    own.push(z);
                }
            }
        }
    }
    let mut depths = if own.is_empty() { any } else { own };
    if depths.is_empty() {
        return None;
    }
    let middle = depths.len() / 2;
    Some(*depths.select_nth_unstable_by(middle, f32::total_cmp).1 as f64)
}

/// The network input `[4, S, S]` (R, G, B, depth) of a square window, S = `input_size`.
pub(crate) fn crop_input(
    config: &NetworkConfig,
    frame: &Frame,
    window: &CropWindow,
    z_ref: f64,
    turn: Option<&InPlaneTurn>,
    augment: Option<(&AugmentConfig, &mut ChaCha8Rng)>,
) -> Vec<f32> {
    let size = config.input_size;
    let step = window.side / size as f64;
    let stretch = config.depth_stretch(frame.intrinsics.fx, window.side, z_ref);
    resample_input(
        frame,
        [window.x0, window.y0],
        [step, step],
        [size, size],
        (z_ref, DEPTH_SCALE_M * stretch as f32),
        turn,
        augment,
    )
}

/// The pixel of an image of `len` pixels nearest to the centre of pixel `index` of a grid that
/// advances `image_pixels / grid_pixels` image pixels per grid pixel, both with pixel centres at
/// +0.5 (the convention of [`CropTransform`]), clamped to the image. The ratio is kept as two
/// numbers so that ties round the same whichever way a caller scales.
pub(crate) fn nearest_source(
    index: usize,
    image_pixels: f64,
    grid_pixels: f64,
    len: usize,
) -> usize {
    (((index as f64 + 0.5) * image_pixels / grid_pixels - 0.5)
        .round()
        .max(0.0) as usize)
        .min(len - 1)
}

/// With `sensor`, puts `frame`'s simulated sensor depth in place of its exact depth
/// ([`Frame::use_sensor_depth`], as `--sensor-depth` perceives it), or says that `dataset` has none.
pub fn perceived_depth(frame: &mut Frame, sensor: bool, dataset: &Path) -> Result<(), LearnError> {
    if sensor && !frame.use_sensor_depth() {
        return Err(LearnError::Data(format!(
            "{}: scene {} frame {} has no sensor depth (`sensor_depth_m_f32le`); --sensor-depth \
             needs a dataset rendered with `[render] sensor_depth = true` in its recipe",
            dataset.display(),
            frame.scene_id,
            frame.frame_id
        )));
    }
    Ok(())
}

/// The frame's depth image, as the fits read it to settle mirror ties.
pub fn depth_view(frame: &Frame) -> DepthView<'_> {
    let k = &frame.intrinsics;
    DepthView {
        width: frame.width,
        height: frame.height,
        intrinsics: [k.fx, k.fy, k.cx, k.cy],
        depth_m: &frame.depth,
    }
}

/// The network input `[4, height, width]` (R, G, B, depth) of the image region that starts at
/// pixel `origin` and advances `step` image pixels per input pixel: RGB resampled bilinearly,
/// depth by nearest neighbour (interpolating across a box's edge would invent surfaces), both
/// with the half-pixel-centre convention of [`CropTransform`]. Outside the image: grey, no depth.
/// Depth enters as (z − z_ref)/scale of `(z_ref, scale)`, clamped to ±DEPTH_CLAMP.
/// With a `turn`, the region is one of the turned camera's image, read from the frame through it.
pub(crate) fn resample_input(
    frame: &Frame,
    origin: [f64; 2],
    step: [f64; 2],
    [width, height]: [usize; 2],
    (z_ref, depth_scale_m): (f64, f32),
    turn: Option<&InPlaneTurn>,
    augment: Option<(&AugmentConfig, &mut ChaCha8Rng)>,
) -> Vec<f32> {
    let plane = width * height;
    let mut input = vec![0.0f32; 4 * plane];
    let (w, h) = (frame.width as isize, frame.height as isize);
    let rgb_at = |x: isize, y: isize, c: usize| -> f32 {
        if x < 0 || y < 0 || x >= w || y >= h {
            RGB_MEAN * 255.0
        } else {
            frame.rgb[(y as usize * frame.width + x as usize) * 3 + c] as f32
        }
    };
    for row in 0..height {
        for col in 0..width {
            let [x, y] = source_position(origin, step, [row, col], turn);
            let (y_floor, fy) = (y.floor(), (y - y.floor()) as f32);
            let (x_floor, fx) = (x.floor(), (x - x.floor()) as f32);
            let (xi, yi) = (x_floor as isize, y_floor as isize);
            for c in 0..3 {
                let top = rgb_at(xi, yi, c) * (1.0 - fx) + rgb_at(xi + 1, yi, c) * fx;
                let bottom = rgb_at(xi, yi + 1, c) * (1.0 - fx) + rgb_at(xi + 1, yi + 1, c) * fx;
                input[c * plane + row * width + col] = top * (1.0 - fy) + bottom * fy;
            }
            let (xn, yn) = (x.round() as isize, y.round() as isize);
            if xn >= 0 && yn >= 0 && xn < w && yn < h {
                input[3 * plane + row * width + col] =
                    frame.depth[yn as usize * frame.width + xn as usize];
            }
        }
    }
    if let Some((augment, rng)) = augment {
        augment_input(&mut input, plane, augment, rng);
    }
    for value in &mut input[..3 * plane] {
        *value = (*value / 255.0 - RGB_MEAN) / RGB_STD;
    }
    for z in &mut input[3 * plane..] {
        if *z > 0.0 {
            *z = ((*z - z_ref as f32) / depth_scale_m).clamp(-DEPTH_CLAMP, DEPTH_CLAMP);
        }
    }
    input
}

/// Where input pixel `[row, col]` of the region that starts at `origin` and advances `step` image
/// pixels per input pixel reads the frame: its centre in the frame's pixel-index (OpenCV)
/// coordinates, the intrinsics' and so the turn's, read through the turn when there is one.
fn source_position(
    origin: [f64; 2],
    step: [f64; 2],
    [row, col]: [usize; 2],
    turn: Option<&InPlaneTurn>,
) -> [f64; 2] {
    let u = origin[0] + (col as f64 + 0.5) * step[0];
    let v = origin[1] + (row as f64 + 0.5) * step[1];
    let [x, y] = [u - 0.5, v - 0.5];
    turn.map_or([x, y], |turn| turn.original_position([x, y]))
}

/// The box's own mask in a sample's crop, `[S, S]` at the network input's size S: 1 where the
/// frame pixel the input's depth channel reads (the nearest, through the sample's turn) shows the
/// box of mask value `label`, 0 elsewhere and outside the frame.
pub fn crop_mask(config: &NetworkConfig, frame: &Frame, sample: &Sample, label: u16) -> Vec<u8> {
    let size = config.input_size;
    let step = sample.window.side / size as f64;
    let origin = [sample.window.x0, sample.window.y0];
    let (w, h) = (frame.width as f64, frame.height as f64);
    let mut mask = vec![0u8; size * size];
    for row in 0..size {
        for col in 0..size {
            let [x, y] = source_position(origin, [step, step], [row, col], sample.turn.as_ref());
            let (xn, yn) = (x.round(), y.round());
            if xn >= 0.0 && yn >= 0.0 && xn < w && yn < h {
                let i = yn as usize * frame.width + xn as usize;
                mask[row * size + col] = u8::from(frame.instance_mask[i] == label);
            }
        }
    }
    mask
}

/// Colour jitter on RGB in [0, 255]; noise and dropout on raw depth in metres.
fn augment_input(input: &mut [f32], plane: usize, augment: &AugmentConfig, rng: &mut ChaCha8Rng) {
    let c = augment.color as f32;
    if c > 0.0 {
        let brightness = rng.random_range(-c..=c) * 255.0;
        let contrast = 1.0 + rng.random_range(-c..=c);
        for channel in 0..3 {
            let gain = 1.0 + rng.random_range(-c..=c) / 2.0;
            for v in &mut input[channel * plane..(channel + 1) * plane] {
                *v = (((*v - 127.5) * contrast + 127.5) * gain + brightness).clamp(0.0, 255.0);
            }
        }
    }
    let noise = Normal::new(0.0, augment.depth_noise_m.max(0.0) as f32)
        .expect("a non-negative standard deviation");
    for z in &mut input[3 * plane..] {
        if *z > 0.0 {
            if rng.random_bool(augment.depth_dropout.clamp(0.0, 1.0)) {
                *z = 0.0;
            } else {
                *z += noise.sample(rng);
            }
        }
    }
}

/// The training target: a Gaussian of `sigma_voxels` at each of the 8 ground-truth corners
/// (occluded ones too: the network is asked for the box, not its visible surface).
pub fn target_heatmap(
    config: &NetworkConfig,
    grid: &VoxelGrid,
    corners_camera: &[[f64; 3]; 8],
) -> Result<Vec<f32>, LearnError> {
    let centres = corners_camera
        .iter()
        .map(|c| grid.project(&Point3::from(*c)))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(heatmap::render_target_heatmap(
        heatmap_dims(config),
        &centres,
        config.sigma_voxels,
    )?)
}

/// One instance ready for the network, with what scoring it needs.
pub struct Sample {
    pub input: Vec<f32>,
    pub target: Vec<f32>,
    pub grid: VoxelGrid,
    /// The crop, in the pixel coordinates of the image it was read from (the turned camera's
    /// when there is a turn).
    pub window: CropWindow,
    /// The corners the target was drawn at: the box's true corners in the camera's frame (the
    /// turned camera's when there is a turn).
    pub corners_camera: [[f64; 3]; 8],
    /// The in-plane turn of the camera the crop was read through (training augmentation).
    pub(crate) turn: Option<InPlaneTurn>,
}

impl Sample {
    /// The angle the camera was turned by about its optical axis (radians, 0 without a turn).
    pub fn turn_rad(&self) -> f64 {
        self.turn.map_or(0.0, |t| t.sin.atan2(t.cos))
    }
}

/// The crop of a ground-truth instance: its visible bbox (jittered when augmenting) and the
/// median depth of its own mask. With `rotation_deg` augmentation, a view of the camera turned
/// about its optical axis ([`turned_instance_sample`]).
pub(crate) fn instance_sample(
    config: &NetworkConfig,
    frame: &Frame,
    instance: &Instance,
    augment: Option<(&AugmentConfig, &mut ChaCha8Rng)>,
) -> Result<Sample, LearnError> {
    let bbox = instance.visible_bbox.ok_or_else(|| {
        LearnError::Data(format!(
            "scene {} frame {} object {}: no visible pixel, nothing to crop",
            instance.scene_id, instance.frame_id, instance.object_id
        ))
    })?;
    let mut window = CropWindow::around(bbox, config.crop_margin);
    let label = instance.mask_label();
    match augment {
        Some((augment, rng)) if augment.rotation_deg > 0.0 => {
            let angle = rng
                .random_range(-augment.rotation_deg..=augment.rotation_deg)
                .to_radians();
            let turn = InPlaneTurn::new(&frame.intrinsics, angle);
            turned_instance_sample(config, frame, instance, bbox, &turn, (augment, rng))
        }
        Some((augment, rng)) => {
            window = window.jittered(augment, rng);
            let z_ref = gt_reference_depth(frame, &window, label)?;
            sample_at(
                config,
                frame,
                &window,
                z_ref,
                &instance.corners_camera,
                None,
                Some((augment, rng)),
            )
        }
        None => {
            let z_ref = gt_reference_depth(frame, &window, label)?;
            sample_at(
                config,
                frame,
                &window,
                z_ref,
                &instance.corners_camera,
                None,
                None,
            )
        }
    }
}

/// The training sample of an instance seen by the camera turned by `turn`: the window around the
/// turned mask's extent (jittered), the median depth of the mask pixels that land in it, the
/// image read through the turn and the target at the turned corners.
fn turned_instance_sample(
    config: &NetworkConfig,
    frame: &Frame,
    instance: &Instance,
    [x_min, y_min, x_max, y_max]: [i32; 4],
    turn: &InPlaneTurn,
    (augment, rng): (&AugmentConfig, &mut ChaCha8Rng),
) -> Result<Sample, LearnError> {
    let label = instance.mask_label();
    // The box's own pixels (their centres in the turned image, pixel-index coordinates) with
    // their depths.
    let mut own = Vec::new();
    for y in y_min.max(0) as usize..(y_max.max(0) as usize).min(frame.height) {
        for x in x_min.max(0) as usize..(x_max.max(0) as usize).min(frame.width) {
            let i = y * frame.width + x;
            if frame.instance_mask[i] == label {
                own.push((turn.turned_position([x as f64, y as f64]), frame.depth[i]));
            }
        }
    }
    if own.is_empty() {
        return Err(LearnError::Data(format!(
            "scene {} frame {} object {}: its visible bbox holds none of its mask pixels",
            instance.scene_id, instance.frame_id, instance.object_id
        )));
    }
    let extent = own.iter().fold(
        [f64::MAX, f64::MAX, f64::MIN, f64::MIN],
        |[x0, y0, x1, y1], &([u, v], _)| [x0.min(u), y0.min(v), x1.max(u), y1.max(v)],
    );
    // The window's coordinates are continuous (pixel i spans [i, i + 1]): a pixel centred at
    // index x covers [x, x + 1].
    let [x0, y0, x1, y1] = extent;
    let window = CropWindow::around_extent([x0, y0, x1 + 1.0, y1 + 1.0], config.crop_margin)
        .jittered(augment, rng);
    let inside = |[x, y]: [f64; 2]| {
        let [u, v] = [x + 0.5, y + 0.5];
        u >= window.x0
            && v >= window.y0
            && u < window.x0 + window.side
            && v < window.y0 + window.side
    };
    let mut depths: Vec<f32> = own
        .iter()
        .filter(|&&(uv, z)| z > 0.0 && inside(uv))
        .map(|&(_, z)| z)
        .collect();
    if depths.is_empty() {
        depths = own.iter().map(|&(_, z)| z).filter(|&z| z > 0.0).collect();
    }
    if depths.is_empty() {
        return Err(LearnError::Data(format!(
            "scene {} frame {}: crop has no depth",
            frame.scene_id, frame.frame_id
        )));
    }
    let middle = depths.len() / 2;
    let z_ref = *depths.select_nth_unstable_by(middle, f32::total_cmp).1 as f64;
    sample_at(
        config,
        frame,
        &window,
        z_ref,
        &instance.corners_camera,
        Some(turn),
        Some((augment, rng)),
    )
}

/// The sample of a box with true corners `corners_camera` in any crop (a predicted one, say),
/// of the image the camera sees turned by `turn` when there is one.
pub(crate) fn sample_at(
    config: &NetworkConfig,
    frame: &Frame,
    window: &CropWindow,
    z_ref: f64,
    corners_camera: &[[f64; 3]; 8],
    turn: Option<&InPlaneTurn>,
    augment: Option<(&AugmentConfig, &mut ChaCha8Rng)>,
) -> Result<Sample, LearnError> {
    let input = crop_input(config, frame, window, z_ref, turn, augment);
    let grid = voxel_grid(config, &frame.intrinsics, window, z_ref);
    let corners = turn.map_or(*corners_camera, |turn| {
        corners_camera.map(|c| turn.point(c))
    });
    let target = target_heatmap(config, &grid, &corners).map_err(|e| {
        LearnError::Data(format!(
            "scene {} frame {}: a box's target heatmap: {e}",
            frame.scene_id, frame.frame_id
        ))
    })?;
    Ok(Sample {
        input,
        target,
        grid,
        window: *window,
        corners_camera: corners,
        turn: turn.copied(),
    })
}

fn gt_reference_depth(frame: &Frame, window: &CropWindow, label: u16) -> Result<f64, LearnError> {
    reference_depth(frame, window, |i| frame.instance_mask[i] == label).ok_or_else(|| {
        LearnError::Data(format!(
            "scene {} frame {}: crop has no depth",
            frame.scene_id, frame.frame_id
        ))
    })
}

/// The frames of some datasets, and the instances to learn from, split by scene into training
/// and held-out validation. Images are read from the shards when first needed and kept in a
/// cache of `frame_cache_mib` ([`DataConfig`]).
pub struct InstanceSet {
    /// Every frame's key, instances and place in its shard (no image).
    pub frames: Vec<FrameEntry>,
    cache: FrameCache,
    /// (frame index, instance index) pairs.
    pub train: Vec<(usize, usize)>,
    pub val: Vec<(usize, usize)>,
    /// Frame indices of the training and held-out scenes.
    pub train_frames: Vec<usize>,
    pub val_frames: Vec<usize>,
    /// How each `[data]` dataset divides, in the config's order.
    pub splits: Vec<DatasetSplit>,
}

/// How one dataset of a training divides between training and held-out scenes (instances
/// counted as training uses them: visible enough, with a bounding box).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DatasetSplit {
    pub path: std::path::PathBuf,
    pub train_frames: usize,
    pub held_out_frames: usize,
    pub train_instances: usize,
    pub held_out_instances: usize,
    /// Copies of its training items per epoch ([`DataConfig::repeat`]).
    pub repeat: usize,
}

/// Whether a box is one the network learns and is judged on: at least `min_visible_fraction`
/// visible, with a visible bounding box, and wholly in front of the camera (a close camera over a
/// large box leaves corners behind it that no pixel shows and no voxel holds).
pub fn is_target(instance: &Instance, min_visible_fraction: f32) -> bool {
    instance.visible_fraction >= min_visible_fraction
        && instance.visible_bbox.is_some()
        && instance.corners_camera.iter().all(|c| c[2] > 0.0)
}

/// Whether a scene is held out from training: every `val_modulus`-th scene id, all its views.
pub fn is_held_out(scene_id: i64, val_modulus: i64) -> bool {
    scene_id.rem_euclid(val_modulus) == 0
}

impl InstanceSet {
    /// Every frame of the `[data]` datasets, split into training and held-out scenes.
    pub fn load(data: &DataConfig) -> Result<Self, LearnError> {
        let (val_modulus, min_visible_fraction) = (data.val_modulus, data.min_visible_fraction);
        let mut frames = Vec::new();
        let mut dataset_of_frame = Vec::new();
        let mut splits = Vec::with_capacity(data.datasets.len());
        for (d, path) in data.datasets.iter().enumerate() {
            let index = Dataset::open(path)?.frame_index()?;
            dataset_of_frame.extend(std::iter::repeat_n(d, index.len()));
            frames.extend(index);
            splits.push(DatasetSplit {
                path: path.clone(),
                repeat: data.repeat.get(d).copied().unwrap_or(1),
                ..DatasetSplit::default()
            });
        }
        let (mut train, mut val) = (Vec::new(), Vec::new());
        let (mut train_frames, mut val_frames) = (Vec::new(), Vec::new());
        for (f, frame) in frames.iter().enumerate() {
            let held_out = is_held_out(frame.scene_id, val_modulus);
            let split = &mut splits[dataset_of_frame[f]];
            let copies = split.repeat;
            if held_out {
                val_frames.push(f);
                split.held_out_frames += 1;
            } else {
                train_frames.extend(std::iter::repeat_n(f, copies));
                split.train_frames += 1;
            }
            for (i, instance) in frame.instances.iter().enumerate() {
                if !is_target(instance, min_visible_fraction) {
                    continue;
                }
                if held_out {
                    val.push((f, i));
                    split.held_out_instances += 1;
                } else {
                    train.extend(std::iter::repeat_n((f, i), copies));
                    split.train_instances += 1;
                }
            }
        }
        Ok(Self {
            frames,
            cache: FrameCache::new(data.frame_cache_mib.saturating_mul(1 << 20)),
            train,
            val,
            train_frames,
            val_frames,
            splits,
        })
    }

    /// Frame `f`, decoded (from the cache when it holds it).
    pub fn frame(&self, f: usize) -> Result<Arc<Frame>, LearnError> {
        self.cache.get_or_read(f, &self.frames[f])
    }

    pub fn instance(&self, (f, i): (usize, usize)) -> &Instance {
        &self.frames[f].instances[i]
    }
}

/// Decoded frames by index, the least recently used dropped once they exceed `budget_bytes`.
struct FrameCache {
    budget_bytes: usize,
    state: Mutex<CacheState>,
}

#[derive(Default)]
struct CacheState {
    /// Frame index → (frame, tick of its last use).
    frames: HashMap<usize, (Arc<Frame>, u64)>,
    bytes: usize,
    tick: u64,
}

impl FrameCache {
    fn new(budget_bytes: usize) -> Self {
        Self {
            budget_bytes,
            state: Mutex::default(),
        }
    }

    fn get_or_read(&self, index: usize, entry: &FrameEntry) -> Result<Arc<Frame>, LearnError> {
        {
            let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
            state.tick += 1;
            let tick = state.tick;
            if let Some((frame, last_use)) = state.frames.get_mut(&index) {
                *last_use = tick;
                return Ok(frame.clone());
            }
        }
        // Decoded outside the lock, so loader threads decode in parallel (two of them may
        // decode one frame at once; the second copy is dropped).
        let frame = Arc::new(entry.read()?);
        let size = decoded_bytes(&frame);
        if size > self.budget_bytes {
            return Ok(frame); // larger than the whole cache: used once, not kept
        }
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        while state.bytes + size > self.budget_bytes && !state.frames.is_empty() {
            let oldest = state
                .frames
                .iter()
                .min_by_key(|(_, (_, last_use))| *last_use)
                .map(|(&k, _)| k)
                .expect("a cached frame");
            if let Some((dropped, _)) = state.frames.remove(&oldest) {
                state.bytes -= decoded_bytes(&dropped);
            }
        }
        let tick = state.tick;
        if state.frames.insert(index, (frame.clone(), tick)).is_none() {
            state.bytes += size;
        }
        Ok(frame)
    }
}

/// Memory of a decoded frame's images.
fn decoded_bytes(frame: &Frame) -> usize {
    frame.rgb.len()
        + frame.depth.len() * 4
        + frame.instance_mask.len() * 2
        + frame.sensor_depth.as_ref().map_or(0, |d| d.len() * 4)
}

#[cfg(test)]
mod tests {
    use boxpose_data::{Pose, Visibility};
    use rand::SeedableRng;

    use super::*;
    use crate::config::Backbone;

    /// Where a crop's pixels satisfy `keep`, their centroid (crop pixels, centres at +0.5).
    fn centroid(plane: &[f32], side: usize, keep: impl Fn(f32) -> bool) -> [f64; 2] {
        let (mut sum, mut n) = ([0.0, 0.0], 0.0);
        for (i, &value) in plane.iter().enumerate() {
            if keep(value) {
                sum[0] += (i % side) as f64 + 0.5;
                sum[1] += (i / side) as f64 + 0.5;
                n += 1.0;
            }
        }
        assert!(n > 0.0, "no crop pixel is selected");
        [sum[0] / n, sum[1] / n]
    }

    /// A 96×80 frame, fx ≠ fy: one light grey box (mask label 1, depth 1 m) over a darker
    /// background at 1.5 m, a white 3×3 spot on it around pixel (52, 30), and every target corner
    /// at the spot.
    fn spot_frame() -> (Frame, [f64; 2]) {
        let (width, height) = (96usize, 80usize);
        let intrinsics = Intrinsics {
            fx: 80.0,
            fy: 100.0,
            cx: 48.0,
            cy: 40.0,
        };
        let (mut rgb, mut depth, mut mask) = (
            vec![100u8; width * height * 3],
            vec![1.5f32; width * height],
            vec![0u16; width * height],
        );
        for y in 25..50 {
            for x in 30..60 {
                depth[y * width + x] = 1.0;
                mask[y * width + x] = 1;
                rgb[(y * width + x) * 3..][..3].fill(160);
            }
        }
        for y in 29..32 {
            for x in 51..54 {
                rgb[(y * width + x) * 3..][..3].fill(255);
            }
        }
        let spot = [52.0, 30.0]; // pixel-index coordinates
        let corner = [
            (spot[0] - intrinsics.cx) / intrinsics.fx,
            (spot[1] - intrinsics.cy) / intrinsics.fy,
            1.0,
        ];
        let instance = Instance {
            scene_id: 0,
            frame_id: 0,
            object_id: 0,
            size: [0.1; 3],
            camera_box: Pose {
                quat_wxyz: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0, 0.0, 1.0],
            },
            corners_camera: [corner; 8],
            corners_px: [spot; 8],
            visibility: [Visibility::Visible; 8],
            label_keypoints_camera: None,
            label_keypoints_px: None,
            visible_bbox: Some([30, 25, 60, 50]),
            visible_pixels: 30 * 25,
            visible_fraction: 1.0,
        };
        let frame = Frame {
            scene_id: 0,
            frame_id: 0,
            width,
            height,
            intrinsics,
            world_camera: Pose {
                quat_wxyz: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0; 3],
            },
            samples: 1,
            denoise: false,
            render_seed: 0,
            blender_version: String::new(),
            rgb,
            depth,
            instance_mask: mask,
            sensor_depth: None,
            instances: vec![instance],
        };
        (frame, spot)
    }

    /// A tiny network's 64² crops, and an augmentation that only turns the camera.
    fn turning_config() -> (NetworkConfig, AugmentConfig) {
        let config = NetworkConfig {
            backbone: Backbone::Tiny,
            input_size: 64,
            depth_bins: 8,
            depth_range_m: [-0.12, 0.24],
            sigma_voxels: 1.0,
            crop_margin: 1.25,
            depth_scale_crop_m: None,
            peak_refine_radius: 1,
        };
        let augment = AugmentConfig {
            shift: 0.0,
            scale: 0.0,
            color: 0.0,
            depth_noise_m: 0.0,
            depth_dropout: 0.0,
            rotation_deg: 180.0,
            sensor_depth: 0.0,
        };
        (config, augment)
    }

    #[test]
    fn a_turned_crop_and_its_target_show_the_same_corner_where_the_turn_puts_it() {
        let (config, augment) = turning_config();
        let (frame, spot) = spot_frame();
        let instance = &frame.instances[0];
        let plane = 64 * 64;
        let [fx, fy] = [frame.intrinsics.fx, frame.intrinsics.fy];
        // The spot seen from the box's centre, in normalized camera coordinates.
        let original = [(spot[0] - 44.5) / fx, (spot[1] - 37.0) / fy];
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        for angle_deg in [0.0f64, 30.0, 90.0, -135.0, 180.0] {
            let turn = InPlaneTurn::new(&frame.intrinsics, angle_deg.to_radians());
            let sample = turned_instance_sample(
                &config,
                &frame,
                instance,
                instance.visible_bbox.unwrap(),
                &turn,
                (&augment, &mut rng),
            )
            .unwrap();
            // Normalized white (255) is 2; grey 100 is below 0.
            let white = centroid(&sample.input[..plane], 64, |r| r > 1.5);
            // The box (grey 160, normalized 0.51; the background −0.43, outside the image 0).
            let boxed = centroid(&sample.input[..plane], 64, |r| r > 0.25);
            // Where the turn puts the spot, in crop pixels.
            let step = sample.grid.crop.sx / 4.0;
            let turned = turn.turned_position(spot);
            let expected = [
                (turned[0] + 0.5 - sample.grid.crop.x0) / step,
                (turned[1] + 0.5 - sample.grid.crop.y0) / step,
            ];
            // The target's centre: its mean over the 16² heatmap (4 crop pixels per cell), every
            // depth bin summed.
            let (mut sum, mut mass) = ([0.0, 0.0], 0.0);
            for (i, &t) in sample.target.iter().enumerate() {
                let cell = i % (16 * 16);
                sum[0] += t as f64 * ((cell % 16) as f64 + 0.5) * 4.0;
                sum[1] += t as f64 * ((cell / 16) as f64 + 0.5) * 4.0;
                mass += t as f64;
            }
            let target = [sum[0] / mass, sum[1] / mass];
            for (what, at, tolerance) in [("white spot", white, 1.0), ("target", target, 0.5)] {
                let gap = ((at[0] - expected[0]).powi(2) + (at[1] - expected[1]).powi(2)).sqrt();
                assert!(
                    gap < tolerance,
                    "{angle_deg}°: the {what} is at {at:?} in the crop, the turn puts the spot \
                     at {expected:?} (crop pixels)"
                );
            }
            // And the spot has turned about the box by the angle (normalized coordinates).
            let seen = [
                (white[0] - boxed[0]) * step / fx,
                (white[1] - boxed[1]) * step / fy,
            ];
            let turned_by = (seen[1].atan2(seen[0]) - original[1].atan2(original[0])).to_degrees();
            let error = (turned_by - angle_deg + 540.0).rem_euclid(360.0) - 180.0;
            assert!(
                error.abs() < 2.0,
                "{angle_deg}°: the spot turned by {turned_by:.1}° about the box's centre"
            );
        }
    }

    #[test]
    fn a_crop_mask_covers_the_pixels_whose_depth_the_crop_reads_from_the_box() {
        let (config, augment) = turning_config();
        let (frame, _) = spot_frame();
        let instance = &frame.instances[0];
        let plane = 64 * 64;
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let unturned = instance_sample(&config, &frame, instance, None).unwrap();
        let mut samples = vec![unturned];
        for angle_deg in [90.0f64, -30.0, 180.0] {
            let turn = InPlaneTurn::new(&frame.intrinsics, angle_deg.to_radians());
            let bbox = instance.visible_bbox.unwrap();
            let turned = (&augment, &mut rng);
            samples.push(
                turned_instance_sample(&config, &frame, instance, bbox, &turn, turned).unwrap(),
            );
        }
        for sample in &samples {
            let mask = crop_mask(&config, &frame, sample, instance.mask_label());
            // The box lies at its crop's reference depth (1 m, the median of its own pixels):
            // its pixels read depth 0 exactly; the background (1.5 m) reads +3 (clamped), and
            // every window here lies inside the frame.
            let on_box: Vec<u8> = sample.input[3 * plane..]
                .iter()
                .map(|&z| u8::from(z == 0.0))
                .collect();
            let count = mask.iter().filter(|&&m| m == 1).count();
            assert!(
                count > 100,
                "{count} mask pixels at {}°",
                sample.turn_rad().to_degrees()
            );
            assert_eq!(mask, on_box, "at {}°", sample.turn_rad().to_degrees());
        }
        assert!((samples[2].turn_rad().to_degrees() + 30.0).abs() < 1e-9);
    }
}
