//! From a frame and a box's crop to its pose (paper steps 4–6): the network's heatmap, NMS
//! peaks, back-projection, and the pose fits with their mirror check ([`perceive`]). A trained model is a folder holding
//! `network.toml` (what the network sees) and `model.bpk` (burn's burnpack weights).

use std::path::Path;

use boxpose_data::{Frame, Instance};
use boxpose_geometry::depth::DepthView;
use boxpose_geometry::heatmap::{self, NmsParams, Peak, VoxelGrid};
use boxpose_geometry::pipeline::{FitRun, Method};
use boxpose_geometry::{BoxModel, GeometryError};
use burn::prelude::*;
use nalgebra::Point3;

use crate::LearnError;
use crate::config::NetworkConfig;
use crate::data::{self, CropWindow};
use crate::model::KeypointNet;
use crate::model_dir::{check_model_dir, load_model_dir, save_model_dir};

pub(crate) const NETWORK_FILE: &str = "network.toml";
/// Peaks taken from each heatmap: one per box corner, as the paper.
pub(crate) const PEAK_COUNT: usize = 8;

/// A trained keypoint network, ready for inference on one device.
pub struct KeypointModel {
    pub config: NetworkConfig,
    pub net: KeypointNet,
    pub device: Device,
}

impl KeypointModel {
    /// Loads `dir/network.toml` and `dir/model.bpk`.
    pub fn load(dir: &Path, device: Device) -> Result<Self, LearnError> {
        let (config, net) = load_model_dir(
            dir,
            NETWORK_FILE,
            NetworkConfig::validate,
            |c: &NetworkConfig| KeypointNet::keypoints(c, &device),
        )?;
        Ok(Self {
            config,
            net,
            device,
        })
    }

    /// Checks that `dir` holds a keypoint network [`load`](Self::load) would read (a valid
    /// network.toml and the weights file), without loading its weights.
    pub fn check_folder(dir: &Path) -> Result<(), LearnError> {
        check_model_dir(dir, NETWORK_FILE, NetworkConfig::validate).map(|_| ())
    }

    /// Writes the model folder (network.toml, model.bpk) atomically: into `dir.tmp`, then renamed.
    pub fn save(config: &NetworkConfig, net: &KeypointNet, dir: &Path) -> Result<(), LearnError> {
        save_model_dir(dir, NETWORK_FILE, config, net)
    }

    /// Heatmaps `[D·H·W]` of prepared inputs `[4·S·S]` each, in batches of `batch_size`.
    pub fn heatmaps(
        &self,
        inputs: &[Vec<f32>],
        batch_size: usize,
    ) -> Result<Vec<Vec<f32>>, LearnError> {
        let s = self.config.input_size;
        let mut out = Vec::with_capacity(inputs.len());
        for chunk in inputs.chunks(batch_size.max(1)) {
            let flat: Vec<f32> = chunk.iter().flatten().copied().collect();
            let input =
                Tensor::<4>::from_data(TensorData::new(flat, [chunk.len(), 4, s, s]), &self.device);
            let output = self.net.forward(input);
            let [_, d, h, w] = output.dims();
            let values: Vec<f32> = output
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| LearnError::Backend(format!("{e:?}")))?;
            out.extend(values.chunks(d * h * w).map(<[f32]>::to_vec));
        }
        if let Some(bad) = out.iter().flatten().find(|v| !v.is_finite()) {
            return Err(LearnError::Backend(format!(
                "the network output a non-finite value ({bad}): corrupt weights?"
            )));
        }
        Ok(out)
    }
}

/// A box's crop at inference: the window and its reference depth.
#[derive(Debug, Clone, Copy)]
pub struct CropRequest {
    pub window: CropWindow,
    pub z_ref: f64,
}

impl CropRequest {
    /// The crop around a bounding box, at the median depth of the pixels `belongs` marks as the
    /// box's (its mask); `None` when the window has no depth.
    pub fn around(
        frame: &Frame,
        config: &NetworkConfig,
        bbox: [i32; 4],
        belongs: impl Fn(usize) -> bool,
    ) -> Option<Self> {
        let window = CropWindow::around(bbox, config.crop_margin);
        data::reference_depth(frame, &window, belongs).map(|z_ref| Self { window, z_ref })
    }

    /// The ground-truth crop of an instance, as the network was trained on it: around its visible
    /// bounding box, at the median depth of its own mask; `None` when it has no visible pixel or
    /// its window no depth.
    pub fn of_instance(frame: &Frame, config: &NetworkConfig, instance: &Instance) -> Option<Self> {
        let label = instance.mask_label();
        Self::around(frame, config, instance.visible_bbox?, |i| {
            frame.instance_mask[i] == label
        })
    }
}

/// One box to perceive: its crop, and its true size when known (every fit but the two
/// size-and-pose fits needs it: [`boxpose_geometry::pipeline::fit_method`]).
#[derive(Debug, Clone, Copy)]
pub struct BoxQuery {
    pub crop: CropRequest,
    pub known_box: Option<BoxModel>,
}

/// What the pipeline recovers for one box's crop.
#[derive(Debug, Clone)]
pub struct Perception {
    /// The network's heatmap `[D·H·W]` and the voxel grid of the crop it lives on.
    pub heatmap: Vec<f32>,
    pub grid: VoxelGrid,
    /// NMS peaks (best first) and their back-projections, camera frame, metres.
    pub peaks: Vec<Peak>,
    pub points: Vec<Point3<f64>>,
    /// Each fit asked for, in the order asked, with its mirror tie settled when a depth image
    /// was given.
    pub fits: Vec<FitRun>,
}

/// NMS on one heatmap, and the peaks back-projected through the crop's voxel grid. A heatmap
/// with no positive voxel has no peak: the fits that follow fail for that box alone.
pub fn decode(
    config: &NetworkConfig,
    heatmap: &[f32],
    grid: &VoxelGrid,
) -> Result<(Vec<Peak>, Vec<Point3<f64>>), LearnError> {
    let params = NmsParams {
        count: PEAK_COUNT,
        sigma: config.sigma_voxels,
        refine_radius: config.peak_refine_radius,
    };
    let peaks = match heatmap::non_maximum_suppression(heatmap, data::heatmap_dims(config), &params)
    {
        Err(GeometryError::EmptyHeatmap) => Vec::new(),
        peaks => peaks?,
    };
    let points = peaks
        .iter()
        .map(|p| grid.back_project(&p.coord))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((peaks, points))
}

/// Paper steps 5–6 on one box's heatmap: its NMS peaks, back-projected through the crop's `grid`,
/// and each fit of `methods` on them ([`FitRun`]: with the frame's `depth` image, mirror ties are
/// settled with it). Training validation calls this directly, without depth (it keeps no frames);
/// everything else goes through [`perceive`].
pub fn perceive_heatmap(
    config: &NetworkConfig,
    heatmap: Vec<f32>,
    grid: VoxelGrid,
    known_box: Option<&BoxModel>,
    methods: &[Method],
    depth: Option<&DepthView>,
) -> Result<Perception, LearnError> {
    let (peaks, points) = decode(config, &heatmap, &grid)?;
    let scores: Vec<f64> = peaks.iter().map(|p| p.score as f64).collect();
    let fits = methods
        .iter()
        .map(|&method| FitRun::new(method, known_box, &points, &scores, depth))
        .collect();
    Ok(Perception {
        heatmap,
        grid,
        peaks,
        points,
        fits,
    })
}

/// The whole pipeline (paper steps 4–6) on boxes of one frame: each crop through the network
/// (`batch_size` crops per forward pass), its heatmap's peaks, and each fit of `methods`, mirror
/// ties settled with the frame's depth image. `boxpose predict`, `boxpose eval` and the
/// counterexample search all perceive through this one function, so they report the same pose
/// for the same crop.
pub fn perceive(
    model: &KeypointModel,
    frame: &Frame,
    boxes: &[BoxQuery],
    methods: &[Method],
    batch_size: usize,
) -> Result<Vec<Perception>, LearnError> {
    let inputs: Vec<Vec<f32>> = boxes
        .iter()
        .map(|b| {
            data::crop_input(
                &model.config,
                frame,
                &b.crop.window,
                b.crop.z_ref,
                None,
                None,
            )
        })
        .collect();
    let heatmaps = model.heatmaps(&inputs, batch_size)?;
    let depth = data::depth_view(frame);
    boxes
        .iter()
        .zip(heatmaps)
        .map(|(b, heatmap)| {
            let grid = data::voxel_grid(
                &model.config,
                &frame.intrinsics,
                &b.crop.window,
                b.crop.z_ref,
            );
            perceive_heatmap(
                &model.config,
                heatmap,
                grid,
                b.known_box.as_ref(),
                methods,
                Some(&depth),
            )
        })
        .collect()
}
