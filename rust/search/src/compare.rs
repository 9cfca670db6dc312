//! Two Monte Carlo runs of one search on the same inputs, compared sample by sample, or two
//! `boxpose eval` tables of one dataset, box by box: the paired evaluation of a change to the
//! pipeline (new networks, another fit). With common random numbers
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

/// The paired comparison of two runs (see the module documentation); `K` names a pair (a search
/// sample's id, or a box of an evaluated dataset).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedComparison<K = i64> {
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
    pub fixed: Vec<K>,
    /// Sample ids that failed after and not before.
    pub new: Vec<K>,
    /// McNemar's exact two-sided p-value of the discordant pairs.
    pub mcnemar_p: f64,
}

/// Pairs two runs' outcomes (each a key and whether it failed; keys are unique within a run):
/// the keys in both are the pairs.
pub fn pair<K: Eq + std::hash::Hash + Clone>(
    before: &[(K, bool)],
    after: &[(K, bool)],
) -> PairedComparison<K> {
    let after_by_key: std::collections::HashMap<&K, bool> =
        after.iter().map(|(k, failed)| (k, *failed)).collect();
    let (mut pairs, mut failed_before, mut failed_after, mut failed_both) = (0, 0, 0, 0);
    let (mut fixed, mut new) = (Vec::new(), Vec::new());
    for (key, b) in before {
        let Some(&a) = after_by_key.get(key) else {
            continue;
        };
        pairs += 1;
        failed_before += u64::from(*b);
        failed_after += u64::from(a);
        match (*b, a) {
            (true, true) => failed_both += 1,
            (true, false) => fixed.push(key.clone()),
            (false, true) => new.push(key.clone()),
            (false, false) => {}
        }
    }
    PairedComparison {
        pairs,
        unpaired: (before.len() + after.len()) as u64 - 2 * pairs,
        before: Rate::new(failed_before, pairs),
        after: Rate::new(failed_after, pairs),
        failed_both,
        mcnemar_p: mcnemar_exact(fixed.len() as u64, new.len() as u64),
        fixed,
        new,
    }
}

/// Pairs the samples of `before` and `after`, two Monte Carlo runs of one search (space, recipe,
/// seed, crops and predicate equal) that may differ in the networks, the fit, the depth the
/// perception reads (`--refine-depth`, `--sensor-depth`), how the frames are rendered
/// (`--whole-frames`) and their length (pairs are the sample ids both drew). Refuses runs that do
/// not draw the same scenes, naming what differs.
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
    // the same scenes, rendered or perceived otherwise
    as_before.settings.whole_frames = before.settings().whole_frames;
    as_before.settings.two_resolutions = before.settings().two_resolutions;
    as_before.settings.refine_depth = before.settings().refine_depth;
    as_before.settings.sensor_depth = before.settings().sensor_depth;
    if as_before != before.record {
        return Err(SearchError::Run {
            path: after.dir.clone(),
            problem: format!(
                "its samples are not {before}'s, so they cannot be paired (\"there\" is {before}, \
                 \"here\" this run: {}); run it with the same space, seed and settings, changing \
                 only --model, --segmenter, --fit, --refine-depth, --sensor-depth, --whole-frames or \
                 --samples",
                differences(&before.record, &as_before).join("; "),
                before = before.dir.display(),
            ),
        });
    }
    let outcomes = |run: &Run| -> Result<Vec<(i64, bool)>> {
        let (rows, _) = run.rows()?;
        Ok(rows
            .iter()
            .filter(|r| r.valid)
            .map(|r| (r.sample_id, r.failed))
            .collect())
    };
    Ok(pair(&outcomes(before)?, &outcomes(after)?))
}

/// A box of an evaluated dataset: (scene_id, frame_id, object_id).
pub type BoxKey = (i64, i32, i32);

/// Each box of a `boxpose eval` table (`eval.parquet`) and whether `method`'s fit failed it: its
/// cube-group corner MSSD not below `fraction` × its diameter, or no pose (not found, not fitted).
/// Only the six columns this needs are read (and checked), so that a table written before
/// `margin_nats` was null where no other hypothesis exists (it was +∞, which the dataset reader's
/// finite-values check refuses) is still read.
pub fn eval_outcomes(
    path: &std::path::Path,
    method: &str,
    fraction: f64,
) -> Result<Vec<(BoxKey, bool)>> {
    use boxpose_data::arrow::array::{Array, AsArray, RecordBatch};
    use boxpose_data::arrow::datatypes::{Float64Type, Int32Type, Int64Type};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let bad = |message: String| SearchError::Io {
        path: path.to_path_buf(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .and_then(|b| b.build())
        .map_err(|e| bad(format!("not a Parquet table: {e}")))?;
    let mut outcomes = Vec::new();
    let mut methods = std::collections::BTreeSet::new();
    for batch in reader {
        let batch: RecordBatch = batch.map_err(|e| bad(e.to_string()))?;
        let column = |name: &str| {
            batch
                .column_by_name(name)
                .cloned()
                .ok_or_else(|| bad(format!("no column {name}: not an `eval` table")))
        };
        let (scene, frame, object) = (
            column("scene_id")?,
            column("frame_id")?,
            column("object_id")?,
        );
        let (method_column, diameter, cube) = (
            column("method")?,
            column("diameter_m")?,
            column("cube_mssd_m")?,
        );
        let mistyped = || bad("a column of another type than `boxpose eval` writes".into());
        let scene = scene.as_primitive_opt::<Int64Type>().ok_or_else(mistyped)?;
        let frame = frame.as_primitive_opt::<Int32Type>().ok_or_else(mistyped)?;
        let object = object
            .as_primitive_opt::<Int32Type>()
            .ok_or_else(mistyped)?;
        let method_of = method_column.as_string_opt::<i32>().ok_or_else(mistyped)?;
        let diameter = diameter
            .as_primitive_opt::<Float64Type>()
            .ok_or_else(mistyped)?;
        let cube = cube
            .as_primitive_opt::<Float64Type>()
            .ok_or_else(mistyped)?;
        for i in 0..batch.num_rows() {
            methods.insert(method_of.value(i).to_string());
            if method_of.value(i) != method {
                continue;
            }
            let succeeded = cube.is_valid(i) && cube.value(i) < fraction * diameter.value(i);
            outcomes.push((
                (scene.value(i), frame.value(i), object.value(i)),
                !succeeded,
            ));
        }
    }
    if outcomes.is_empty() {
        return Err(bad(format!(
            "no rows of the fit '{method}' (it has {methods:?})"
        )));
    }
    Ok(outcomes)
}

/// One run's estimate, as [`agreement`] reads it from its `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RunEstimate {
    pub run: std::path::PathBuf,
    pub sampler: Sampler,
    pub seed: u64,
    pub p_hat: f64,
    pub ci95: (f64, f64),
    pub samples_spent: usize,
    /// The run's own warnings (weights, splitting's plateaus, …).
    pub warnings: Vec<String>,
}

/// Whether independent runs of one search estimate the same failure probability.
#[derive(Debug, Clone, Serialize)]
pub struct Agreement {
    pub estimates: Vec<RunEstimate>,
    /// Pairs of runs (indices into `estimates`) whose 95 % intervals do not overlap: at least one
    /// of the two is wrong — an importance sampler that never drew a failure mode the other found,
    /// or an interval too narrow for its chain's correlation.
    pub disjoint: Vec<(usize, usize)>,
    /// Pairs that share a seed and a sampler: the same samples, not independent evidence.
    pub same_seed: Vec<(usize, usize)>,
}

/// Compares the estimates of finished runs of one search — the same space, recipe, crops,
/// networks (or system under test), fit and predicate; any sampler, seed and budget. Two 95 %
/// intervals that do not overlap mean the estimates differ beyond what both claim (under equal
/// standard errors, by chance in fewer than 0.6 % of pairs of correct intervals): the sign of a
/// failure mode one run missed (issue 29's failure sets with several modes), which no run's own
/// diagnostics can show.
pub fn agreement(runs: &[Run]) -> Result<Agreement> {
    let Some(first) = runs.first() else {
        return Err(SearchError::Settings(
            "give at least two run folders".into(),
        ));
    };
    if runs.len() < 2 {
        return Err(SearchError::Run {
            path: first.dir.clone(),
            problem: "one run agrees with itself: give a second run of the same search".into(),
        });
    }
    let event = |run: &Run| {
        let s = run.settings();
        (
            run.record.space_toml.clone(),
            run.record.recipe_toml.clone(),
            s.crops,
            s.whole_frames,
            s.two_resolutions,
            s.refine_depth,
            s.sensor_depth,
            s.fit.clone(),
            s.predicate,
            s.model.clone(),
            s.segmenter.clone(),
            s.sut.clone(),
        )
    };
    let mut estimates = Vec::new();
    for run in runs {
        if event(run) != event(first) {
            return Err(SearchError::Run {
                path: run.dir.clone(),
                problem: format!(
                    "it estimates another event than {}: the space, recipe, crops, networks, fit, \
                     depth and predicate must be equal (the sampler, seed and budget may differ)",
                    first.dir.display()
                ),
            });
        }
        let path = run.dir.join("summary.json");
        let text = std::fs::read_to_string(&path).map_err(|e| SearchError::Run {
            path: path.clone(),
            problem: format!(
                "{e}: the run is not finished (run its `boxpose search` command again, or \
                 `boxpose search merge` for a sharded one)"
            ),
        })?;
        let summary: crate::run::Summary =
            serde_json::from_str(&text).map_err(|e| SearchError::Run {
                path: path.clone(),
                problem: format!("unreadable summary.json: {e}"),
            })?;
        let ci95 = summary.estimate.ci95.ok_or_else(|| SearchError::Run {
            path: path.clone(),
            problem: "its estimate has no 95 % interval (no valid sample?)".into(),
        })?;
        estimates.push(RunEstimate {
            run: run.dir.clone(),
            sampler: summary.sampler,
            seed: run.settings().seed,
            p_hat: summary.estimate.p_hat,
            ci95,
            samples_spent: summary.samples_spent,
            warnings: summary.warnings,
        });
    }
    let (mut disjoint, mut same_seed) = (Vec::new(), Vec::new());
    for i in 0..estimates.len() {
        for j in i + 1..estimates.len() {
            let (a, b) = (&estimates[i], &estimates[j]);
            if a.ci95.1 < b.ci95.0 || b.ci95.1 < a.ci95.0 {
                disjoint.push((i, j));
            }
            if a.seed == b.seed && a.sampler == b.sampler {
                same_seed.push((i, j));
            }
        }
    }
    Ok(Agreement {
        estimates,
        disjoint,
        same_seed,
    })
}
