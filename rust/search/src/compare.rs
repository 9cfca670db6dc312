//! Two Monte Carlo runs of one search on the same inputs, compared sample by sample: the paired
//! evaluation of a change to the pipeline (new networks, another fit). With common random numbers
//! (the same space, recipe and seed), sample i is the same scene in both runs, so each sample is a
//! pair (failed before, failed after); McNemar's exact test on the discordant pairs says whether
//! the failure rate moved, and the pairs name which scenes the change fixed and which it broke.

use serde::Serialize;

use crate::run::{Run, Sampler, differences};
use crate::{Result, SearchError};
use boxpose_search_stats::{clopper_pearson, mcnemar_exact};

/// A failure rate over the paired samples: failures of `samples`, with its 95 % Clopper–Pearson
/// interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rate {
    pub failures: u64,
    pub samples: u64,
    pub p_hat: f64,
    pub ci95: (f64, f64),
}

impl Rate {
    fn new(failures: u64, samples: u64) -> Self {
        Self {
            failures,
            samples,
            p_hat: if samples == 0 {
                0.0
            } else {
                failures as f64 / samples as f64
            },
            ci95: clopper_pearson(failures, samples, 0.95),
        }
    }
}

/// The paired comparison of two runs (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedComparison {
    /// Samples valid (settled and scored) in both runs: the pairs.
    pub pairs: u64,
    /// Samples of one run's sample ids that the other has not drawn yet or did not record as
    /// valid; not paired.
    pub unpaired: u64,
    pub before: Rate,
    pub after: Rate,
    /// Failed in both.
    pub failed_both: u64,
    /// Sample ids that failed before and not after.
    pub fixed: Vec<i64>,
    /// Sample ids that failed after and not before.
    pub new: Vec<i64>,
    /// McNemar's exact two-sided p-value of the discordant pairs.
    pub mcnemar_p: f64,
}

/// Pairs the samples of `before` and `after`, two Monte Carlo runs of one search (space, recipe,
/// seed, crops and predicate equal) that may differ in the networks, the fit and their length
/// (pairs are the sample ids both drew). Refuses runs that do not draw the same scenes, naming
/// what differs.
pub fn compare(before: &Run, after: &Run) -> Result<PairedComparison> {
    for run in [before, after] {
        if run.settings().sampler != Sampler::Mc {
            return Err(SearchError::Run {
                path: run.dir.clone(),
                problem: "a cross-entropy run draws from a proposal tuned on its own pipeline's \
                          failures, so its samples are not the other run's: compare Monte Carlo runs"
                    .into(),
            });
        }
    }
    // What the comparison is about may differ; everything that draws or judges a sample may not.
    // Sample i's inputs depend on (seed, iteration, i) only, so runs of other lengths or batch
    // sizes pair over the samples both drew.
    let mut as_before = after.record.clone();
    as_before.settings.samples = before.settings().samples;
    as_before.settings.batch_size = before.settings().batch_size;
    as_before.settings.ce.final_samples = before.settings().ce.final_samples;
    as_before.settings.model = before.settings().model.clone();
    as_before.settings.segmenter = before.settings().segmenter.clone();
    as_before.settings.fit = before.settings().fit.clone();
    if as_before != before.record {
        return Err(SearchError::Run {
            path: after.dir.clone(),
            problem: format!(
                "its samples are not {before}'s, so they cannot be paired (\"there\" is {before}, \
                 \"here\" this run: {}); run it with the same space, seed and settings, changing \
                 only --model, --segmenter, --fit or --samples",
                differences(&before.record, &as_before).join("; "),
                before = before.dir.display(),
            ),
        });
    }
    let (before_rows, _) = before.rows()?;
    let (after_rows, _) = after.rows()?;
    let after_by_id: std::collections::HashMap<i64, &crate::run::SampleRow> =
        after_rows.iter().map(|r| (r.sample_id, r)).collect();
    let (mut pairs, mut failed_before, mut failed_after, mut failed_both) = (0, 0, 0, 0);
    let (mut fixed, mut new) = (Vec::new(), Vec::new());
    for b in before_rows.iter().filter(|r| r.valid) {
        let Some(a) = after_by_id.get(&b.sample_id).filter(|a| a.valid) else {
            continue;
        };
        pairs += 1;
        failed_before += u64::from(b.failed);
        failed_after += u64::from(a.failed);
        match (b.failed, a.failed) {
            (true, true) => failed_both += 1,
            (true, false) => fixed.push(b.sample_id),
            (false, true) => new.push(b.sample_id),
            (false, false) => {}
        }
    }
    let valid = |rows: &[crate::run::SampleRow]| rows.iter().filter(|r| r.valid).count() as u64;
    Ok(PairedComparison {
        pairs,
        unpaired: valid(&before_rows) + valid(&after_rows) - 2 * pairs,
        before: Rate::new(failed_before, pairs),
        after: Rate::new(failed_after, pairs),
        failed_both,
        mcnemar_p: mcnemar_exact(fixed.len() as u64, new.len() as u64),
        fixed,
        new,
    })
}
