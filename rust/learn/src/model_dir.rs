//! A model folder on disk: a network's config (TOML) and its weights (`model.bpk`, burn's
//! burnpack), written atomically; training checkpoints are written the same way.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::LearnError;
use crate::model::ResNetDeconv;

pub(crate) const WEIGHTS_FILE: &str = "model.bpk";

/// Reads a trained network's folder: its config (TOML, `config_file`), checked by `validate`,
/// and its weights (`model.bpk`), loaded into the untrained network `build` makes from it.
pub(crate) fn load_model_dir<C: DeserializeOwned>(
    dir: &Path,
    config_file: &str,
    validate: impl FnOnce(&C) -> Result<(), LearnError>,
    build: impl FnOnce(&C) -> ResNetDeconv,
) -> Result<(C, ResNetDeconv), LearnError> {
    let config = check_model_dir(dir, config_file, validate)?;
    let weights = dir.join(WEIGHTS_FILE);
    let net = build(&config).try_load_file(&weights).map_err(|e| {
        LearnError::Checkpoint(
            weights.clone(),
            format!("cannot load the weights ({e}); were they trained with this {config_file}?"),
        )
    })?;
    Ok((config, net.valid()))
}

/// Reads a trained network's folder as [`load_model_dir`] does — its config, checked by
/// `validate`, and the presence of its weights — without loading the weights: what a command
/// checks before it starts work that the model is needed for later.
pub(crate) fn check_model_dir<C: DeserializeOwned>(
    dir: &Path,
    config_file: &str,
    validate: impl FnOnce(&C) -> Result<(), LearnError>,
) -> Result<C, LearnError> {
    let config: C = read_model_config(dir, config_file)?;
    validate(&config).map_err(|e| LearnError::Checkpoint(dir.join(config_file), e.to_string()))?;
    let weights = dir.join(WEIGHTS_FILE);
    if !weights.is_file() {
        return Err(LearnError::Checkpoint(
            weights,
            "missing: is this a model folder written by `boxpose train` or `train-segmenter`?"
                .into(),
        ));
    }
    Ok(config)
}

/// A model folder's network config (`config_file`, TOML).
pub(crate) fn read_model_config<C: DeserializeOwned>(
    dir: &Path,
    config_file: &str,
) -> Result<C, LearnError> {
    let config_path = dir.join(config_file);
    let text = std::fs::read_to_string(&config_path)
        .map_err(|e| LearnError::Io(config_path.clone(), e))?;
    toml::from_str(&text).map_err(|e| LearnError::Checkpoint(config_path, e.to_string()))
}

/// Checks that the model folder `dir` holds a network whose weights can start a run that trains
/// `expected` (`fits(expected, found)`, the config type's rule): what fine-tuning starts from.
pub(crate) fn check_same_network<C: DeserializeOwned + std::fmt::Debug>(
    dir: &Path,
    config_file: &str,
    expected: &C,
    fits: impl FnOnce(&C, &C) -> bool,
) -> Result<(), LearnError> {
    let found: C = read_model_config(dir, config_file)?;
    if !fits(expected, &found) {
        return Err(LearnError::Config(format!(
            "{}: its network ({found:?}) is not the one this run trains ({expected:?}); \
             fine-tuning needs the same network settings",
            dir.join(config_file).display()
        )));
    }
    Ok(())
}

/// Writes a trained network's folder (`config_file` and `model.bpk`) atomically: into `dir.tmp`,
/// then renamed.
pub(crate) fn save_model_dir<C: Serialize>(
    dir: &Path,
    config_file: &str,
    config: &C,
    net: &ResNetDeconv,
) -> Result<(), LearnError> {
    write_dir_atomically(dir, |tmp| {
        let path = tmp.join(config_file);
        std::fs::write(
            &path,
            toml::to_string_pretty(config).expect("a network config serializes"),
        )
        .map_err(|e| LearnError::Io(path, e))?;
        let path = tmp.join(WEIGHTS_FILE);
        net.clone()
            .save_file(&path)
            .map_err(|e| LearnError::Checkpoint(path, e.to_string()))
    })
}

/// Writes a folder by filling `dir.tmp` and publishing it as `dir`
/// ([`boxpose_data::publish_folder`]), so a reader never sees a half-written one and `dir` is
/// never missing (an interrupted write leaves the previous folder intact).
pub(crate) fn write_dir_atomically(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<(), LearnError>,
) -> Result<(), LearnError> {
    let with_suffix = |suffix: &str| -> PathBuf {
        let mut name = dir.file_name().unwrap_or_default().to_os_string();
        name.push(suffix);
        dir.with_file_name(name)
    };
    let (tmp, old) = (with_suffix(".tmp"), with_suffix(".old"));
    restore_interrupted(dir, &old)?;
    for leftover in [&tmp, &old] {
        if leftover.exists() {
            std::fs::remove_dir_all(leftover).map_err(|e| LearnError::Io(leftover.clone(), e))?;
        }
    }
    std::fs::create_dir_all(&tmp).map_err(|e| LearnError::Io(tmp.clone(), e))?;
    fill(&tmp)?;
    // swapped in one step; where the file system cannot, the previous folder waits at `dir.old`
    boxpose_data::publish_folder(&tmp, dir)?;
    Ok(())
}

/// If a write was interrupted between the renames of a file system that cannot swap two folders,
/// `dir` is missing and `dir.old` is the last complete folder: put it back.
pub(crate) fn restore_interrupted(dir: &Path, old: &Path) -> Result<(), LearnError> {
    if !dir.exists() && old.exists() {
        std::fs::rename(old, dir).map_err(|e| LearnError::Io(dir.to_path_buf(), e))?;
    }
    Ok(())
}
