//! The training loop shared by both networks: Adam on the task's loss, warm-up then cosine
//! learning-rate decay, validation on held-out scenes every `validate_every` steps, and a
//! checkpoint (weights, optimizer state, step, history) written atomically at each validation,
//! from which an interrupted run resumes exactly where it stopped.
//!
//! A run folder holds `config.toml` (the full configuration), `checkpoint/` (the latest state),
//! `history.csv` (one row per validation) and, at the end, `model/` (what inference loads).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::LearnError;
use crate::config::OptimizerConfig;
use crate::loader::{ExampleSource, spawn_loader};
use crate::model::ResNetDeconv;
use crate::model_dir::{WEIGHTS_FILE, restore_interrupted, write_dir_atomically};

const CONFIG_FILE: &str = "config.toml";
const CHECKPOINT_DIR: &str = "checkpoint";
const STATE_FILE: &str = "state.toml";
const OPTIMIZER_FILE: &str = "optimizer.bpk";
const HISTORY_FILE: &str = "history.csv";
pub const MODEL_DIR: &str = "model";

/// What a network learns: its examples (an [`ExampleSource`]), loss, held-out scores and saved
/// form.
pub trait Task: ExampleSource {
    /// Shapes of one example's input and target, `[channels, height, width]`.
    fn input_shape(&self) -> [usize; 3];
    fn target_shape(&self) -> [usize; 3];
    fn network(&self, device: &Device) -> ResNetDeconv;
    /// The scalar loss of a batch's output against its targets.
    fn loss(&self, output: Tensor<4>, target: Tensor<4>) -> Tensor<1>;
    /// Held-out scores of the network (in inference mode), as (name, value) in a fixed order.
    fn validate(&self, net: &ResNetDeconv) -> Result<Vec<(String, f64)>, LearnError>;
    /// Writes the finished model folder.
    fn save_model(&self, net: &ResNetDeconv, dir: &Path) -> Result<(), LearnError>;
    /// Checks that the finished model folder `dir` holds this task's network, whose weights a
    /// run can then start from (fine-tuning).
    fn check_same_network(&self, dir: &Path) -> Result<(), LearnError>;
}

/// What a checkpoint records beside the weights: where the run stands.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainState {
    /// Optimizer steps done.
    pub step: usize,
    /// Wall-clock seconds spent training so far, over every session of the run.
    pub train_seconds: f64,
    pub last_validation: Option<Validation>,
}

/// One validation: the mean training loss since the previous one, and held-out scores.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Validation {
    pub step: usize,
    pub train_loss: f64,
    pub metrics: Vec<(String, f64)>,
}

/// How a run ended.
pub struct TrainReport {
    pub run_dir: PathBuf,
    pub state: TrainState,
    pub resumed_from: Option<usize>,
    pub finished: bool,
}

/// Options of one run beyond the configuration.
pub struct TrainOptions {
    pub device: Device,
    /// Discard an existing checkpoint in the run folder instead of resuming from it.
    pub restart: bool,
    /// Stop (with a checkpoint) after this many steps of this session; for tests and time-boxed
    /// jobs. The run resumes from there later.
    pub stop_after: Option<usize>,
    /// Start from the weights of this finished model folder (fine-tuning) instead of random
    /// ones; used when the run starts, ignored when it resumes from its checkpoint.
    pub init: Option<PathBuf>,
}

/// What a run reports as it goes, for a progress display: the library prints nothing.
pub trait TrainObserver {
    /// The run starts at `step` (0, or where it resumes) of `total`.
    fn started(&mut self, _step: usize, _total: usize) {}
    /// Step `step` is done; `mean_loss` is the training loss since the last validation.
    fn stepped(&mut self, _step: usize, _mean_loss: f64) {}
    /// A validation was scored (and checkpointed).
    fn validated(&mut self, _validation: &Validation) {}
    /// The session ends (finished, stopped early or failed).
    fn ended(&mut self) {}
}

/// An observer that shows nothing.
pub struct Silent;

impl TrainObserver for Silent {}

/// Learning rate at `step`: linear warm-up over the first 5 % of the run, then cosine decay to
/// `final_lr_fraction` of the peak.
pub fn learning_rate(o: &OptimizerConfig, step: usize) -> f64 {
    let warmup = (o.steps / 20).max(1);
    if step < warmup {
        return o.learning_rate * (step + 1) as f64 / warmup as f64;
    }
    let progress = (step - warmup) as f64 / (o.steps - warmup).max(1) as f64;
    let floor = o.learning_rate * o.final_lr_fraction;
    floor
        + (o.learning_rate - floor) * 0.5 * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos())
}

/// Holds an exclusive lock on `run_dir/.lock` for as long as the returned file lives: two
/// trainings in one run folder would overwrite each other's checkpoints.
fn lock_run_dir(run_dir: &Path) -> Result<std::fs::File, LearnError> {
    let path = run_dir.join(".lock");
    let file = std::fs::File::create(&path).map_err(|e| LearnError::Io(path.clone(), e))?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => Err(LearnError::Config(format!(
            "another training is running in {} (it holds {}); wait for it, stop it, or choose another run folder",
            run_dir.display(),
            path.display()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(LearnError::Io(path, e)),
    }
}

/// A training config as a run folder keeps it: written as TOML, read back and compared on resume.
pub trait RunConfig: Serialize + DeserializeOwned + PartialEq {}
impl<C: Serialize + DeserializeOwned + PartialEq> RunConfig for C {}

/// Trains `task` in `run_dir`, resuming its checkpoint when the run's configuration is unchanged.
/// The saved `config.toml` is compared as a value read with today's defaults, so a field added
/// to the config since the checkpoint was written does not orphan it.
pub fn train<T: Task, C: RunConfig>(
    task: Arc<T>,
    o: &OptimizerConfig,
    config: &C,
    loader_threads: usize,
    run_dir: &Path,
    options: TrainOptions,
    observer: &mut dyn TrainObserver,
) -> Result<TrainReport, LearnError> {
    std::fs::create_dir_all(run_dir).map_err(|e| LearnError::Io(run_dir.to_path_buf(), e))?;
    let _lock = lock_run_dir(run_dir)?;
    let checkpoint_dir = run_dir.join(CHECKPOINT_DIR);
    restore_interrupted(
        &checkpoint_dir,
        &run_dir.join(format!("{CHECKPOINT_DIR}.old")),
    )?;
    let config_path = run_dir.join(CONFIG_FILE);
    if options.restart {
        for stale in [
            checkpoint_dir.clone(),
            run_dir.join(MODEL_DIR),
            run_dir.join(HISTORY_FILE),
        ] {
            remove_if_present(&stale)?;
        }
    } else if checkpoint_dir.exists() {
        let saved = std::fs::read_to_string(&config_path)
            .map_err(|e| LearnError::Io(config_path.clone(), e))?;
        if toml::from_str::<C>(&saved).ok().as_ref() != Some(config) {
            return Err(LearnError::Config(format!(
                "{} holds a checkpoint of a run with another configuration ({}); pass --restart to discard it or choose another run folder",
                run_dir.display(),
                config_path.display()
            )));
        }
    }
    let config_toml = toml::to_string_pretty(config)
        .map_err(|e| LearnError::Config(format!("the configuration cannot be written: {e}")))?;
    // Atomically: a kill here must not leave a torn config that only --restart (which deletes
    // the checkpoint) gets past.
    boxpose_data::write_file_atomically(&config_path, config_toml.as_bytes())?;

    let device = options.device.clone().autodiff();
    device.seed(o.seed);
    let mut model = task.network(&device);
    let mut optimizer = AdamConfig::new()
        .with_weight_decay(Some(WeightDecayConfig::new(o.weight_decay as f32)))
        .init();
    let mut state = TrainState {
        step: 0,
        train_seconds: 0.0,
        last_validation: None,
    };
    let mut resumed_from = None;
    if checkpoint_dir.exists() {
        (model, optimizer, state) = load_checkpoint(&checkpoint_dir, model, optimizer)?;
        trim_history(run_dir, state.step)?;
        resumed_from = Some(state.step);
    } else {
        // a run that stopped before its first checkpoint starts again from step 0, with a new history
        remove_if_present(&run_dir.join(HISTORY_FILE))?;
        if let Some(init) = &options.init {
            task.check_same_network(init)?;
            let path = init.join(WEIGHTS_FILE);
            model = model
                .try_load_file(&path)
                .map_err(|e| LearnError::Checkpoint(path.clone(), e.to_string()))?;
        }
    }

    let last_step = match options.stop_after {
        Some(n) => (state.step + n).min(o.steps),
        None => o.steps,
    };
    let batches = spawn_loader(
        task.clone(),
        o.batch_size,
        o.seed,
        state.step,
        last_step,
        loader_threads,
    )?;
    observer.started(state.step, o.steps);
    let result = run_steps(
        &task,
        o,
        run_dir,
        &checkpoint_dir,
        &device,
        model,
        optimizer,
        state,
        last_step,
        batches,
        observer,
    );
    observer.ended();
    let (model, state) = result?;
    let finished = state.step == o.steps;
    if finished {
        task.save_model(&model.valid(), &run_dir.join(MODEL_DIR))?;
    }
    Ok(TrainReport {
        run_dir: run_dir.to_path_buf(),
        state,
        resumed_from,
        finished,
    })
}

/// The optimizer steps of one session, from `state.step` to `last_step`, validating and
/// checkpointing on the way; returns the network and where the run stands.
#[allow(clippy::too_many_arguments)]
fn run_steps<T: Task>(
    task: &Arc<T>,
    o: &OptimizerConfig,
    run_dir: &Path,
    checkpoint_dir: &Path,
    device: &Device,
    mut model: ResNetDeconv,
    mut optimizer: ModuleOptimizer,
    mut state: TrainState,
    last_step: usize,
    batches: std::sync::mpsc::Receiver<Result<crate::loader::Batch, LearnError>>,
    observer: &mut dyn TrainObserver,
) -> Result<(ResNetDeconv, TrainState), LearnError> {
    let (input_shape, target_shape) = (task.input_shape(), task.target_shape());
    let (mut loss_sum, mut loss_count) = (0.0, 0usize);
    let mut session_start = Instant::now();
    while state.step < last_step {
        let batch = batches
            .recv()
            .map_err(|_| LearnError::Data("the batch loader stopped".into()))??;
        // workers build batches in parallel; the trainer must still see them in step order
        assert_eq!(
            batch.step, state.step,
            "the batch loader delivered a batch out of order"
        );
        let [c, h, w] = input_shape;
        let inputs =
            Tensor::<4>::from_data(TensorData::new(batch.inputs, [batch.size, c, h, w]), device);
        let [c, h, w] = target_shape;
        let targets = Tensor::<4>::from_data(
            TensorData::new(batch.targets, [batch.size, c, h, w]),
            device,
        );
        let loss = task.loss(model.forward(inputs), targets);
        let loss_value = loss.clone().into_scalar::<f32>() as f64;
        if !loss_value.is_finite() {
            return Err(LearnError::Diverged {
                step: state.step,
                loss: loss_value,
            });
        }
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optimizer.step(learning_rate(o, state.step), model, grads);
        state.step += 1;
        loss_sum += loss_value;
        loss_count += 1;
        observer.stepped(state.step, loss_sum / loss_count as f64);
        if state.step.is_multiple_of(o.validate_every) || state.step == last_step {
            state.train_seconds += session_start.elapsed().as_secs_f64();
            let validation = Validation {
                step: state.step,
                train_loss: loss_sum / loss_count as f64,
                metrics: task.validate(&model.valid())?,
            };
            append_history(run_dir, &validation)?;
            state.last_validation = Some(validation);
            save_checkpoint(checkpoint_dir, &model, &optimizer, &state)?;
            if let Some(validation) = &state.last_validation {
                observer.validated(validation);
            }
            (loss_sum, loss_count) = (0.0, 0);
            session_start = Instant::now();
        }
    }
    Ok((model, state))
}

fn save_checkpoint(
    dir: &Path,
    model: &ResNetDeconv,
    optimizer: &ModuleOptimizer,
    state: &TrainState,
) -> Result<(), LearnError> {
    write_dir_atomically(dir, |tmp| {
        let path = tmp.join(WEIGHTS_FILE);
        model
            .clone()
            .save_file(&path)
            .map_err(|e| LearnError::Checkpoint(path, e.to_string()))?;
        let path = tmp.join(OPTIMIZER_FILE);
        optimizer
            .save(&path)
            .map_err(|e| LearnError::Checkpoint(path, e.to_string()))?;
        let path = tmp.join(STATE_FILE);
        std::fs::write(
            &path,
            toml::to_string_pretty(state).expect("a TrainState serializes"),
        )
        .map_err(|e| LearnError::Io(path, e))
    })
}

fn load_checkpoint(
    dir: &Path,
    model: ResNetDeconv,
    optimizer: ModuleOptimizer,
) -> Result<(ResNetDeconv, ModuleOptimizer, TrainState), LearnError> {
    let bad = |path: PathBuf, e: String| {
        LearnError::Checkpoint(path, format!("{e}; pass --restart to train from scratch"))
    };
    let path = dir.join(STATE_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| bad(path.clone(), e.to_string()))?;
    let state: TrainState = toml::from_str(&text).map_err(|e| bad(path.clone(), e.to_string()))?;
    let path = dir.join(WEIGHTS_FILE);
    let model = model
        .try_load_file(&path)
        .map_err(|e| bad(path.clone(), e.to_string()))?;
    let path = dir.join(OPTIMIZER_FILE);
    let optimizer = optimizer
        .load(&path)
        .map_err(|e| bad(path.clone(), e.to_string()))?;
    Ok((model, optimizer, state))
}

/// Removes a file or folder; one that is not there is fine.
fn remove_if_present(path: &Path) -> Result<(), LearnError> {
    let removed = if path.is_dir() {
        std::fs::remove_dir_all(path)
    } else {
        std::fs::remove_file(path)
    };
    match removed {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(LearnError::Io(path.to_path_buf(), e))
        }
        _ => Ok(()),
    }
}

/// Drops the history rows after `step`: a run stopped between a validation and its checkpoint
/// redoes those steps on resume and would otherwise list them twice.
fn trim_history(run_dir: &Path, step: usize) -> Result<(), LearnError> {
    let path = run_dir.join(HISTORY_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(LearnError::Io(path, e)),
    };
    let row_step = |line: &str| {
        line.split(',')
            .next()
            .and_then(|field| field.parse::<usize>().ok())
    };
    let kept: String = text
        .lines()
        .filter(|line| row_step(line).is_none_or(|row| row <= step))
        .map(|line| format!("{line}\n"))
        .collect();
    if kept == text {
        return Ok(());
    }
    Ok(boxpose_data::write_file_atomically(&path, kept.as_bytes())?)
}

fn append_history(run_dir: &Path, v: &Validation) -> Result<(), LearnError> {
    let path = run_dir.join(HISTORY_FILE);
    let mut line = String::new();
    if !path.exists() {
        line.push_str("step,train_loss");
        v.metrics
            .iter()
            .for_each(|(name, _)| line.push_str(&format!(",{name}")));
        line.push('\n');
    }
    line.push_str(&format!("{},{:.6e}", v.step, v.train_loss));
    v.metrics
        .iter()
        .for_each(|(_, value)| line.push_str(&format!(",{value}")));
    line.push('\n');
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(|e| LearnError::Io(path.clone(), e))?;
    file.write_all(line.as_bytes())
        .map_err(|e| LearnError::Io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_folder_admits_one_training_at_a_time() {
        let dir = tempfile::tempdir().unwrap();
        let held = lock_run_dir(dir.path()).unwrap();
        let second = lock_run_dir(dir.path()).unwrap_err().to_string();
        assert!(second.contains("another training is running"), "{second}");
        drop(held);
        lock_run_dir(dir.path()).expect("the lock is free once the first training ends");
    }

    #[test]
    fn resuming_drops_the_history_rows_after_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(HISTORY_FILE);
        std::fs::write(&path, "step,train_loss\n250,0.5\n500,0.4\n750,0.3\n").unwrap();
        trim_history(dir.path(), 500).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "step,train_loss\n250,0.5\n500,0.4\n"
        );
        trim_history(dir.path(), 0).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "step,train_loss\n");
    }
}
