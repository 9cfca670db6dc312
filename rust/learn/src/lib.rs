//! Learning in boxpose (paper steps 3–5), laid out as burn's own examples: [`model`] (the
//! keypoint network), [`data`] (Parquet frames → crops and targets), [`training`] (the loop,
//! validation, checkpoints) and [`inference`] (a frame and a crop → heatmap → peaks → pose);
//! [`segmentation`] finds the boxes (and their crops) in a whole frame.

pub mod backend;
pub mod config;
pub mod data;
pub mod evaluation;
pub mod inference;
pub mod model;
pub mod segmentation;
pub mod training;

use std::path::PathBuf;

/// Every way learning can fail, each naming what to fix.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    #[error("{0}")]
    Config(String),
    #[error("{0}")]
    Data(String),
    #[error(transparent)]
    Dataset(#[from] boxpose_data::DataError),
    #[error("geometry: {0}")]
    Geometry(#[from] boxpose_geometry::GeometryError),
    #[error("{}: {}", .0.display(), .1)]
    Io(PathBuf, std::io::Error),
    #[error("{}: {}", .0.display(), .1)]
    Checkpoint(PathBuf, String),
    #[error("training diverged at step {step}: the loss is {loss} (lower the learning rate)")]
    Diverged { step: usize, loss: f64 },
    #[error("backend: {0}")]
    Backend(String),
}
