//! The keypoint network's task (paper step 3): crops of ground-truth instances, the weighted
//! heatmap MSE, and held-out scores from the evaluation of each crop's fits.

use std::path::Path;
use std::sync::Arc;

use boxpose_data::Frame;
use boxpose_geometry::BoxModel;
use boxpose_geometry::pipeline::Method;
use burn::prelude::*;
use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::LearnError;
use crate::config::{NetworkConfig, TrainConfig};
use crate::data::{self, InstanceSet};
use crate::evaluation::{self, InstanceEval};
use crate::inference::{self, KeypointModel, NETWORK_FILE};
use crate::loader::ExampleSource;
use crate::model::{KeypointNet, ResNetDeconv};
use crate::model_dir;
use crate::training::Task;

/// The keypoint network's task: crops of ground-truth instances, heatmap MSE.
pub struct KeypointTask {
    pub config: TrainConfig,
    pub set: InstanceSet,
}

impl KeypointTask {
    pub fn load(config: TrainConfig) -> Result<Self, LearnError> {
        config.validate()?;
        let set = InstanceSet::load(&config.data)?;
        Ok(Self { config, set })
    }

    /// Scores on (up to `max_val_instances`, evenly spread) held-out instances.
    pub fn evaluate(&self, net: &KeypointNet) -> Result<Vec<InstanceEval>, LearnError> {
        let (config, set) = (&self.config, &self.set);
        let max = config.data.max_val_instances;
        let mut picks = set.val.clone();
        if max > 0 && picks.len() > max {
            picks = (0..max).map(|i| set.val[i * set.val.len() / max]).collect();
        }
        if picks.is_empty() {
            return Err(LearnError::Data(format!(
                "no held-out instance: no scene has scene_id % {} == 0 (add scenes or lower val_modulus)",
                config.data.val_modulus
            )));
        }
        let samples = picks
            .par_iter()
            .map(|&pick| Ok(self.plain_sample(pick)?.0))
            .collect::<Result<Vec<_>, LearnError>>()?;
        let device = net.devices().into_iter().next().unwrap_or_default();
        let model = KeypointModel {
            config: config.network.clone(),
            net: net.clone(),
            device,
        };
        let inputs: Vec<Vec<f32>> = samples.iter().map(|s| s.input.clone()).collect();
        let heatmaps = model.heatmaps(&inputs, config.optimizer.batch_size)?;
        picks
            .par_iter()
            .zip(samples)
            .zip(heatmaps)
            .map(|((&pick, sample), heatmap)| {
                let instance = set.instance(pick);
                let known = BoxModel::new(Vector3::from(instance.size))?;
                let perception = inference::perceive_heatmap(
                    &config.network,
                    heatmap,
                    sample.grid,
                    Some(&known),
                    &Method::ALL,
                    // validation keeps no frames in memory: the fits run on the peaks alone
                    None,
                )?;
                evaluation::evaluate_perception(instance, &perception, &sample.target)
            })
            .collect()
    }
}

impl ExampleSource for KeypointTask {
    fn train_items(&self) -> usize {
        self.set.train.len()
    }

    fn training_example(
        &self,
        item: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<(Vec<f32>, Vec<f32>), LearnError> {
        let (sample, _) = self.training_sample(item, rng)?;
        Ok((sample.input, sample.target))
    }
}

impl KeypointTask {
    /// Training item `item` as training draws it with `rng` (the depth it reads, then the crop's
    /// augmentation), and the frame it was read from (the sensor's depth in place when the draw
    /// chose it).
    pub fn training_sample(
        &self,
        item: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<(data::Sample, Arc<Frame>), LearnError> {
        let pick = self.set.train[item];
        let mut frame = self.set.frame(pick.0)?;
        let augment = &self.config.augment;
        // drawn only when asked for, so that other configs' random streams stay as they were
        if augment.sensor_depth > 0.0
            && frame.sensor_depth.is_some()
            && rng.random_bool(augment.sensor_depth)
        {
            let mut sensed = Frame::clone(&frame);
            sensed.use_sensor_depth();
            frame = Arc::new(sensed);
        }
        let sample = data::instance_sample(
            &self.config.network,
            &frame,
            self.set.instance(pick),
            Some((augment, rng)),
        )?;
        Ok((sample, frame))
    }

    /// The instance `pick` (frame, instance) of either split without augmentation, as validation
    /// reads it, and its frame.
    pub fn plain_sample(
        &self,
        pick: (usize, usize),
    ) -> Result<(data::Sample, Arc<Frame>), LearnError> {
        let frame = self.set.frame(pick.0)?;
        let sample =
            data::instance_sample(&self.config.network, &frame, self.set.instance(pick), None)?;
        Ok((sample, frame))
    }
}

impl Task for KeypointTask {
    fn input_shape(&self) -> [usize; 3] {
        let s = self.config.network.input_size;
        [4, s, s]
    }

    fn target_shape(&self) -> [usize; 3] {
        let n = self.config.network.heatmap_size();
        [self.config.network.depth_bins, n, n]
    }

    fn network(&self, device: &Device) -> ResNetDeconv {
        KeypointNet::keypoints(&self.config.network, device)
    }

    /// The paper's loss, mean squared error of the heatmap against the Gaussian target, with each
    /// voxel weighted by 1 + positive_weight·target (see [`crate::config::OptimizerConfig::positive_weight`]).
    fn loss(&self, output: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let weight = target.clone() * self.config.optimizer.positive_weight + 1.0;
        ((output - target).powi_scalar(2) * weight).mean()
    }

    fn validate(&self, net: &ResNetDeconv) -> Result<Vec<(String, f64)>, LearnError> {
        Ok(evaluation::summarize(&self.evaluate(net)?).named())
    }

    fn save_model(&self, net: &ResNetDeconv, dir: &Path) -> Result<(), LearnError> {
        KeypointModel::save(&self.config.network, net, dir)
    }

    fn check_same_network(&self, dir: &Path) -> Result<(), LearnError> {
        model_dir::check_same_network(
            dir,
            NETWORK_FILE,
            &self.config.network,
            NetworkConfig::can_fine_tune_from,
        )
    }
}
