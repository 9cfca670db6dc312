//! What each iteration of a run does, what is left to do, and the progress a run reports.

use boxpose_search_stats::{CeStep, Proposal, SplittingState, TiltChoice};
use serde::{Deserialize, Serialize};

use super::SampleRow;

/// `--ce-tilt auto`: the tilted parameters are chosen from the nominal tuning iterations.
pub const AUTO_TILT: &str = "auto";

/// `--ce-tilt auto`'s family-wise level: with probability ≥ 99 % a parameter the failures do not
/// depend on stays at its nominal.
pub const AUTO_TILT_ALPHA: f64 = 0.01;

/// What iteration K does: its stage, its number of samples, the proposal it draws from.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IterationPlan {
    /// `mc`, `tune`, `final` or `split`.
    pub stage: String,
    pub samples: usize,
    /// The density the samples' log_proposal is of (subset simulation: the nominal, every
    /// weight 1; its samples come from [`IterationPlan::splitting`]).
    pub proposal: Proposal,
    /// Cross-entropy: the step that produced this proposal (none for iteration 0).
    pub step: Option<CeStep>,
    /// Subset simulation: the state whose candidates this iteration scores.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splitting: Option<SplittingState>,
    /// Cross-entropy with `--ce-tilt auto`: the last look's choice (made after iteration 0, and
    /// again after each later iteration while nothing is chosen), carried by every later plan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt: Option<TiltChoice>,
}

impl IterationPlan {
    /// Whether a barrier follows this iteration (cross-entropy tuning, every splitting step
    /// until the run ends), rather than it being the run's last.
    pub(super) fn has_barrier(&self) -> bool {
        self.stage == "tune" || self.stage == "split"
    }
}

/// Progress reports from a run; the CLI draws them (the library never prints).
pub trait Observer {
    /// Iteration `iteration` starts: `plan`, and how many of its samples are already done.
    /// Iteration `iteration` starts: its plan, and the samples of its batches already committed
    /// (by an earlier, interrupted run or by other shards).
    fn iteration(&mut self, _iteration: u32, _plan: &IterationPlan, _done: &[SampleRow]) {}
    /// A sample finished.
    fn sample(&mut self, _row: &SampleRow) {}
    /// This process waits for other shards' batches.
    fn waiting(&mut self, _what: &str) {}
}

/// What [`Run::pending`] finds: iteration `iteration`'s uncommitted batches (each
/// `batch_size` samples of its `samples`), or `complete` when none is left in the last one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PendingWork {
    pub iteration: u32,
    pub stage: String,
    pub samples: usize,
    pub batch_size: usize,
    pub batches: Vec<usize>,
    pub complete: bool,
}
