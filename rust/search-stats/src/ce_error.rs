//! The error of the cross-entropy method, its own module because both the step ([`crate::ce`])
//! and the choice of tilted dimensions ([`crate::tilt`]) return it.

use crate::proposal::ProposalError;
use crate::stats::EstimateError;

/// Errors of the cross-entropy step, its configuration and the reference driver.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CeError {
    /// A configuration value is out of range; `key` names it.
    #[error("ce config `{key}`: {message}")]
    Config {
        /// The offending key.
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// The step's inputs do not match (lengths, or no finite score).
    #[error("ce step: {0}")]
    Input(String),
    /// The weighted fit failed.
    #[error(transparent)]
    Proposal(#[from] ProposalError),
    /// The final estimate could not be formed.
    #[error(transparent)]
    Estimate(#[from] EstimateError),
}
