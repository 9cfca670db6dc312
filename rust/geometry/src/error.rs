//! The one error type of the crate: every fallible function returns `Result<_, GeometryError>`
//! instead of panicking on bad input.

/// Why a geometric computation refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// A coordinate, size, weight or parameter was NaN or infinite.
    #[error("{what} contains a non-finite value (NaN or infinity)")]
    NonFinite { what: &'static str },

    /// Fewer points than the computation needs.
    #[error("{what}: need at least {needed} points, got {got}")]
    TooFewPoints {
        what: &'static str,
        needed: usize,
        got: usize,
    },

    /// Points whose configuration does not determine the result (coincident or collinear).
    #[error("degenerate input: {0}")]
    Degenerate(&'static str),

    /// Two inputs that must agree in length (or a buffer and its dimensions) do not.
    #[error("{what}: expected {expected}, got {got}")]
    ShapeMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },

    /// A heatmap with no positive voxel: there is no peak to take.
    #[error("heatmap has no positive voxel")]
    EmptyHeatmap,

    /// A parameter outside its valid range (for example a non-positive sigma or box side).
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        name: &'static str,
        reason: &'static str,
    },

    /// A robust fit found no pose supported by at least three points.
    #[error("no pose hypothesis is supported by at least {needed} points")]
    NoConsensus { needed: usize },
}

pub type Result<T> = std::result::Result<T, GeometryError>;

/// Fails with [`GeometryError::NonFinite`] unless every value is finite.
pub(crate) fn ensure_finite<'a>(
    what: &'static str,
    values: impl IntoIterator<Item = &'a f64>,
) -> Result<()> {
    if values.into_iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(GeometryError::NonFinite { what })
    }
}

/// Fails with [`GeometryError::NonFinite`] unless every coordinate of every point is finite.
pub(crate) fn ensure_finite_points(
    what: &'static str,
    points: &[nalgebra::Point3<f64>],
) -> Result<()> {
    ensure_finite(what, points.iter().flat_map(|p| p.coords.iter()))
}

/// Fails with [`GeometryError::ShapeMismatch`] unless `got == expected`.
pub(crate) fn ensure_len(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(GeometryError::ShapeMismatch {
            what,
            expected,
            got,
        })
    }
}
