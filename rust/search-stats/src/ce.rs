//! The multilevel cross-entropy method (Rubinstein–Kroese; O'Kelly et al., NeurIPS 2018) on the
//! search's z-space.

use serde::{Deserialize, Serialize};

pub use crate::ce_error::CeError;
use crate::proposal::{Proposal, log_nominal};
use crate::rng::sample_rng;
use crate::stats::{ImportanceEstimate, WeightedSample};
use crate::tilt::{TiltChoice, choose_tilt, hold_at_nominal};

/// The `iteration` that [`run_in_memory`] gives [`sample_rng`] for the final batch.
pub const FINAL_ITERATION: u32 = u32::MAX;

/// Settings of a cross-entropy search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CeConfig {
    /// Samples drawn per tuning iteration (N); ≥ 2 and large enough that (1 − ρ)N ≥ 1.
    pub samples_per_iteration: usize,
    /// Most tuning iterations (≥ 1); tuning stops earlier once the failure level is reached.
    pub max_iterations: u32,
    /// Elite quantile ρ ∈ (0, 1): the top (1 − ρ) fraction of scores are elites (e.g. 0.9).
    pub rho: f64,
    /// Smoothing α ∈ (0, 1] of the update θ_new = α θ_fit + (1 − α) θ_old.
    pub alpha: f64,
    /// Defensive weight λ ∈ [0, 1] of the nominal in the frozen final proposal (e.g. 0.1–0.2);
    /// the final weights are then bounded by 1/λ.
    pub defensive_lambda: f64,
    /// Fresh samples drawn from the frozen proposal for the estimate (≥ 1).
    pub final_samples: usize,
    /// Mixture components K ≥ 1 of the proposal.
    pub components: usize,
    /// Floor on every fitted standard deviation (> 0). Above 1/√2 (default 0.75) the
    /// likelihood ratio of each component has finite variance even without the defensive
    /// nominal; a diagonal Gaussian fitted to a failure set that is not axis-aligned otherwise
    /// shrinks some σ below it and gives heavy-tailed weights and under-covering intervals.
    pub min_std: f64,
}

impl Default for CeConfig {
    fn default() -> Self {
        Self {
            samples_per_iteration: 1000,
            max_iterations: 20,
            rho: 0.9,
            alpha: 0.9,
            defensive_lambda: 0.1,
            final_samples: 2000,
            components: 1,
            min_std: 0.75,
        }
    }
}

fn bad(key: &'static str, message: impl Into<String>) -> CeError {
    CeError::Config {
        key,
        message: message.into(),
    }
}

impl CeConfig {
    /// Checks every value; the error names the first bad key.
    pub fn validate(&self) -> Result<(), CeError> {
        if self.samples_per_iteration < 2 {
            return Err(bad("samples_per_iteration", "must be at least 2"));
        }
        if !(self.rho > 0.0 && self.rho < 1.0) {
            return Err(bad("rho", format!("{} is not in (0, 1)", self.rho)));
        }
        if ((1.0 - self.rho) * self.samples_per_iteration as f64) < 1.0 {
            return Err(bad(
                "samples_per_iteration",
                format!(
                    "{} samples leave no elite at rho = {}",
                    self.samples_per_iteration, self.rho
                ),
            ));
        }
        if self.max_iterations < 1 {
            return Err(bad("max_iterations", "must be at least 1"));
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(bad("alpha", format!("{} is not in (0, 1]", self.alpha)));
        }
        if !(0.0..=1.0).contains(&self.defensive_lambda) {
            return Err(bad(
                "defensive_lambda",
                format!("{} is not in [0, 1]", self.defensive_lambda),
            ));
        }
        if self.final_samples < 1 {
            return Err(bad("final_samples", "must be at least 1"));
        }
        if self.components < 1 {
            return Err(bad("components", "must be at least 1"));
        }
        if !(self.min_std.is_finite() && self.min_std > 0.0) {
            return Err(bad("min_std", format!("{} must be > 0", self.min_std)));
        }
        Ok(())
    }
}

/// The result of one cross-entropy step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CeStep {
    /// The updated proposal (same λ and K as the current one).
    pub next: Proposal,
    /// The level used: min(γ, ρ-quantile of the finite scores).
    pub level: f64,
    /// The ρ-quantile of the finite scores.
    pub quantile: f64,
    /// Whether the ρ-quantile reached the failure level γ.
    pub reached: bool,
    /// Number of elites (finite scores ≥ `level`).
    pub elites: usize,
}

/// One multilevel cross-entropy step, stateless so the caller can checkpoint between
/// iterations.
///
/// `zs` were drawn from `current`; `scores[i]` is sample i's score (larger = closer to
/// failure, failure ⇔ score ≥ γ = `failure_level`; NaN marks an invalid sample, which is never
/// an elite). The ρ-quantile q is the ⌊ρ n⌋-th smallest of the n finite scores (0-based,
/// clamped), ρ = `config.rho`; the level is min(γ, q), and the elites are the samples with
/// score ≥ level. The next proposal is the weighted MLE ([`Proposal::fit_floored`], smoothing
/// α = `config.alpha`, σ floor `config.min_std`) on the elites with self-normalised
/// likelihood-ratio weights w_i ∝ p(z_i)/q_current(z_i). Only `rho`, `alpha` and `min_std` of
/// `config` are read (and checked).
pub fn ce_step(
    current: &Proposal,
    zs: &[Vec<f64>],
    scores: &[f64],
    failure_level: f64,
    config: &CeConfig,
) -> Result<CeStep, CeError> {
    let (rho, alpha) = (config.rho, config.alpha);
    if zs.len() != scores.len() {
        return Err(CeError::Input(format!(
            "{} samples but {} scores",
            zs.len(),
            scores.len()
        )));
    }
    if !(rho > 0.0 && rho < 1.0) {
        return Err(bad("rho", format!("{rho} is not in (0, 1)")));
    }
    if !(alpha > 0.0 && alpha <= 1.0) {
        return Err(bad("alpha", format!("{alpha} is not in (0, 1]")));
    }
    if !(config.min_std.is_finite() && config.min_std > 0.0) {
        return Err(bad("min_std", format!("{} must be > 0", config.min_std)));
    }
    let Elites {
        quantile,
        level,
        indices: elite,
    } = elites(scores, rho, failure_level)?;
    let log_w: Vec<f64> = elite
        .iter()
        .map(|&i| log_nominal(&zs[i]) - current.log_density(&zs[i]))
        .collect();
    let max = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let weights: Vec<f64> = log_w.iter().map(|l| (l - max).exp()).collect();
    let elite_zs: Vec<Vec<f64>> = elite.iter().map(|&i| zs[i].clone()).collect();
    let next = current.fit_floored(&elite_zs, &weights, alpha, config.min_std)?;
    Ok(CeStep {
        next,
        level,
        quantile,
        reached: quantile >= failure_level,
        elites: elite.len(),
    })
}

/// The elites of one tuning iteration (see [`ce_step`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Elites {
    /// The ρ-quantile of the finite scores.
    pub quantile: f64,
    /// min(γ, quantile).
    pub level: f64,
    /// The samples with a finite score ≥ `level`, in order.
    pub indices: Vec<usize>,
}

/// The elites of `scores` at quantile `rho` and failure level γ = `failure_level`: the ρ-quantile
/// q is the ⌊ρ n⌋-th smallest of the n finite scores (0-based, clamped), the level min(γ, q);
/// NaN scores (invalid samples) are never elites.
pub fn elites(scores: &[f64], rho: f64, failure_level: f64) -> Result<Elites, CeError> {
    let mut finite: Vec<f64> = scores.iter().copied().filter(|s| !s.is_nan()).collect();
    if finite.is_empty() {
        return Err(CeError::Input("no finite score".into()));
    }
    finite.sort_by(f64::total_cmp);
    let index = ((rho * finite.len() as f64).floor() as usize).min(finite.len() - 1);
    let quantile = finite[index];
    let level = quantile.min(failure_level);
    let indices = (0..scores.len())
        .filter(|&i| !scores[i].is_nan() && scores[i] >= level)
        .collect();
    Ok(Elites {
        quantile,
        level,
        indices,
    })
}

/// The outcome of [`run_in_memory`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CeRun {
    /// The levels of the tuning iterations, in order.
    pub levels: Vec<f64>,
    /// Whether tuning reached the failure level.
    pub reached: bool,
    /// Score evaluations spent on tuning (charged to cross-entropy).
    pub tuning_evaluations: u64,
    /// The frozen defensive proposal the final batch was drawn from.
    pub final_proposal: Proposal,
    /// The estimate from the final batch alone.
    pub estimate: ImportanceEstimate,
}

/// Reference driver for cheap score functions (tests, benchmarks): the whole pipeline in one
/// process.
///
/// Tuning starts from [`Proposal::tuning_start`] (λ = 0, K = `config.components`), and each
/// iteration `it` draws sample `i` with [`sample_rng`]`(seed, it, i)`, scores it and applies
/// [`ce_step`], until the failure level is reached (that iteration's update included) or
/// `max_iterations` are spent. The last proposal is frozen, mixed with the nominal at
/// λ = `defensive_lambda`, and a fresh batch of `final_samples` (iteration
/// [`FINAL_ITERATION`]) gives the unbiased estimate of P(score ≥ γ | valid); a NaN score marks
/// an invalid sample.
pub fn run_in_memory(
    config: &CeConfig,
    dim: usize,
    seed: u64,
    failure_level: f64,
    score: impl Fn(&[f64]) -> f64,
) -> Result<CeRun, CeError> {
    let start = Proposal::tuning_start(dim, config.components);
    run_in_memory_from(config, &start, seed, failure_level, score)
}

/// [`run_in_memory`] tuning from `start` instead of [`Proposal::tuning_start`], e.g. with
/// rotation blocks: `Proposal::tuning_start(dim, config.components).with_rotation_blocks(&[0])?`.
/// `config.components` is not read here (the start's components are used).
pub fn run_in_memory_from(
    config: &CeConfig,
    start: &Proposal,
    seed: u64,
    failure_level: f64,
    score: impl Fn(&[f64]) -> f64,
) -> Result<CeRun, CeError> {
    config.validate()?;
    tune_then_estimate(
        config,
        start.clone(),
        seed,
        failure_level,
        &score,
        None,
        None,
    )
}

/// [`run_in_memory`] with the tilted dimensions chosen from data, as `boxpose search --ce-tilt
/// auto` does: the tuning iterations draw from the nominal until [`choose_tilt`], repeated on
/// every nominal sample so far at level `tilt_alpha / config.max_iterations` per look
/// (`rotation_blocks`: the orientation blocks' starts), finds a dimension the scores depend on;
/// from then on every proposal holds the untilted dimensions at their nominal
/// ([`hold_at_nominal`]) and the chosen orientation blocks get angular central Gaussians. When
/// no look finds one, the final batch is drawn from the nominal: plain Monte Carlo.
pub fn run_in_memory_auto_tilt(
    config: &CeConfig,
    dim: usize,
    rotation_blocks: &[usize],
    seed: u64,
    failure_level: f64,
    tilt_alpha: f64,
    score: impl Fn(&[f64]) -> f64,
) -> Result<(CeRun, TiltChoice), CeError> {
    config.validate()?;
    let nominal = Proposal::tuning_start(dim, config.components);
    let look_alpha = tilt_alpha / config.max_iterations as f64;
    let (mut zs, mut scores) = (Vec::new(), Vec::new());
    let mut iteration = 0;
    let choice = loop {
        let batch = draw(&nominal, seed, iteration, config.samples_per_iteration);
        scores.extend(batch.iter().map(|z| score(z)));
        zs.extend(batch);
        let choice = choose_tilt(&zs, &scores, dim, rotation_blocks, look_alpha)?;
        let last = iteration + 1 == config.max_iterations
            || ce_step(&nominal, &zs, &scores, failure_level, config)?.reached;
        if !choice.undecided() || last {
            break choice;
        }
        iteration += 1;
    };
    let mask = choice.mask(dim);
    let start = nominal.with_rotation_blocks(&choice.tilted_blocks())?;
    let run = tune_then_estimate(
        config,
        start,
        seed,
        failure_level,
        &score,
        Some(&mask),
        Some((iteration, zs, scores)),
    )?;
    Ok((run, choice))
}

fn draw(proposal: &Proposal, seed: u64, iteration: u32, n: usize) -> Vec<Vec<f64>> {
    (0..n as u64)
        .map(|i| proposal.sample(&mut sample_rng(seed, iteration, i)))
        .collect()
}

/// The tuning iterations from `proposal`, each fitted proposal held at the nominal outside
/// `mask`, then the final batch and its estimate. `first` = (iteration, samples, scores): the
/// samples already drawn from `proposal`'s density that the step of that iteration fits on
/// (tuning then goes on from there); without it tuning starts at iteration 0.
fn tune_then_estimate(
    config: &CeConfig,
    mut proposal: Proposal,
    seed: u64,
    failure_level: f64,
    score: &dyn Fn(&[f64]) -> f64,
    mask: Option<&[bool]>,
    first: Option<(u32, Vec<Vec<f64>>, Vec<f64>)>,
) -> Result<CeRun, CeError> {
    let mut levels = Vec::new();
    let mut reached = false;
    let mut tuning_evaluations = 0u64;
    let (start, mut first) = match first {
        Some((iteration, zs, scores)) => (iteration, Some((zs, scores))),
        None => (0, None),
    };
    for it in start..config.max_iterations {
        let (zs, scores) = first.take().unwrap_or_else(|| {
            let zs = draw(&proposal, seed, it, config.samples_per_iteration);
            let scores = zs.iter().map(|z| score(z)).collect();
            (zs, scores)
        });
        tuning_evaluations += zs.len() as u64;
        let step = ce_step(&proposal, &zs, &scores, failure_level, config)?;
        proposal = match mask {
            Some(mask) => hold_at_nominal(step.next, mask),
            None => step.next,
        };
        levels.push(step.level);
        if step.reached {
            reached = true;
            break;
        }
    }
    let final_proposal = proposal.with_defensive(config.defensive_lambda);
    let samples: Vec<WeightedSample> = (0..config.final_samples as u64)
        .map(|i| {
            let z = final_proposal.sample(&mut sample_rng(seed, FINAL_ITERATION, i));
            let s = score(&z);
            WeightedSample {
                log_weight: final_proposal.log_weight(&z),
                valid: !s.is_nan(),
                failed: s >= failure_level,
                stratum: 0,
            }
        })
        .collect();
    let estimate = ImportanceEstimate::compute(&samples, &[1.0])?;
    Ok(CeRun {
        levels,
        reached,
        tuning_evaluations,
        final_proposal,
        estimate,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_errors_name_the_key() {
        let ok = CeConfig::default();
        assert!(ok.validate().is_ok());
        let cases: [(CeConfig, &str); 7] = [
            (
                CeConfig {
                    min_std: 0.0,
                    ..ok.clone()
                },
                "min_std",
            ),
            (
                CeConfig {
                    rho: 1.0,
                    ..ok.clone()
                },
                "rho",
            ),
            (
                CeConfig {
                    alpha: 0.0,
                    ..ok.clone()
                },
                "alpha",
            ),
            (
                CeConfig {
                    defensive_lambda: -0.1,
                    ..ok.clone()
                },
                "defensive_lambda",
            ),
            (
                CeConfig {
                    samples_per_iteration: 5,
                    ..ok.clone()
                },
                "samples_per_iteration",
            ),
            (
                CeConfig {
                    components: 0,
                    ..ok.clone()
                },
                "components",
            ),
            (
                CeConfig {
                    final_samples: 0,
                    ..ok.clone()
                },
                "final_samples",
            ),
        ];
        for (config, key) in cases {
            match config.validate() {
                Err(CeError::Config { key: k, .. }) => assert_eq!(k, key),
                other => panic!("{key}: expected a config error, got {other:?}"),
            }
        }
        let json = r#"{"samples_per_iteration":10,"max_iterations":1,"rho":0.9,"alpha":1,
            "defensive_lambda":0.1,"final_samples":1,"components":1,"min_std":0.75,"bogus":1}"#;
        assert!(
            serde_json::from_str::<CeConfig>(json)
                .unwrap_err()
                .to_string()
                .contains("bogus")
        );
    }

    #[test]
    fn step_level_and_elites() {
        let p = Proposal::tuning_start(1, 1);
        let zs: Vec<Vec<f64>> = (0..10).map(|i| vec![i as f64]).collect();
        let mut scores: Vec<f64> = (0..10).map(|i| i as f64).collect();
        scores[0] = f64::NAN;
        // 9 finite scores 1..9, ⌊0.8·9⌋ = 7 → quantile 8
        let config = CeConfig {
            rho: 0.8,
            alpha: 1.0,
            min_std: 0.01,
            ..CeConfig::default()
        };
        let s = ce_step(&p, &zs, &scores, 100.0, &config).unwrap();
        assert_eq!(
            (s.quantile, s.level, s.reached, s.elites),
            (8.0, 8.0, false, 2)
        );
        assert!((s.next.components[0].mean[0] - 8.5).abs() < 0.05);
        let s = ce_step(&p, &zs, &scores, 5.0, &config).unwrap();
        assert_eq!((s.level, s.reached, s.elites), (5.0, true, 5));
    }
}
