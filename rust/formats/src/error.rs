//! The one error type of the crate.

use std::path::PathBuf;

/// Why an export or a results file could not be written or read. Each message names the file
/// (or the dataset row) and the problem.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error(transparent)]
    Data(#[from] boxpose_data::DataError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Png {
        path: PathBuf,
        source: png::EncodingError,
    },
    #[error("{context}: {source}")]
    Geometry {
        context: String,
        source: boxpose_geometry::GeometryError,
    },
    /// The input holds something the format cannot express or the scorer cannot use; the
    /// message says which file or row and what.
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T, E = FormatError> = std::result::Result<T, E>;

/// `Io` for `path`, as a closure for `map_err`.
pub(crate) fn io(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> FormatError + '_ {
    move |source| FormatError::Io {
        path: path.to_path_buf(),
        source,
    }
}
