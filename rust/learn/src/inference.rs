//! From a frame and a box's crop to its pose (paper steps 4–6): the network's heatmap, NMS
//! peaks, back-projection, and a pose-and-size fit. A trained model is a folder holding
//! `network.toml` (what the network sees) and `model.bpk` (burn's burnpack weights).

use std::path::Path;

use boxpose_data::Frame;
use boxpose_geometry::heatmap::{self, NmsParams, Peak, VoxelGrid};
use boxpose_geometry::size_fit::{self, SizedBoxFit};
use boxpose_geometry::{GeometryError, pipeline};
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
}

/// What the pipeline recovers for one box.
#[derive(Debug, Clone)]
pub struct BoxPrediction {
    /// NMS peaks (best first) and their back-projections, camera frame, metres.
    pub peaks: Vec<Peak>,
    pub points: Vec<Point3<f64>>,
    /// The pose-and-size fit (pose, size, inliers, residuals), or why it failed.
    pub fit: Result<SizedBoxFit, String>,
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

/// Mirror ties of the size fit settled with the frame's depth image, as every fit does in
/// evaluation ([`pipeline::Fitted::resolve_mirror`]).
fn settle_mirror_tie(
    mut fit: size_fit::RobustSizedFit,
    points: &[Point3<f64>],
    frame: &Frame,
) -> size_fit::RobustSizedFit {
    let mut fitted = pipeline::Fitted::from_robust_size(&fit);
    fitted.resolve_mirror(points, &data::depth_view(frame));
    fit.pose = fitted.pose;
    fit.confidence = fitted.own_confidence.unwrap_or(fit.confidence);
    fit
}

/// Runs the whole pipeline on crops of one frame.
pub fn predict(
    model: &KeypointModel,
    frame: &Frame,
    crops: &[CropRequest],
    batch_size: usize,
) -> Result<Vec<BoxPrediction>, LearnError> {
    let inputs: Vec<Vec<f32>> = crops
        .iter()
        .map(|c| {
            data::crop_input(
                frame,
                &c.window,
                c.z_ref,
                model.config.input_size,
                None,
                None,
            )
        })
        .collect();
    let heatmaps = model.heatmaps(&inputs, batch_size)?;
    crops
        .iter()
        .zip(&heatmaps)
        .map(|(crop, heatmap)| {
            let grid = data::voxel_grid(&model.config, &frame.intrinsics, &crop.window, crop.z_ref);
            let (peaks, points) = decode(&model.config, heatmap, &grid)?;
            // The noise-adaptive pose-and-size fit (survives outlier peaks); `SizedBoxFit::cost` is
            // its plain sum of squared residuals, as `fit_pose_and_size`'s default would give.
            let fit = size_fit::robust_size_fit(&points, &size_fit::RobustSizeParams::default())
                .map(|f| settle_mirror_tie(f, &points, frame))
                .map(|f| {
                    let inlier_squares: Vec<f64> = f
                        .residuals
                        .iter()
                        .zip(&f.inliers)
                        .filter(|(_, i)| **i)
                        .map(|(r, _)| r * r)
                        .collect();
                    SizedBoxFit {
                        inlier_rms: (inlier_squares.iter().sum::<f64>()
                            / inlier_squares.len().max(1) as f64)
                            .sqrt(),
                        cost: f.residuals.iter().map(|r| r * r).sum(),
                        model: f.model,
                        pose: f.pose,
                        nearest_corners: f.nearest_corners,
                        residuals: f.residuals,
                        inliers: f.inliers,
                    }
                })
                .map_err(|e| e.to_string());
            Ok(BoxPrediction { peaks, points, fit })
        })
        .collect()
}
