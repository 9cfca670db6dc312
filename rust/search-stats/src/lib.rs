//! Statistics for boxpose's rare-failure search, with no knowledge of scenes.
//!
//! The search writes every scene as a deterministic function of a fixed-length vector
//! z ∈ R^d of standard normals, so the nominal density is exactly p(z) = N(0, I_d). Everything
//! here acts on that z-space:
//!
//! - [`stats`]: binomial intervals (Clopper–Pearson, Wilson), the normal quantile, and the
//!   importance-sampling estimate of a failure probability ([`stats::ImportanceEstimate`]) with
//!   the ratio estimator for redrawn invalid samples and post-stratification.
//! - [`proposal`]: the defensive Gaussian-mixture proposal q(z), its exact density and
//!   likelihood ratio, sampling, and the weighted maximum-likelihood update; optional rotation
//!   blocks (4 dimensions whose direction is an orientation) carry an angular central Gaussian
//!   direction instead of a diagonal Gaussian ([`acg`]).
//! - [`ce`]: one stateless step of the multilevel cross-entropy method, its configuration, and
//!   an in-memory reference driver for cheap score functions (tests, benchmarks).
//! - [`splitting`]: subset simulation (adaptive multilevel splitting with a fixed conditional
//!   probability per level): levels on the continuous score, moves that keep the nominal
//!   conditioned on a level invariant (pCN, and small rotations on orientation blocks), the
//!   estimate with an interval that accounts for the chains' correlation, and an in-memory
//!   driver (not yet a sampler of `boxpose search`).
//! - [`tilt`]: which dimensions of z a cross-entropy proposal tilts, chosen by testing the
//!   first tuning iteration's elites against the nominal.
//! - [`rng`]: per-sample random generators, so sample `i`'s z depends only on its id.

pub mod acg;
pub mod ce;
mod ce_error;
pub mod proposal;
pub mod rng;
pub mod splitting;
pub mod stats;
pub mod tilt;

pub use ce::{
    CeConfig, CeError, CeRun, CeStep, Elites, ce_step, elites, run_in_memory,
    run_in_memory_auto_tilt, run_in_memory_from,
};
pub use proposal::{Component, Proposal, ProposalError, RotationShape, log_nominal};
pub use rng::sample_rng;
pub use splitting::{
    Candidate, Level, Particle, SplittingConfig, SplittingError, SplittingEstimate, SplittingRun,
    SplittingState, correlation_factor, propose_move,
};
pub use stats::{
    CiMethod, EstimateError, EstimatorKind, ImportanceEstimate, WeightedSample, clopper_pearson,
    mcnemar_exact, normal_cdf, normal_quantile, wilson,
};
pub use tilt::{DimensionTest, TiltChoice, choose_tilt, hold_at_nominal};
