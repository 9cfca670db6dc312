//! `boxpose train`: the keypoint network from a TOML config, with command-line overrides.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use boxpose_learn::backend::BackendKind;
use boxpose_learn::config::{Backbone, TrainConfig};
use boxpose_learn::segmentation::{SegmenterTask, SegmenterTrainConfig};
use boxpose_learn::training::{self, KeypointTask, MODEL_DIR, TrainOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Training config (TOML: [network], [augment], [optimizer], [data]); see configs/.
    #[arg(long, default_value = "configs/keypoint-slim.toml")]
    config: PathBuf,
    /// Run folder: config.toml, checkpoint/, history.csv and, when done, model/. A run folder
    /// with a checkpoint of the same config is resumed.
    #[arg(long)]
    out: PathBuf,
    /// Train on these dataset folders instead of the config's [data] datasets.
    #[arg(long = "dataset")]
    datasets: Vec<PathBuf>,
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
    /// Discard the run folder's checkpoint and train from scratch.
    #[arg(long)]
    restart: bool,
    /// Stop after this many steps of this session, with a checkpoint (resume later).
    #[arg(long)]
    stop_after: Option<usize>,
    /// Backend that runs the network (those not compiled in say how to enable them).
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

fn parse_backbone(text: &str) -> Result<Backbone, String> {
    toml::Value::String(text.into()).try_into().map_err(|_| format!("unknown backbone {text:?} (resnet18, resnet34, slim, tiny)"))
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut config = TrainConfig::load(&args.config)?;
    if !args.datasets.is_empty() {
        config.data.datasets = args.datasets.clone();
    }
    let o = &mut config.optimizer;
    o.steps = args.steps.unwrap_or(o.steps);
    o.batch_size = args.batch_size.unwrap_or(o.batch_size);
    o.learning_rate = args.learning_rate.unwrap_or(o.learning_rate);
    o.validate_every = args.validate_every.unwrap_or(o.validate_every);
    o.seed = args.seed.unwrap_or(o.seed);
    let n = &mut config.network;
    n.backbone = args.backbone.unwrap_or(n.backbone);
    n.input_size = args.input_size.unwrap_or(n.input_size);
    n.depth_bins = args.depth_bins.unwrap_or(n.depth_bins);
    config.data.max_val_instances = args.max_val_instances.unwrap_or(config.data.max_val_instances);
    config.validate().with_context(|| format!("{} with the command-line overrides", args.config.display()))?;

    let device = args.backend.device()?;
    println!(
        "training {:?} at {}² → {}×{}² heatmap on {} for {} steps of {} crops (backend {})",
        config.network.backbone,
        config.network.input_size,
        config.network.depth_bins,
        config.network.heatmap_size(),
        config.data.datasets.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "),
        config.optimizer.steps,
        config.optimizer.batch_size,
        args.backend.name(),
    );
    let task = Arc::new(KeypointTask::load(config.clone())?);
    println!("{} training / {} held-out instances", task.set.train.len(), task.set.val.len());
    let report = training::train(
        task,
        &config.optimizer,
        &config.to_toml(),
        config.data.loader_threads,
        &args.out,
        TrainOptions { device, restart: args.restart, stop_after: args.stop_after, progress: true },
    )?;
    print_report(&report, config.optimizer.steps)
}

/// `boxpose train-segmenter`: the instance segmenter from a TOML config.
#[derive(clap::Args)]
pub struct SegmenterArgs {
    /// Segmenter training config (TOML: [segmenter], [augment], [optimizer], [data]); see configs/.
    #[arg(long, default_value = "configs/segmenter-slim.toml")]
    config: PathBuf,
    /// Run folder (resumed when it holds a checkpoint of the same config).
    #[arg(long)]
    out: PathBuf,
    /// Train on these dataset folders instead of the config's [data] datasets.
    #[arg(long = "dataset")]
    datasets: Vec<PathBuf>,
    /// Override [optimizer] steps.
    #[arg(long)]
    steps: Option<usize>,
    /// Override [optimizer] learning_rate.
    #[arg(long)]
    learning_rate: Option<f64>,
    /// Discard the run folder's checkpoint and train from scratch.
    #[arg(long)]
    restart: bool,
    /// Stop after this many steps of this session, with a checkpoint (resume later).
    #[arg(long)]
    stop_after: Option<usize>,
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

pub fn run_segmenter(args: &SegmenterArgs) -> anyhow::Result<()> {
    let mut config = SegmenterTrainConfig::load(&args.config)?;
    if !args.datasets.is_empty() {
        config.data.datasets = args.datasets.clone();
    }
    config.optimizer.steps = args.steps.unwrap_or(config.optimizer.steps);
    config.optimizer.learning_rate = args.learning_rate.unwrap_or(config.optimizer.learning_rate);
    let device = args.backend.device()?;
    let task = Arc::new(SegmenterTask::load(config.clone())?);
    println!(
        "training the {:?} segmenter at {}×{} on {} training / {} held-out frames for {} steps of {} (backend {})",
        config.segmenter.backbone,
        config.segmenter.input_width,
        config.segmenter.input_height,
        task.set.train_frames.len(),
        task.set.val_frames.len(),
        config.optimizer.steps,
        config.optimizer.batch_size,
        args.backend.name()
    );
    let report = training::train(
        task,
        &config.optimizer,
        &config.to_toml(),
        config.data.loader_threads,
        &args.out,
        TrainOptions { device, restart: args.restart, stop_after: args.stop_after, progress: true },
    )?;
    print_report(&report, config.optimizer.steps)
}

fn print_report(report: &training::TrainReport, steps: usize) -> anyhow::Result<()> {
    if let Some(step) = report.resumed_from {
        println!("resumed from the checkpoint at step {step}");
    }
    println!("{} of {steps} steps done in {:.0} s of training", report.state.step, report.state.train_seconds);
    if let Some(v) = &report.state.last_validation {
        training::print_validation(v);
    }
    if report.finished {
        println!("model: {}", report.run_dir.join(MODEL_DIR).display());
    } else {
        println!("stopped early; run the same command again to resume");
    }
    Ok(())
}
