//! `boxpose train` and `boxpose train-segmenter`: a network from a TOML config, with
//! command-line overrides, in a run folder that resumes after an interruption.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use boxpose_learn::backend::BackendKind;
use boxpose_learn::config::{Backbone, DataConfig, OptimizerConfig, TrainConfig};
use boxpose_learn::data::DatasetSplit;
use boxpose_learn::keypoint::KeypointTask;
use boxpose_learn::segmentation::{SegmenterTask, SegmenterTrainConfig};
use boxpose_learn::training::{
    self, MODEL_DIR, RunConfig, Task, TrainObserver, TrainOptions, Validation,
};
use indicatif::{ProgressBar, ProgressStyle};

/// What both training commands take beside their config.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Run folder: config.toml, checkpoint/, history.csv and, when done, model/. A run folder
    /// with a checkpoint of the same config is resumed.
    #[arg(long)]
    out: PathBuf,
    /// Train on these dataset folders instead of the config's [data] datasets (and its repeat).
    #[arg(long = "dataset")]
    datasets: Vec<PathBuf>,
    /// Copies of each dataset's training scenes per epoch, one count per dataset in order
    /// (e.g. `--repeat 16,1`): the mix of a small set beside a large one. Overrides [data] repeat.
    #[arg(long, value_delimiter = ',', value_name = "K,K,…")]
    repeat: Vec<usize>,
    /// Override [optimizer] steps.
    #[arg(long)]
    steps: Option<usize>,
    /// Override [optimizer] batch_size.
    #[arg(long)]
    batch_size: Option<usize>,
    /// Override [optimizer] learning_rate.
    #[arg(long)]
    learning_rate: Option<f64>,
    /// Override [optimizer] validate_every.
    #[arg(long)]
    validate_every: Option<usize>,
    /// Override [optimizer] seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Discard the run folder's checkpoint and train from scratch.
    #[arg(long)]
    restart: bool,
    /// Stop after this many steps of this session, with a checkpoint (resume later).
    #[arg(long)]
    stop_after: Option<usize>,
    /// Fine-tune: start from the weights of this finished model folder (e.g. models/keypoint-slim)
    /// instead of random ones. Its network must be the config's; give the original datasets
    /// beside the new ones (--dataset twice) so that nothing is forgotten.
    #[arg(long, value_name = "MODEL")]
    init: Option<PathBuf>,
    /// Backend that runs the network (those not compiled in say how to enable them).
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

impl RunArgs {
    /// A run folder resumes its own checkpoint; a dataset or another command's run is refused
    /// before the run writes its config.toml into it, and a second training into the same
    /// folder while this one runs.
    fn claim_out(&self, command: &str) -> anyhow::Result<boxpose_data::output_folder::Claim> {
        Ok(boxpose_data::output_folder::claim(
            &self.out,
            "--out",
            command,
            &["config.toml", "checkpoint"],
        )?)
    }

    fn override_config(&self, data: &mut DataConfig, o: &mut OptimizerConfig) {
        override_datasets(data, &self.datasets, &self.repeat);
        o.steps = self.steps.unwrap_or(o.steps);
        o.batch_size = self.batch_size.unwrap_or(o.batch_size);
        o.learning_rate = self.learning_rate.unwrap_or(o.learning_rate);
        o.validate_every = self.validate_every.unwrap_or(o.validate_every);
        o.seed = self.seed.unwrap_or(o.seed);
    }

    /// Trains `task` and prints how the run ended.
    fn train<T: Task, C: RunConfig>(
        &self,
        task: T,
        o: &OptimizerConfig,
        config: &C,
        loader_threads: usize,
    ) -> anyhow::Result<()> {
        let options = TrainOptions {
            device: self.backend.device()?,
            restart: self.restart,
            stop_after: self.stop_after,
            init: self.init.clone(),
        };
        let report = training::train(
            Arc::new(task),
            o,
            config,
            loader_threads,
            &self.out,
            options,
            &mut ProgressDisplay::default(),
        )?;
        if let Some(step) = report.resumed_from {
            println!("resumed from the checkpoint at step {step}");
        }
        println!(
            "{} of {} steps done in {:.0} s of training",
            report.state.step, o.steps, report.state.train_seconds
        );
        if let Some(v) = &report.state.last_validation {
            println!("{}", validation_line(v));
        }
        if report.finished {
            println!("model: {}", report.run_dir.join(MODEL_DIR).display());
        } else {
            println!("stopped early; run the same command again to resume");
        }
        Ok(())
    }
}

/// `--dataset` (in place of the config's datasets and their repeat) and `--repeat`.
pub(crate) fn override_datasets(data: &mut DataConfig, datasets: &[PathBuf], repeat: &[usize]) {
    if !datasets.is_empty() {
        data.datasets = datasets.to_vec();
        data.repeat.clear();
    }
    if !repeat.is_empty() {
        data.repeat = repeat.to_vec();
    }
}

/// The training run on the terminal: a progress bar with the running loss and ETA, and a line
/// per validation.
#[derive(Default)]
struct ProgressDisplay {
    bar: Option<ProgressBar>,
}

impl TrainObserver for ProgressDisplay {
    fn started(&mut self, step: usize, total: usize) {
        let style = ProgressStyle::with_template(
            "training {bar:30} {pos}/{len} steps [{elapsed_precise}<{eta_precise}, {per_sec}] {msg}",
        )
        .expect("a valid template");
        let bar = ProgressBar::new(total as u64).with_style(style);
        bar.set_position(step as u64);
        bar.reset_eta();
        self.bar = Some(bar);
    }

    fn stepped(&mut self, step: usize, mean_loss: f64) {
        if let Some(bar) = &self.bar {
            bar.set_position(step as u64);
            bar.set_message(format!("loss {mean_loss:.3e}"));
        }
    }

    fn validated(&mut self, validation: &Validation) {
        let line = validation_line(validation);
        match &self.bar {
            Some(bar) => bar.suspend(|| println!("{line}")),
            None => println!("{line}"),
        }
    }

    fn ended(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

/// One validation as the CLI prints it.
fn validation_line(v: &Validation) -> String {
    let metrics: Vec<String> = v
        .metrics
        .iter()
        .map(|(name, value)| format!("{name} {value:.4}"))
        .collect();
    format!(
        "step {:>6}  train loss {:.3e}  held out: {}",
        v.step,
        v.train_loss,
        metrics.join(", ")
    )
}

#[derive(clap::Args)]
pub struct Args {
    /// Training config (TOML: [network], [augment], [optimizer], [data]); see configs/.
    #[arg(long, default_value = "configs/keypoint-slim.toml", value_parser = crate::shipped_path)]
    config: PathBuf,
    #[command(flatten)]
    run: RunArgs,
    /// Override [network] backbone.
    #[arg(long, value_parser = parse_backbone)]
    backbone: Option<Backbone>,
    /// Override [network] input_size (pixels, a multiple of 32).
    #[arg(long)]
    input_size: Option<usize>,
    /// Override [network] depth_bins.
    #[arg(long)]
    depth_bins: Option<usize>,
    /// Override [data] max_val_instances (0: every held-out instance).
    #[arg(long)]
    max_val_instances: Option<usize>,
}

fn parse_backbone(text: &str) -> Result<Backbone, String> {
    toml::Value::String(text.into())
        .try_into()
        .map_err(|_| format!("unknown backbone {text:?} (resnet18, resnet34, slim, tiny)"))
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let _claim = args.run.claim_out("train")?;
    let mut config = TrainConfig::load(&args.config)?;
    args.run
        .override_config(&mut config.data, &mut config.optimizer);
    let n = &mut config.network;
    n.backbone = args.backbone.unwrap_or(n.backbone);
    n.input_size = args.input_size.unwrap_or(n.input_size);
    n.depth_bins = args.depth_bins.unwrap_or(n.depth_bins);
    config.data.max_val_instances = args
        .max_val_instances
        .unwrap_or(config.data.max_val_instances);
    config
        .validate()
        .with_context(|| format!("{} with the command-line overrides", args.config.display()))?;

    let task = KeypointTask::load(config.clone())?;
    println!(
        "training {:?} at {}² → {}×{}² heatmap on {} training / {} held-out instances for {} steps of {} crops (backend {})",
        config.network.backbone,
        config.network.input_size,
        config.network.depth_bins,
        config.network.heatmap_size(),
        task.set.train.len(),
        task.set.val.len(),
        config.optimizer.steps,
        config.optimizer.batch_size,
        args.run.backend.name(),
    );
    print_splits(
        &task.set.splits,
        "instances",
        config.data.val_modulus,
        |s| (s.train_instances, s.held_out_instances),
    );
    args.run
        .train(task, &config.optimizer, &config, config.data.loader_threads)
}

/// A line per dataset: its share of training and held-out `unit`s, and what it means for the
/// run when one side is empty (a sharded recipe's folder may hold only held-out scenes, or none).
fn print_splits(
    splits: &[DatasetSplit],
    unit: &str,
    val_modulus: i64,
    counts: impl Fn(&DatasetSplit) -> (usize, usize),
) {
    for split in splits {
        let (train, held_out) = counts(split);
        let remark = match (train, held_out) {
            (0, 0) => " — nothing usable in it".to_string(),
            (0, _) => format!(
                " — every scene of it is held out (scene_id % {val_modulus} == 0): it adds nothing to training"
            ),
            (_, 0) => format!(
                " — none of its scenes is held out (scene_id % {val_modulus} == 0): held-out scores do not cover it"
            ),
            _ => String::new(),
        };
        let copies = if split.repeat > 1 && train > 0 {
            format!(" (×{} per epoch)", split.repeat)
        } else {
            String::new()
        };
        println!(
            "  {}: {train} training{copies} / {held_out} held-out {unit}{remark}",
            split.path.display()
        );
    }
}

#[derive(clap::Args)]
pub struct SegmenterArgs {
    /// Segmenter training config (TOML: [segmenter], [augment], [optimizer], [data]); see configs/.
    #[arg(long, default_value = "configs/segmenter-slim.toml", value_parser = crate::shipped_path)]
    config: PathBuf,
    #[command(flatten)]
    run: RunArgs,
}

pub fn run_segmenter(args: &SegmenterArgs) -> anyhow::Result<()> {
    let _claim = args.run.claim_out("train-segmenter")?;
    let mut config = SegmenterTrainConfig::load(&args.config)?;
    args.run
        .override_config(&mut config.data, &mut config.optimizer);
    let task = SegmenterTask::load(config.clone())?;
    println!(
        "training the {:?} segmenter at {}×{} on {} training / {} held-out frames for {} steps of {} (backend {})",
        config.segmenter.backbone,
        config.segmenter.input_width,
        config.segmenter.input_height,
        task.set.train_frames.len(),
        task.set.val_frames.len(),
        config.optimizer.steps,
        config.optimizer.batch_size,
        args.run.backend.name()
    );
    print_splits(&task.set.splits, "frames", config.data.val_modulus, |s| {
        (s.train_frames, s.held_out_frames)
    });
    args.run
        .train(task, &config.optimizer, &config, config.data.loader_threads)
}
