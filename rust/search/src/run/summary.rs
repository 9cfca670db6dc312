//! The failure-probability estimate, the warnings on its interval, and `summary.json`.

use std::collections::BTreeMap;
use std::sync::Arc;

use boxpose_data::schema::{SEARCH_SAMPLES, SEARCH_TIMINGS};
use boxpose_search_stats::{ImportanceEstimate, SplittingRun, TiltChoice, WeightedSample};
use serde::{Deserialize, Serialize};

use super::{Run, SampleRow, Sampler, TimingRow, samples_batch, timings_batch};
use crate::error::{Result, SearchError};
use crate::sut::{Crops, Predicate};

impl Run {
    /// The estimate from the samples the sampler's estimator uses: all of them for Monte Carlo,
    /// the final (frozen-proposal) batch for cross-entropy; subset simulation's levels.
    pub fn estimate(&self, rows: &[SampleRow]) -> Result<ImportanceEstimate> {
        if self.settings().sampler != Sampler::Splitting {
            return estimate(rows, self.settings().sampler, None);
        }
        let not_ready = |problem: &str| SearchError::Run {
            path: self.dir.clone(),
            problem: problem.into(),
        };
        let result = self
            .splitting_result()?
            .ok_or_else(|| not_ready("the subset simulation has not ended yet"))?;
        let first_stage_valid = rows.iter().filter(|r| r.iteration == 0 && r.valid).count();
        let valid = rows.iter().filter(|r| r.valid).count();
        result
            .importance_estimate(
                self.settings().samples,
                first_stage_valid as u64,
                valid as u64,
            )
            .ok_or_else(|| {
                not_ready(&format!(
                    "the subset simulation did not reach the failure level within {} stages \
                     (splitting.json has its levels): p is below about {:.1e}, or raise \
                     --splitting-max-levels",
                    result.levels.len(),
                    result
                        .levels
                        .iter()
                        .map(|l| l.conditional_probability)
                        .product::<f64>()
                ))
            })
    }

    /// Merges the batches into `samples.parquet` and `timings.parquet` and writes
    /// `summary.json`. Refuses an incomplete run.
    pub fn merge(&self) -> Result<Summary> {
        if !self.complete()? {
            return Err(SearchError::Run {
                path: self.dir.clone(),
                problem:
                    "not every batch is done yet: resume the search (same command) before merging"
                        .into(),
            });
        }
        let (samples, timings) = self.rows()?;
        boxpose_data::write_parquet(
            &self.dir.join("samples.parquet"),
            Arc::new(SEARCH_SAMPLES.arrow_schema()),
            &[samples_batch(&samples)],
        )?;
        boxpose_data::write_parquet(
            &self.dir.join("timings.parquet"),
            Arc::new(SEARCH_TIMINGS.arrow_schema()),
            &[timings_batch(&timings)],
        )?;
        let summary = self.summary(&samples, &timings)?;
        boxpose_data::write_file_atomically(
            &self.dir.join("summary.json"),
            &serde_json::to_vec_pretty(&summary).expect("a summary serialises"),
        )?;
        Ok(summary)
    }

    fn summary(&self, samples: &[SampleRow], timings: &[TimingRow]) -> Result<Summary> {
        let headline = self.estimate(samples)?;
        let splitting = self.splitting_result()?;
        let plans = self.plans()?;
        let mean = |f: fn(&TimingRow) -> f64| {
            if timings.is_empty() {
                0.0
            } else {
                timings.iter().map(f).sum::<f64>() / timings.len() as f64
            }
        };
        let s = self.settings();
        let ce_tilt = plans
            .iter()
            .rev()
            .find_map(|p| p.tilt.as_ref())
            .map(|choice| TiltSummary::new(choice, &self.record.dimensions));
        Ok(Summary {
            space: toml::from_str::<toml::Table>(&self.record.space_toml)
                .ok()
                .and_then(|t| t.get("name").and_then(|n| n.as_str()).map(String::from))
                .unwrap_or_default(),
            sampler: s.sampler,
            crops: s.crops,
            fit: s.fit.clone(),
            predicate: s.predicate,
            samples_spent: samples.len(),
            tuning_samples: samples.iter().filter(|r| r.stage == "tune").count(),
            ce_levels: plans
                .iter()
                .filter_map(|p| p.step.as_ref().map(|st| st.level))
                .collect(),
            failures_total: samples.iter().filter(|r| r.failed).count(),
            invalid_reasons: samples
                .iter()
                .filter_map(|r| r.invalid_reason.clone())
                .fold(BTreeMap::new(), |mut m, reason| {
                    let key = reason
                        .split(':')
                        .next()
                        .unwrap_or_default()
                        .trim()
                        .to_string();
                    *m.entry(if key.starts_with("target") {
                        "target not visible enough".to_string()
                    } else {
                        key
                    })
                    .or_insert(0usize) += 1;
                    m
                }),
            mean_seconds: StageMeans {
                settle: mean(|t| t.settle_s),
                render: mean(|t| t.render_s),
                inference: mean(|t| t.inference_s),
                fit: mean(|t| t.fit_s),
            },
            warnings: match &splitting {
                Some(run) => splitting_warnings(run, &headline),
                None => warnings(&headline),
            }
            .into_iter()
            .chain(system_errors_warning(samples))
            .chain(ce_tilt.as_ref().filter(|t| t.nothing_stood_out).map(
                |t| match t.held_at_nominal {
                    true => format!(
                        "--ce-tilt auto: no parameter's effect on the score showed in the {} \
                         valid nominal samples of the tuning iterations, so nothing was tilted \
                         and the estimate is plain Monte Carlo's",
                        t.samples
                    ),
                    false => format!(
                        "--ce-tilt auto: no parameter's effect on the score showed in the first \
                         iteration's {} valid samples, so every parameter was tilted",
                        t.samples
                    ),
                },
            ))
            .collect(),
            strata: match &splitting {
                Some(_) => vec![StratumSummary::whole(&headline)],
                None => self
                    .record
                    .strata
                    .iter()
                    .map(|&n| StratumSummary::new(samples, s.sampler, n, self.record.strata.len()))
                    .collect(),
            },
            estimate: headline,
            splitting: splitting.map(|run| SplittingSummary::new(&run)),
            ce_tilt,
            boxpose_version: env!("CARGO_PKG_VERSION").into(),
            mujoco_version: boxpose_physics::MUJOCO_VERSION.into(),
        })
    }
}

/// The estimate of P(fail | valid) from the rows a sampler's estimator uses (all of Monte
/// Carlo's; cross-entropy's final stage), optionally only those of stratum `neighbours`.
///
/// Always the ratio estimator Σ w 1{valid ∧ fail} / Σ w 1{valid}: a drawn scene can always turn
/// out invalid, so the nominal's normaliser P(valid) is unknown even when every drawn sample is
/// valid. Strata are allocated in proportion to their nominal probabilities and never tilted
/// (their weight is 1), so pooling the samples of every stratum estimates P(fail | valid) over
/// the whole space; each stratum's own estimate is in [`Summary::strata`]. Plain Monte Carlo
/// gets the exact Clopper–Pearson interval on (failures, valid samples).
pub fn estimate(
    rows: &[SampleRow],
    sampler: Sampler,
    neighbours: Option<u32>,
) -> Result<ImportanceEstimate> {
    if sampler == Sampler::Splitting {
        return Err(SearchError::Sample(
            "subset simulation's estimate is the product of its levels (`splitting.json`), \
             not a weighted mean of samples"
                .into(),
        ));
    }
    let stage = estimating_stage(sampler);
    let weighted: Vec<WeightedSample> = rows
        .iter()
        .filter(|r| r.stage == stage && neighbours.is_none_or(|n| r.stratum == n as i32))
        .map(|r| WeightedSample {
            log_weight: r.log_weight,
            valid: r.valid,
            failed: r.failed,
            stratum: 0,
        })
        .collect();
    let mut estimate = ImportanceEstimate::compute_ratio(&weighted, &[1.0])
        .map_err(|e| SearchError::Sample(format!("estimate: {e}")))?;
    // The strata are pooled into one ratio (they are allocated in proportion and never tilted):
    // the estimator's single pseudo-stratum repeats the totals, and each stratum's own estimate
    // is in `Summary::strata`.
    estimate.strata.clear();
    Ok(estimate)
}

/// The stage whose samples a sampler's estimator uses: all of Monte Carlo's, cross-entropy's
/// final (frozen-proposal) batch.
fn estimating_stage(sampler: Sampler) -> &'static str {
    match sampler {
        Sampler::Mc => "mc",
        Sampler::Ce => "final",
        Sampler::Splitting => "split",
    }
}

/// Effective failures below which an importance-sampling interval is flagged.
pub const MIN_FAILURE_ESS: f64 = 10.0;
/// Share of the estimate one failure may carry before the interval is flagged.
pub const MAX_WEIGHT_SHARE: f64 = 0.5;

/// Why an importance-sampling interval may under-cover: a Wald interval rests on the failures'
/// weights being many and comparable, and the diagnostics say when they are not (Owen, *Monte
/// Carlo*, §9.3). Monte Carlo's exact interval needs no such warning.
pub fn warnings(e: &ImportanceEstimate) -> Vec<String> {
    let mut out = Vec::new();
    if e.ci_method == boxpose_search_stats::CiMethod::ClopperPearson {
        return out;
    }
    if e.failures == 0 {
        out.push(format!(
            "no failure among the {} weighted samples of the estimate: importance sampling gives no interval, and p̂ = 0 does not show that failures are rare (the proposal may never have reached them); run Monte Carlo or subset simulation for a bound",
            e.samples
        ));
    }
    if e.failures > 0 && e.failure_ess < MIN_FAILURE_ESS {
        out.push(format!(
            "only {:.1} effective failures (of {}): the weights are too uneven for the interval to be trusted; tilt fewer parameters (--ce-tilt), add components, or draw more samples",
            e.failure_ess, e.failures
        ));
    }
    if e.max_weight_share > MAX_WEIGHT_SHARE {
        out.push(format!(
            "one failure carries {:.0}% of the estimate",
            100.0 * e.max_weight_share
        ));
    }
    out
}

/// Samples an external system under test did not answer (crashed, timed out, broke the
/// protocol): not scored, so p̂ holds only the samples it answered — if its errors come with hard
/// inputs, p̂ is too low.
fn system_errors_warning(samples: &[SampleRow]) -> Option<String> {
    let errors = samples
        .iter()
        .filter(|r| {
            r.invalid_reason
                .as_deref()
                .is_some_and(|reason| reason.starts_with("system under test"))
        })
        .count();
    (errors > 0).then(|| {
        format!(
            "the system under test did not answer {errors} of {} samples (crash, timeout or a broken answer; see invalid_reason): they are not scored, so p̂ is over the samples it answered",
            samples.len()
        )
    })
}

/// Why a subset simulation's interval may not be trusted: few lineages behind the final
/// failures (the interval then rests on few independent clusters), chains that hardly moved,
/// invalid first-stage samples (P̂(valid)'s own error is not in the interval).
pub fn splitting_warnings(run: &SplittingRun, e: &ImportanceEstimate) -> Vec<String> {
    let mut out = Vec::new();
    if run.distinct_ancestors < MIN_SPLITTING_LINEAGES {
        out.push(format!(
            "the final failures descend from {} first-stage sample(s): the interval rests on few \
             independent lineages; more particles (--samples) give more",
            run.distinct_ancestors
        ));
    }
    for (i, level) in run.levels.iter().enumerate() {
        if let Some(rate) = level
            .acceptance_rate
            .filter(|&r| r < MIN_SPLITTING_ACCEPTANCE)
        {
            out.push(format!(
                "stage {i} accepted {:.1}% of its moves: its chains hardly moved",
                100.0 * rate
            ));
        }
    }
    if e.p_valid < 1.0 {
        out.push(format!(
            "{:.1}% of the first stage's samples were invalid: p̂ is P(fail ∧ valid)/P̂(valid), \
             and the interval leaves P̂(valid)'s own error out",
            100.0 * (1.0 - e.p_valid)
        ));
    }
    out
}

/// Lineages (distinct first-stage ancestors of the final failures) below which a splitting
/// interval is flagged.
pub const MIN_SPLITTING_LINEAGES: usize = 5;
/// Move acceptance below which a splitting stage is flagged.
pub const MIN_SPLITTING_ACCEPTANCE: f64 = 0.05;

/// A subset simulation's diagnostics in `summary.json`: per stage its level, conditional
/// probability, correlation factor and acceptance, and the lineages of the final failures.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SplittingSummary {
    pub reached: bool,
    pub levels: Vec<SplittingLevelSummary>,
    /// The estimate of P(score > 0) with both coefficients of variation.
    pub estimate: Option<boxpose_search_stats::SplittingEstimate>,
    pub evaluations: u64,
    /// Distinct first-stage ancestors of the final failures.
    pub distinct_ancestors: usize,
}

/// One stage of [`SplittingSummary`] (the ρ of each of its steps are in `splitting.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SplittingLevelSummary {
    /// The level b_i ranked from the stage's particles (the last: 0, failure), in score units
    /// (log10 of the metric over its threshold).
    pub threshold: f64,
    pub conditional_probability: f64,
    pub correlation_factor: f64,
    pub chains: usize,
    pub acceptance_rate: Option<f64>,
    pub evaluations: u64,
}

impl SplittingSummary {
    fn new(run: &SplittingRun) -> Self {
        Self {
            reached: run.reached,
            levels: run
                .levels
                .iter()
                .map(|l| SplittingLevelSummary {
                    threshold: l.threshold,
                    conditional_probability: l.conditional_probability,
                    correlation_factor: l.correlation_factor,
                    chains: l.chains,
                    acceptance_rate: l.acceptance_rate,
                    evaluations: l.evaluations,
                })
                .collect(),
            estimate: run.estimate.clone(),
            evaluations: run.evaluations,
            distinct_ancestors: run.distinct_ancestors,
        }
    }
}

/// One stratum's own estimate of P(fail | valid), from the samples the headline estimate uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StratumSummary {
    /// Number of neighbouring boxes.
    pub neighbours: u32,
    /// Its nominal probability (every stratum has the same).
    pub nominal_probability: f64,
    /// Samples drawn in it (valid or not), valid ones and valid failing ones.
    pub samples: u64,
    pub valid: u64,
    pub failures: u64,
    /// P(fail | valid) in it, its standard error and 95% interval (as for the headline); none
    /// when it has no valid sample.
    pub p_hat: Option<f64>,
    pub std_error: Option<f64>,
    pub ci95: Option<(f64, f64)>,
}

impl StratumSummary {
    /// The only stratum of a run whose estimate is `e` (subset simulation draws from one).
    fn whole(e: &ImportanceEstimate) -> Self {
        Self {
            neighbours: 0,
            nominal_probability: 1.0,
            samples: e.samples,
            valid: e.valid,
            failures: e.failures,
            p_hat: Some(e.p_hat),
            std_error: Some(e.std_error),
            ci95: e.ci95,
        }
    }

    /// Stratum `neighbours`, one of `strata` strata, from the rows of the sampler's estimating
    /// stage.
    fn new(samples: &[SampleRow], sampler: Sampler, neighbours: u32, strata: usize) -> Self {
        let stage = estimating_stage(sampler);
        let rows: Vec<&SampleRow> = samples
            .iter()
            .filter(|r| r.stage == stage && r.stratum == neighbours as i32)
            .collect();
        let estimate = estimate(samples, sampler, Some(neighbours)).ok();
        Self {
            neighbours,
            nominal_probability: 1.0 / strata as f64,
            samples: rows.len() as u64,
            valid: rows.iter().filter(|r| r.valid).count() as u64,
            failures: rows.iter().filter(|r| r.valid && r.failed).count() as u64,
            p_hat: estimate.as_ref().map(|e| e.p_hat),
            std_error: estimate.as_ref().map(|e| e.std_error),
            ci95: estimate.and_then(|e| e.ci95),
        }
    }
}

/// Mean seconds per sample in each stage.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct StageMeans {
    pub settle: f64,
    pub render: f64,
    pub inference: f64,
    pub fit: f64,
}

/// `--ce-tilt auto`: what the nominal tuning iterations' scores chose (the last look).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TiltSummary {
    /// Valid nominal samples the tests were made on.
    pub samples: usize,
    /// The level of the look; each test is held to it / the number of tests.
    pub alpha: f64,
    /// No parameter passed its test.
    pub nothing_stood_out: bool,
    /// When nothing stood out: `true`, nothing was tilted (the final batch is Monte Carlo);
    /// `false` (runs begun before 2026-12-06), every parameter was.
    #[serde(default)]
    pub held_at_nominal: bool,
    /// Every parameter in z's order (an orientation block once, by its name without `.q0`).
    pub tests: Vec<TiltTest>,
}

/// One parameter's test of "the failures do not depend on it".
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TiltTest {
    pub parameter: String,
    pub p_value: f64,
    pub tilted: bool,
}

impl TiltSummary {
    fn new(choice: &TiltChoice, dimensions: &[String]) -> Self {
        Self {
            samples: choice.samples,
            alpha: choice.alpha,
            nothing_stood_out: choice.is_empty(),
            held_at_nominal: choice.undecided(),
            tests: choice
                .tests
                .iter()
                .map(|t| TiltTest {
                    parameter: match t.len {
                        1 => dimensions[t.start].clone(),
                        _ => dimensions[t.start].trim_end_matches(".q0").to_string(),
                    },
                    p_value: t.p_value,
                    tilted: t.tilted,
                })
                .collect(),
        }
    }

    /// The tilted parameters' names.
    pub fn tilted(&self) -> Vec<&str> {
        self.tests
            .iter()
            .filter(|t| t.tilted || (self.nothing_stood_out && !self.held_at_nominal))
            .map(|t| t.parameter.as_str())
            .collect()
    }
}

/// `summary.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    pub space: String,
    pub sampler: Sampler,
    pub crops: Crops,
    pub fit: String,
    pub predicate: Predicate,
    /// Every sample drawn, tuning included: the budget to compare samplers by.
    pub samples_spent: usize,
    pub tuning_samples: usize,
    /// Cross-entropy: the level reached at each tuning iteration (failure at 0).
    pub ce_levels: Vec<f64>,
    /// Failing samples in all stages (each one is a counterexample).
    pub failures_total: usize,
    /// Invalid samples by reason (all stages).
    pub invalid_reasons: BTreeMap<String, usize>,
    pub mean_seconds: StageMeans,
    /// P(fail | valid) with its 95% interval, from the estimating stage.
    pub estimate: ImportanceEstimate,
    /// The same per stratum (number of neighbours; one stratum of 0 without neighbours).
    pub strata: Vec<StratumSummary>,
    /// Why the interval may not be trusted (see [`warnings`], [`splitting_warnings`]); empty
    /// when nothing stands out.
    pub warnings: Vec<String>,
    /// Subset simulation's levels and diagnostics.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splitting: Option<SplittingSummary>,
    /// `--ce-tilt auto`: the parameters tested and tilted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ce_tilt: Option<TiltSummary>,
    pub boxpose_version: String,
    pub mujoco_version: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(log_weight: f64, failed: bool) -> WeightedSample {
        WeightedSample {
            log_weight,
            valid: true,
            failed,
            stratum: 0,
        }
    }

    #[test]
    fn uneven_failure_weights_are_flagged_and_monte_carlo_is_not() {
        // one failure with a weight 50× the others' carries most of the estimate
        let mut uneven: Vec<WeightedSample> = (0..200).map(|i| sample(-2.0, i < 3)).collect();
        uneven.push(sample(50f64.ln() - 2.0, true));
        let e = ImportanceEstimate::compute_ratio(&uneven, &[1.0]).unwrap();
        let w = warnings(&e);
        assert!(w.iter().any(|m| m.contains("effective failures")), "{w:?}");
        assert!(w.iter().any(|m| m.contains("of the estimate")), "{w:?}");
        // many comparable weights: nothing to flag
        let even: Vec<WeightedSample> = (0..400)
            .map(|i| sample(-1.0 + 0.01 * (i % 7) as f64, i % 20 == 0))
            .collect();
        assert!(warnings(&ImportanceEstimate::compute_ratio(&even, &[1.0]).unwrap()).is_empty());
        // weighted samples without a failure: no interval, which is said
        let none: Vec<WeightedSample> = (0..100)
            .map(|i| sample(-0.5 + 0.01 * i as f64, false))
            .collect();
        let w = warnings(&ImportanceEstimate::compute_ratio(&none, &[1.0]).unwrap());
        assert!(w.iter().any(|m| m.contains("no failure")), "{w:?}");
        // Monte Carlo's exact interval needs no warning, however few the failures
        let mc: Vec<WeightedSample> = (0..100).map(|i| sample(0.0, i == 0)).collect();
        assert!(warnings(&ImportanceEstimate::compute_ratio(&mc, &[1.0]).unwrap()).is_empty());
    }
}
