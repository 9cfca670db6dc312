use std::path::PathBuf;

/// Everything that can stop a search, each naming what to fix.
#[derive(Debug, thiserror::Error)]
pub enum SearchError {
    /// A search space key that is unknown, missing or out of range.
    #[error("search space: {key}: {problem}")]
    Space { key: String, problem: String },
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    /// A run folder that belongs to another search, or is damaged.
    #[error("run folder {path}: {problem}")]
    Run { path: PathBuf, problem: String },
    /// A command-line setting that cannot be used; the message starts with its flag.
    #[error("{0}")]
    Settings(String),
    #[error("sample: {0}")]
    Sample(String),
    #[error(transparent)]
    Data(#[from] boxpose_data::DataError),
    #[error(transparent)]
    Physics(#[from] boxpose_physics::PhysicsError),
    #[error(transparent)]
    Render(#[from] boxpose_render::RenderError),
    #[error(transparent)]
    Learn(#[from] boxpose_learn::LearnError),
    #[error(transparent)]
    Geometry(#[from] boxpose_geometry::GeometryError),
}

pub type Result<T, E = SearchError> = std::result::Result<T, E>;
