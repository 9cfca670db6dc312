//! Network and training settings: one TOML file (see `models/*/config.toml` and
//! `configs/*.toml`), every field overridable from the command line.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::LearnError;

/// Reads a training config file and checks it with `validate`; errors name the file.
pub(crate) fn read_config<C: DeserializeOwned>(
    path: &Path,
    validate: impl FnOnce(&C) -> Result<(), LearnError>,
) -> Result<C, LearnError> {
    let text = std::fs::read_to_string(path).map_err(|e| LearnError::Io(path.to_path_buf(), e))?;
    let config: C = toml::from_str(&text)
        .map_err(|e| LearnError::Config(format!("{}: {e}", path.display())))?;
    validate(&config).map_err(|e| LearnError::Config(format!("{}: {e}", path.display())))?;
    Ok(config)
}

/// Backbone layouts. `resnet18`/`resnet34` are the paper's family (ResNet-34 in the paper);
/// `slim` halves every width of ResNet-18 for CPU training, `tiny` is for tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backbone {
    Resnet18,
    Resnet34,
    Slim,
    Tiny,
}

/// Channel widths and BasicBlock counts of the four ResNet stages, and the head's width.
pub struct Layout {
    pub widths: [usize; 4],
    pub blocks: [usize; 4],
    pub head_channels: usize,
}

impl Backbone {
    pub fn layout(self) -> Layout {
        match self {
            Backbone::Resnet18 => Layout {
                widths: [64, 128, 256, 512],
                blocks: [2, 2, 2, 2],
                head_channels: 256,
            },
            Backbone::Resnet34 => Layout {
                widths: [64, 128, 256, 512],
                blocks: [3, 4, 6, 3],
                head_channels: 256,
            },
            Backbone::Slim => Layout {
                widths: [32, 64, 128, 256],
                blocks: [2, 2, 2, 2],
                head_channels: 128,
            },
            Backbone::Tiny => Layout {
                widths: [8, 8, 16, 16],
                blocks: [1, 1, 1, 1],
                head_channels: 8,
            },
        }
    }
}

/// What the network sees and outputs; stored beside every checkpoint so inference rebuilds the
/// same crop and voxel grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkConfig {
    pub backbone: Backbone,
    /// Side of the square network input in pixels (128 on CPU, 256 as in the paper); a multiple
    /// of 32. The heatmap is input_size / 4 on a side.
    pub input_size: usize,
    /// Depth bins D of the heatmap.
    pub depth_bins: usize,
    /// Depth range of the heatmap relative to the crop's reference depth (the median depth of the
    /// box's visible pixels), metres: [near, far]. With `depth_scale_crop_m`, the range of a crop
    /// that wide; other crops scale it.
    pub depth_range_m: [f64; 2],
    /// When set, the crop's depth axis scales with the crop as its image axes do: a crop whose
    /// window is w metres wide at its reference depth (side · z_ref / fx) gets the heatmap range
    /// `depth_range_m` · w / `depth_scale_crop_m`, and its depth input is scaled alike. The
    /// network then sees a 50 cm box at 1.2 m as it sees a 10 cm box at 0.24 m, and no box is too
    /// deep for the heatmap (a fixed range of 36 cm cannot hold the corners of a 50 cm box).
    /// Absent (models trained before it): a fixed range in metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_scale_crop_m: Option<f64>,
    /// Standard deviation of the target Gaussians and of the NMS kernel, in voxels.
    pub sigma_voxels: f64,
    /// The square crop's side is the box's visible bounding box's longer side times this.
    pub crop_margin: f64,
    /// Half-width, in voxels, of the window of the heatmap averaged around each NMS peak for its
    /// sub-voxel position (0: the voxel centre). Inference only; `boxpose eval
    /// --peak-refine-radius` overrides it. A file without it reads as 2, the held-out ablation's
    /// choice (docs/learning.md), which models trained before the field existed decode with too.
    #[serde(default = "default_peak_refine_radius")]
    pub peak_refine_radius: usize,
}

fn default_peak_refine_radius() -> usize {
    2
}

impl NetworkConfig {
    /// Whether weights trained with `trained` can start a run that trains `self`: everything
    /// that shapes the weights or gives the heatmap's voxels their place (backbone, input size,
    /// depth bins and range, crop margin) must agree. The target Gaussians' width
    /// (`sigma_voxels`, a loss setting) and the decoding window (`peak_refine_radius`) may
    /// differ: the weights fit any of them, and the run's own network.toml records its choice.
    /// A run may also scale the depth axis with the crop (`depth_scale_crop_m`) where the trained
    /// weights had a fixed range: for crops of that width the voxels are the same, and the run
    /// learns the rest.
    pub fn can_fine_tune_from(&self, trained: &NetworkConfig) -> bool {
        let depth_scale_crop_m = match trained.depth_scale_crop_m {
            None => self.depth_scale_crop_m,
            scaled => scaled,
        };
        let trained = NetworkConfig {
            sigma_voxels: self.sigma_voxels,
            peak_refine_radius: self.peak_refine_radius,
            depth_scale_crop_m,
            ..trained.clone()
        };
        *self == trained
    }

    pub fn heatmap_size(&self) -> usize {
        self.input_size / 4
    }

    /// How much a crop's depth axis (heatmap range and depth input) is stretched against
    /// `depth_range_m`: 1 for a fixed metric range, else the window's width in metres at the
    /// reference depth over `depth_scale_crop_m`.
    pub fn depth_stretch(&self, fx: f64, window_side_px: f64, z_ref: f64) -> f64 {
        match self.depth_scale_crop_m {
            None => 1.0,
            Some(reference_m) => window_side_px * z_ref / fx / reference_m,
        }
    }

    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |reason: String| Err(LearnError::Config(reason));
        if self.input_size == 0 || !self.input_size.is_multiple_of(32) {
            return bad(format!(
                "input_size {} must be a positive multiple of 32",
                self.input_size
            ));
        }
        if self.depth_bins < 2 {
            return bad(format!("depth_bins {} must be at least 2", self.depth_bins));
        }
        let [near, far] = self.depth_range_m;
        if !(near.is_finite() && far.is_finite() && near < far) {
            return bad(format!(
                "depth_range_m {:?} must be finite with near < far",
                self.depth_range_m
            ));
        }
        if let Some(w) = self.depth_scale_crop_m
            && !(w.is_finite() && w > 0.0)
        {
            return bad(format!(
                "depth_scale_crop_m {w} must be a positive width in metres"
            ));
        }
        if !(self.sigma_voxels > 0.0) || !(self.crop_margin >= 1.0) {
            return bad(format!(
                "sigma_voxels {} must be > 0 and crop_margin {} ≥ 1",
                self.sigma_voxels, self.crop_margin
            ));
        }
        Ok(())
    }
}

/// Training-time augmentation of the crops (never applied in validation or inference).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AugmentConfig {
    /// Crop centre moves by up to this fraction of the crop's side.
    pub shift: f64,
    /// Crop side is scaled by a factor in [1 − scale, 1 + scale].
    pub scale: f64,
    /// Brightness, contrast and per-channel gain vary by up to this fraction.
    pub color: f64,
    /// Standard deviation of Gaussian noise added to valid depth, metres.
    pub depth_noise_m: f64,
    /// Fraction of depth pixels set to "no measurement" (0), as a real sensor drops them.
    pub depth_dropout: f64,
    /// In-plane rotation: the camera turns about its optical axis by an angle drawn uniformly in
    /// ± this many degrees, the image and the corner targets together (an exact new view, not an
    /// approximation: a turn about the optical axis changes neither depth nor visibility). 0, the
    /// default, draws nothing and leaves the crops as they were.
    #[serde(default)]
    pub rotation_deg: f64,
    /// The probability that a training crop reads its frame's simulated sensor depth
    /// (`sensor_depth_m_f32le`: projector shadows, no return at edges and grazing angles,
    /// disparity noise) instead of the exact render depth, as `--sensor-depth` perceives it; a
    /// frame rendered without the sensor channel always reads the exact depth. 0, the default,
    /// draws nothing.
    #[serde(default)]
    pub sensor_depth: f64,
}

impl AugmentConfig {
    pub fn validate(&self) -> Result<(), LearnError> {
        let fields = [
            ("shift", self.shift),
            ("scale", self.scale),
            ("color", self.color),
            ("depth_noise_m", self.depth_noise_m),
            ("depth_dropout", self.depth_dropout),
            ("rotation_deg", self.rotation_deg),
            ("sensor_depth", self.sensor_depth),
        ];
        if let Some((name, value)) = fields.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            return Err(LearnError::Config(format!(
                "[augment] {name} = {value} must be a number ≥ 0"
            )));
        }
        if self.scale >= 1.0 || self.color >= 1.0 || self.depth_dropout > 1.0 {
            return Err(LearnError::Config(format!(
                "[augment] scale {} and color {} must be below 1, depth_dropout {} at most 1",
                self.scale, self.color, self.depth_dropout
            )));
        }
        if self.sensor_depth > 1.0 {
            return Err(LearnError::Config(format!(
                "[augment] sensor_depth = {} is a probability: at most 1",
                self.sensor_depth
            )));
        }
        if self.rotation_deg > 180.0 {
            return Err(LearnError::Config(format!(
                "[augment] rotation_deg = {} must be at most 180 (± a half turn covers every angle)",
                self.rotation_deg
            )));
        }
        // The loader draws the noise in f32: beyond f32's range it is infinite and the normal
        // distribution cannot be built (the loader panicked); a metre is already absurd.
        if self.depth_noise_m > 1.0 {
            return Err(LearnError::Config(format!(
                "[augment] depth_noise_m = {} m must be at most 1 m",
                self.depth_noise_m
            )));
        }
        Ok(())
    }
}

/// Everything `boxpose train` needs; a TOML file with these sections.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    pub network: NetworkConfig,
    pub augment: AugmentConfig,
    pub optimizer: OptimizerConfig,
    pub data: DataConfig,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    pub batch_size: usize,
    /// Total optimizer steps of the run.
    pub steps: usize,
    /// Adam learning rate; decays by cosine to `learning_rate · final_lr_fraction`.
    pub learning_rate: f64,
    pub final_lr_fraction: f64,
    pub weight_decay: f64,
    /// Heatmap loss weight on voxels near a corner: each squared error is weighted by
    /// 1 + positive_weight·target. 0 is the paper's plain MSE, which on a sparse 3D target first
    /// learns to predict zero everywhere; the segmenter ignores it.
    #[serde(default)]
    pub positive_weight: f64,
    /// Validate and checkpoint every this many steps (and at the end).
    pub validate_every: usize,
    pub seed: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Dataset folders to train on (relative paths are taken from the working directory).
    pub datasets: Vec<PathBuf>,
    /// Scenes with `scene_id % val_modulus == 0` are held out for validation.
    pub val_modulus: i64,
    /// Instances less visible than this are not trained or evaluated on (a detector would not
    /// find them either).
    pub min_visible_fraction: f32,
    /// At most this many validation instances are scored per validation (0: all).
    pub max_val_instances: usize,
    /// Worker threads preparing batches (crop, augment, target) ahead of the optimizer.
    pub loader_threads: usize,
    /// Memory for decoded frames, in MiB. Frames are read from their shards when first needed
    /// and kept up to this much (least recently used dropped first): a dataset that fits is
    /// decoded once; a larger one is read again as needed instead of exhausting memory.
    #[serde(default = "default_frame_cache_mib")]
    pub frame_cache_mib: usize,
    /// Copies of each dataset's training scenes per epoch, in `datasets` order (empty: one
    /// each): a small set's weight in the mix, e.g. the bins of `train` beside the floors of a
    /// set twenty times its size. Held-out scenes are never repeated.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub repeat: Vec<usize>,
}

/// 4 GiB: about 1500 decoded 640×480 frames (2.8 MB each without sensor depth).
fn default_frame_cache_mib() -> usize {
    4096
}

impl TrainConfig {
    pub fn load(path: &Path) -> Result<Self, LearnError> {
        read_config(path, Self::validate)
    }

    pub fn validate(&self) -> Result<(), LearnError> {
        self.network.validate()?;
        self.augment.validate()?;
        self.optimizer.validate()?;
        self.data.validate()
    }
}

impl DataConfig {
    pub fn validate(&self) -> Result<(), LearnError> {
        if self.val_modulus < 2 {
            return Err(LearnError::Config(format!(
                "val_modulus {} must be at least 2",
                self.val_modulus
            )));
        }
        if self.datasets.is_empty() {
            return Err(LearnError::Config(
                "[data] datasets is empty: name at least one dataset folder".into(),
            ));
        }
        if !self.repeat.is_empty() && self.repeat.len() != self.datasets.len() {
            return Err(LearnError::Config(format!(
                "[data] repeat has {} entries for {} datasets: give one per dataset, in order \
                 (--repeat with --dataset)",
                self.repeat.len(),
                self.datasets.len()
            )));
        }
        if self.repeat.contains(&0) {
            return Err(LearnError::Config(
                "[data] repeat: every dataset is repeated at least once (leave a dataset out \
                 instead of repeating it 0 times)"
                    .into(),
            ));
        }
        // A run records its configuration as TOML, which holds only UTF-8 text.
        if let Some(path) = self.datasets.iter().find(|p| p.to_str().is_none()) {
            return Err(LearnError::Config(format!(
                "[data] datasets: {} is not valid UTF-8, so a run's config.toml cannot record it; \
                 rename the folder or reach it through a symlink with a UTF-8 name",
                path.display()
            )));
        }
        Ok(())
    }
}

impl OptimizerConfig {
    pub fn validate(&self) -> Result<(), LearnError> {
        if self.batch_size == 0 || self.steps == 0 || self.validate_every == 0 {
            return Err(LearnError::Config(
                "batch_size, steps and validate_every must be positive".into(),
            ));
        }
        if !(self.learning_rate > 0.0) || !(0.0..=1.0).contains(&self.final_lr_fraction) {
            return Err(LearnError::Config(format!(
                "learning_rate {} must be > 0 and final_lr_fraction {} in [0, 1]",
                self.learning_rate, self.final_lr_fraction
            )));
        }
        if !(self.positive_weight >= 0.0) {
            return Err(LearnError::Config(format!(
                "positive_weight {} must be ≥ 0",
                self.positive_weight
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shipped_keypoint_config_loads() {
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut loaded = Vec::new();
        for entry in std::fs::read_dir(&configs).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            // the segmenters' configs are segmentation.rs's to load (its tests)
            if name.ends_with(".toml") && !name.starts_with("segmenter") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                loaded.push(name);
            }
        }
        assert!(
            loaded.contains(&"keypoint-wide.toml".to_string()),
            "{loaded:?}"
        );
    }

    #[test]
    fn augmentation_that_would_crash_the_loader_is_refused_up_front() {
        let fine = AugmentConfig {
            shift: 0.1,
            scale: 0.15,
            color: 0.2,
            depth_noise_m: 0.002,
            depth_dropout: 0.02,
            rotation_deg: 180.0,
            sensor_depth: 0.5,
        };
        fine.validate().unwrap();
        for bad in [
            AugmentConfig {
                shift: -0.1,
                ..fine.clone()
            },
            AugmentConfig {
                scale: 1.0,
                ..fine.clone()
            },
            AugmentConfig {
                depth_dropout: f64::NAN,
                ..fine.clone()
            },
            AugmentConfig {
                depth_noise_m: 1e40,
                ..fine.clone()
            },
            AugmentConfig {
                sensor_depth: 1.5,
                ..fine.clone()
            },
            AugmentConfig {
                rotation_deg: 181.0,
                ..fine.clone()
            },
            AugmentConfig {
                rotation_deg: f64::INFINITY,
                ..fine.clone()
            },
        ] {
            let message = bad.validate().unwrap_err().to_string();
            assert!(message.starts_with("[augment]"), "{message}");
        }
    }
}
