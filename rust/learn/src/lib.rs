//! Learning in boxpose (paper steps 3–5), laid out as burn's own examples, each module using only
//! those before it (`tests/module_graph.rs` holds the order):
//! - [`config`], [`backend`];
//! - [`data`]: Parquet frames → crops and targets (no burn); [`loader`]: batches on worker
//!   threads (no burn);
//! - [`model`]: the ResNet + deconvolution network; [`model_dir`]: model folders on disk;
//! - [`inference`]: a frame and a crop → heatmap → peaks → pose; [`evaluation`]: scores of it;
//!   [`prediction`]: `boxpose predict`'s boxes, fits and table;
//!   [`fit_table`]: the Arrow columns of the fit tables (no burn);
//! - [`training`]: the loop, validation and checkpoints for any [`training::Task`], reporting to
//!   a [`training::TrainObserver`];
//! - [`keypoint`]: the keypoint network's task; [`segmentation`]: the segmenter (its model,
//!   grouping, AP and task), which finds the boxes (and their crops) in a whole frame;
//! - [`sample_server`]: the keypoint task's training examples for another framework's loop
//!   (protocol `boxpose-samples/1`, no burn).

pub mod backend;
pub mod config;
pub mod data;
pub mod evaluation;
pub mod fit_table;
pub mod inference;
pub mod keypoint;
pub mod loader;
pub mod model;
pub mod model_dir;
pub mod prediction;
pub mod sample_server;
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
