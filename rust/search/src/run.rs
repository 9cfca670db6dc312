//! A search run: its folder, its samplers (Monte Carlo, cross-entropy, subset simulation),
//! resumable batches and the failure-probability estimate.
//!
//! Run folder (every file published atomically):
//! - `run.json`: what is searched and how (space, recipe, sampler settings, seed): a resumed or
//!   sharded process must find the same, or it refuses to touch the folder.
//! - `proposals/iter-KKKK.json`, K ≥ 1: the proposal iteration K draws from (computed at the
//!   barrier after iteration K − 1 from all of its samples; iteration 0 draws from the nominal).
//!   For subset simulation, the splitting state before move step K (its chains, level and ρ):
//!   each iteration is one synchronous move of every chain, and `splitting.json`, written at
//!   the last barrier, holds the levels and the estimate.
//! - `batches/samples/iter-KKKK-batch-BBBBB.parquet` and `batches/timings/…`: one file per batch,
//!   the samples file last (it is the batch's commit point); a batch whose samples file exists
//!   is done and skipped on resume. Sample i's z, stratum and seed are a function of
//!   (run seed, iteration, index) only, so results do not depend on which process ran which batch.
//! - `counterexamples/{scenes,objects,frames,instances}/iter-KKKK-batch-BBBBB.parquet`: every
//!   failing sample as dataset rows (scene_id = sample_id), which `boxpose render` re-renders.
//! - after the last batch: `samples.parquet`, `timings.parquet` (all batches in sample_id order)
//!   and `summary.json` (the estimate with its CI, counts, diagnostics, versions).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use boxpose_data::arrow::array::{
    Array, ArrayRef, AsArray, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array,
    ListArray, StringArray,
};
use boxpose_data::arrow::datatypes::{Float32Type, Float64Type, Int32Type, Int64Type};
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::schema::{self, SEARCH_SAMPLES, SEARCH_TIMINGS, Table};
use boxpose_data::{Object, Scene};
use boxpose_search_stats::{
    CeConfig, CeError, CeStep, ImportanceEstimate, Proposal, SplittingConfig, SplittingError,
    SplittingRun, SplittingState, TiltChoice, WeightedSample, ce_step, choose_tilt,
    hold_at_nominal, log_nominal, sample_rng,
};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SearchError};
use crate::space::SearchSpace;
use crate::sut::{Crops, Evaluate, Invalid, Outcome, Perceived, Predicate};

/// Version of the run folder's layout and `run.json`.
pub const RUN_FORMAT: u32 = 1;

/// The random stream of splitting candidates' scene seeds (the chains' moves use the streams of
/// their stages, 0, 1, 2, …).
const SPLITTING_SEED_STREAM: u32 = u32::MAX;

/// Which sampler draws the scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Naive Monte Carlo from the nominal distribution.
    Mc,
    /// Cross-entropy adaptive importance sampling, then a frozen defensive proposal.
    Ce,
    /// Subset simulation (adaptive multilevel splitting) from the nominal.
    Splitting,
}

impl Sampler {
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Mc => "mc",
            Sampler::Ce => "ce",
            Sampler::Splitting => "splitting",
        }
    }
}

/// How a run samples and scores; stored in `run.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSettings {
    pub sampler: Sampler,
    /// Monte Carlo: samples in all. Cross-entropy: the final batch (`ce.final_samples`).
    /// Subset simulation: particles per stage (`splitting.particles`).
    pub samples: usize,
    /// Samples per batch file (the unit of resumption and of sharding).
    pub batch_size: usize,
    pub seed: u64,
    pub crops: Crops,
    /// Render whole frames even for ground-truth crops (the samples' frames then differ from a
    /// region render's, so it is part of the run's identity).
    #[serde(default)]
    pub whole_frames: bool,
    /// The pose fit: paper, fast, robust or size.
    pub fit: String,
    pub predicate: Predicate,
    /// Cross-entropy settings (`final_samples` is `samples`); unused by Monte Carlo.
    pub ce: CeConfig,
    /// Cross-entropy: the parameters the proposal may tilt (names or prefixes of z's dimensions,
    /// e.g. `target.size_m`); the others stay at their nominal, so they add no weight variance.
    /// Empty: all of them. [`AUTO_TILT`] alone: chosen from the first tuning iteration's scores
    /// ([`boxpose_search_stats::choose_tilt`]).
    #[serde(default)]
    pub ce_tilt: Vec<String>,
    /// Subset simulation's settings (`particles` is `samples`); only with that sampler.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splitting: Option<SplittingConfig>,
    /// The networks, as given (their files are not hashed).
    pub model: String,
    pub segmenter: Option<String>,
    /// An external system under test (`exec:COMMAND` or `python:MODULE:CALLABLE`), instead of
    /// the networks; as given (what it runs is not hashed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sut: Option<String>,
}

/// `run.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub format: u32,
    pub settings: RunSettings,
    pub space_toml: String,
    pub recipe_toml: String,
    /// Names of z's dimensions, in order.
    pub dimensions: Vec<String>,
    /// The strata (neighbour counts), each of nominal probability 1 / len.
    pub strata: Vec<u32>,
    /// A `[pile]` space's boxes, as read from its dataset when the run started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pile: Option<Vec<crate::space::PileBox>>,
}

impl RunRecord {
    pub fn new(space: &SearchSpace, settings: RunSettings) -> Result<Self> {
        if settings.samples == 0 || settings.batch_size == 0 {
            return Err(SearchError::Sample(
                "--samples and --batch-size must be at least 1".into(),
            ));
        }
        if settings.sampler == Sampler::Ce {
            let mut ce = settings.ce.clone();
            ce.final_samples = settings.samples;
            ce.validate().map_err(|e| match e {
                CeError::Config { key, message } => {
                    SearchError::Sample(format!("{}: {message}", ce_flag(key)))
                }
                other => SearchError::Sample(other.to_string()),
            })?;
        }
        match (settings.sampler, &settings.splitting) {
            (Sampler::Splitting, Some(config)) => {
                if config.particles != settings.samples {
                    return Err(SearchError::Sample(format!(
                        "splitting particles {} differ from --samples {}",
                        config.particles, settings.samples
                    )));
                }
                config.validate().map_err(|e| match e {
                    SplittingError::Config { key, message } => SearchError::Sample(format!(
                        "{}: {message}",
                        if key == "particles" {
                            "--samples".to_string()
                        } else {
                            setting_flag(&format!("splitting.{key}"))
                        }
                    )),
                    other => SearchError::Sample(other.to_string()),
                })?;
                if space.strata().len() > 1 {
                    return Err(SearchError::Sample(format!(
                        "--sampler splitting draws from one stratum, and this space has {} \
                         (its neighbour counts): use --sampler mc or ce",
                        space.strata().len()
                    )));
                }
            }
            (Sampler::Splitting, None) => {
                return Err(SearchError::Sample(
                    "--sampler splitting needs its settings".into(),
                ));
            }
            (_, Some(_)) => {
                return Err(SearchError::Sample(
                    "splitting settings are for --sampler splitting only".into(),
                ));
            }
            (_, None) => {}
        }
        let names: Vec<&str> = space.dimensions.iter().map(|d| d.name.as_str()).collect();
        if settings.ce_tilt.iter().any(|t| t == AUTO_TILT) {
            if settings.ce_tilt.len() > 1 {
                return Err(SearchError::Sample(format!(
                    "--ce-tilt {AUTO_TILT} chooses the parameters itself: give it alone, or name them"
                )));
            }
            if settings.ce.samples_per_iteration < boxpose_search_stats::tilt::MIN_SAMPLES {
                return Err(SearchError::Sample(format!(
                    "--ce-tilt {AUTO_TILT} tests the first iteration's samples: give \
                     --ce-samples-per-iteration at least {} (a few hundred to find weak effects)",
                    boxpose_search_stats::tilt::MIN_SAMPLES
                )));
            }
        }
        for prefix in settings.ce_tilt.iter().filter(|t| *t != AUTO_TILT) {
            if !names.iter().any(|n| n.starts_with(prefix.as_str())) {
                return Err(SearchError::Sample(format!(
                    "--ce-tilt {prefix}: no parameter of the space starts with it (they are: {})",
                    names.join(", ")
                )));
            }
        }
        Ok(Self {
            format: RUN_FORMAT,
            settings,
            space_toml: space.text.clone(),
            recipe_toml: space.recipe_toml.clone(),
            dimensions: space.dimensions.iter().map(|d| d.name.clone()).collect(),
            strata: space.strata(),
            pile: space.pile.clone(),
        })
    }
}

/// The `boxpose search` flag that sets a cross-entropy setting, for errors in the user's terms.
fn ce_flag(key: &str) -> String {
    match key {
        "final_samples" => "--samples".to_string(),
        "defensive_lambda" => "--ce-lambda".to_string(),
        other => format!("--ce-{}", other.replace('_', "-")),
    }
}

/// Refuses a shard that is not one of `num_shards` (checked before a run folder is touched).
pub fn check_shard(shard: usize, num_shards: usize) -> Result<()> {
    if num_shards == 0 || shard >= num_shards {
        return Err(SearchError::Sample(format!(
            "--shard {shard} is not below --num-shards {num_shards} (shards are numbered 0 to N − 1, N ≥ 1)"
        )));
    }
    Ok(())
}

/// What differs between the search a run folder holds (`run`) and a command's (`this`), in the
/// command's terms: the flag (or the file) and both values.
pub(crate) fn differences(run: &RunRecord, this: &RunRecord) -> Vec<String> {
    let mut out = Vec::new();
    if run.space_toml != this.space_toml {
        out.push("the search space differs".to_string());
    }
    if run.recipe_toml != this.recipe_toml {
        out.push("the base recipe differs".to_string());
    }
    if run.pile != this.pile {
        out.push("the pile's boxes differ (its dataset changed since the run started)".to_string());
    }
    let fields = |settings: &RunSettings| match serde_json::to_value(settings) {
        Ok(serde_json::Value::Object(fields)) => fields,
        _ => unreachable!("run settings serialise as a JSON object"),
    };
    let (theirs, ours) = (fields(&run.settings), fields(&this.settings));
    let shown = |value: Option<&serde_json::Value>| match value {
        Some(serde_json::Value::String(text)) => text.clone(),
        Some(serde_json::Value::Null) | None => "none".to_string(),
        Some(value) => value.to_string(),
    };
    let mut differ =
        |name: &str, theirs: Option<&serde_json::Value>, ours: Option<&serde_json::Value>| {
            if theirs != ours {
                out.push(format!(
                    "{} is {} there, {} here",
                    setting_flag(name),
                    shown(theirs),
                    shown(ours)
                ));
            }
        };
    for (key, value) in &theirs {
        match (key.as_str(), value, ours.get(key)) {
            ("ce", serde_json::Value::Object(theirs), Some(serde_json::Value::Object(ours))) => {
                for (ce_key, value) in theirs {
                    // the final stage's sample count is --samples, compared above
                    if ce_key != "final_samples" {
                        differ(&format!("ce.{ce_key}"), Some(value), ours.get(ce_key));
                    }
                }
            }
            (
                "splitting",
                serde_json::Value::Object(theirs),
                Some(serde_json::Value::Object(ours)),
            ) => {
                for (split_key, value) in theirs {
                    // the particles are --samples, compared above
                    if split_key != "particles" {
                        differ(
                            &format!("splitting.{split_key}"),
                            Some(value),
                            ours.get(split_key),
                        );
                    }
                }
            }
            (_, value, ours) => differ(key, Some(value), ours),
        }
    }
    if out.is_empty() {
        out.push("its record differs".to_string());
    }
    out
}

/// The command-line flag that sets a field of [`RunSettings`] (dotted for `ce`).
fn setting_flag(field: &str) -> String {
    let flag = match field {
        "predicate" => "fail-when",
        "ce.defensive_lambda" => "ce-lambda",
        other => other,
    };
    format!("--{}", flag.replace(['_', '.'], "-"))
}

/// `--ce-tilt auto`: the tilted parameters are chosen from the first tuning iteration.
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
    /// Cross-entropy with `--ce-tilt auto`: the tilt chosen after iteration 0, carried by every
    /// later plan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt: Option<TiltChoice>,
}

impl IterationPlan {
    /// Whether a barrier follows this iteration (cross-entropy tuning, every splitting step
    /// until the run ends), rather than it being the run's last.
    fn has_barrier(&self) -> bool {
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

/// One row of the `samples` table (see [`schema::SEARCH_SAMPLES`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SampleRow {
    pub sample_id: i64,
    pub sampler: String,
    pub stage: String,
    pub iteration: i32,
    pub stratum: i32,
    pub seed: i64,
    pub z: Vec<f64>,
    pub params: Vec<f64>,
    pub log_nominal: f64,
    pub log_proposal: f64,
    pub log_weight: f64,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    pub target_visible_fraction: Option<f32>,
    pub detected: Option<bool>,
    pub fit_error: Option<String>,
    pub paper_error: Option<f64>,
    pub paper_error_normalized: Option<f64>,
    pub mssd_over_diameter: Option<f64>,
    pub cube_mssd_over_diameter: Option<f64>,
    pub add_s_m: Option<f64>,
    pub rotation_error_deg: Option<f64>,
    pub translation_error_m: Option<f64>,
    /// Null when not scored or nothing fitted (then +∞ for the cross-entropy levels).
    pub score: Option<f64>,
    pub fit_confidence: Option<f64>,
    pub failed: bool,
    pub peaks_camera_m: Option<Vec<f64>>,
    pub fitted_corners_camera_m: Option<Vec<f64>>,
}

impl SampleRow {
    /// Whether this sample fails under `predicate`, whichever predicate its run used: valid, and
    /// not found, not fitted, or the predicate's error above its threshold.
    pub fn fails_under(&self, predicate: &Predicate) -> bool {
        let (error, threshold) = predicate.judge(
            self.paper_error_normalized,
            self.mssd_over_diameter,
            self.cube_mssd_over_diameter,
        );
        self.valid
            && (self.detected == Some(false)
                || self.fit_error.is_some()
                || error.is_some_and(|e| e > threshold))
    }

    /// The score the cross-entropy levels use: NaN for an invalid sample (never an elite), +∞
    /// for a valid one with nothing fitted.
    pub fn level_score(&self) -> f64 {
        match (self.valid, self.score) {
            (false, _) => f64::NAN,
            (true, Some(s)) => s,
            (true, None) => f64::INFINITY,
        }
    }
}

/// Per-stage seconds of one sample (the `timings` table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimingRow {
    pub sample_id: i64,
    pub settle_s: f64,
    pub render_s: f64,
    pub inference_s: f64,
    pub fit_s: f64,
}

/// A run folder, opened for sampling or reading.
pub struct Run {
    pub dir: PathBuf,
    pub record: RunRecord,
}

/// The JSON file `path` of the run folder, `None` while it does not exist yet; `what` names it
/// in the error when it cannot be read.
fn read_json_if_present<T: serde::de::DeserializeOwned>(
    path: PathBuf,
    what: &str,
) -> Result<Option<T>> {
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| io_error(&path, e))?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| SearchError::Run {
            path,
            problem: format!("unreadable {what}: {e}"),
        })
}

fn io_error(path: &Path, e: impl std::fmt::Display) -> SearchError {
    SearchError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl Run {
    /// Creates the run folder, or reopens it when it holds the same search (resume); refuses a
    /// folder holding another search or anything else.
    pub fn create(dir: &Path, record: RunRecord) -> Result<Self> {
        let path = dir.join("run.json");
        if path.exists() {
            let run = Self::open(dir)?;
            if run.record != record {
                return Err(SearchError::Run {
                    path: dir.to_path_buf(),
                    problem: format!(
                        "it holds another search ({}); resume it with its own settings or choose a new --out",
                        differences(&run.record, &record).join("; ")
                    ),
                });
            }
            return Ok(run);
        }
        // another shard may be publishing run.json right now: neither it nor its temporary file
        // is a stranger (run.json itself is compared below, once written)
        let foreign = |entry: std::io::Result<std::fs::DirEntry>| {
            entry
                .map(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    !(name.ends_with(".tmp") || name.ends_with(".lock") || name == "run.json")
                })
                .unwrap_or(true)
        };
        if dir.exists()
            && std::fs::read_dir(dir)
                .map_err(|e| io_error(dir, e))?
                .any(foreign)
        {
            return Err(SearchError::Run {
                path: dir.to_path_buf(),
                problem: "not empty and not a search run (no run.json): choose a new --out".into(),
            });
        }
        let json = serde_json::to_vec_pretty(&record).expect("a run record serialises");
        boxpose_data::write_file_atomically(&path, &json)?;
        // two shards started together both write run.json; the one that lost the race re-reads it
        let run = Self::open(dir)?;
        if run.record != record {
            return Err(SearchError::Run {
                path: dir.to_path_buf(),
                problem: "another process created it for another search at the same time".into(),
            });
        }
        Ok(run)
    }

    /// An exclusive lock on this shard of the run, held while the returned file lives (the
    /// kernel releases it when the process ends, however it ends): two processes sampling one
    /// shard would write the same batches.
    pub fn lock_shard(&self, shard: usize, num_shards: usize) -> Result<std::fs::File> {
        let path = self
            .dir
            .join(format!(".shard-{shard:05}-of-{num_shards:05}.lock"));
        let file = std::fs::File::create(&path).map_err(|e| io_error(&path, e))?;
        match file.try_lock() {
            Ok(()) => Ok(file),
            Err(std::fs::TryLockError::WouldBlock) => Err(SearchError::Run {
                path: self.dir.clone(),
                problem: format!(
                    "shard {shard} of {num_shards} is being sampled by another process; wait for it or stop it (its committed batches are kept)"
                ),
            }),
            Err(std::fs::TryLockError::Error(e)) => Err(io_error(&path, e)),
        }
    }

    /// Opens an existing run folder.
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join("run.json");
        let text = std::fs::read_to_string(&path).map_err(|e| {
            io_error(
                &path,
                format!("{e} (is this a `boxpose search` run folder?)"),
            )
        })?;
        let record: RunRecord = serde_json::from_str(&text).map_err(|e| SearchError::Run {
            path: path.clone(),
            problem: format!("unreadable run.json: {e}"),
        })?;
        if record.format != RUN_FORMAT {
            return Err(SearchError::Run {
                path,
                problem: format!(
                    "run format {} (this boxpose reads {RUN_FORMAT})",
                    record.format
                ),
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            record,
        })
    }

    pub(crate) fn settings(&self) -> &RunSettings {
        &self.record.settings
    }

    fn batch_name(iteration: u32, batch: usize) -> String {
        format!("iter-{iteration:04}-batch-{batch:05}.parquet")
    }

    fn batch_path(&self, table: &Table, iteration: u32, batch: usize) -> PathBuf {
        self.dir
            .join("batches")
            .join(table.name)
            .join(Self::batch_name(iteration, batch))
    }

    fn plan_path(&self, iteration: u32) -> PathBuf {
        self.dir
            .join("proposals")
            .join(format!("iter-{iteration:04}.json"))
    }

    fn batches(&self, samples: usize) -> usize {
        samples.div_ceil(self.settings().batch_size)
    }

    /// The first sample_id of `iteration`: tuning iterations hold `samples_per_iteration` each.
    fn first_id(&self, iteration: u32) -> i64 {
        match self.settings().sampler {
            Sampler::Mc | Sampler::Splitting => 0,
            Sampler::Ce => iteration as i64 * self.settings().ce.samples_per_iteration as i64,
        }
    }

    /// Where the tuning start's orientation blocks start (four normals normalised to a quaternion
    /// each): the cross-entropy proposal gives the tilted ones an angular central Gaussian, the
    /// rest a Gaussian. With `--ce-tilt auto` every block, until the choice is made.
    fn rotation_blocks(&self) -> Vec<usize> {
        let tilted = self.tilt_mask(None);
        self.orientation_blocks()
            .into_iter()
            .filter(|&i| tilted[i])
            .collect()
    }

    fn auto_tilt(&self) -> bool {
        self.settings().ce_tilt.iter().any(|t| t == AUTO_TILT)
    }

    /// Per dimension of z: whether the cross-entropy proposal may move it — the names and
    /// prefixes of `--ce-tilt`, or with `--ce-tilt auto` the `chosen` tilt (every dimension
    /// before it is made).
    fn tilt_mask(&self, chosen: Option<&TiltChoice>) -> Vec<bool> {
        let dim = self.record.dimensions.len();
        if self.auto_tilt() {
            return chosen.map_or_else(|| vec![true; dim], |c| c.mask(dim));
        }
        let tilt = &self.settings().ce_tilt;
        self.record
            .dimensions
            .iter()
            .map(|name| tilt.is_empty() || tilt.iter().any(|p| name.starts_with(p.as_str())))
            .collect()
    }

    /// The plan of `iteration`, if it is known yet (written at the barrier before it).
    pub fn plan(&self, iteration: u32) -> Result<Option<IterationPlan>> {
        let dim = self.record.dimensions.len();
        let s = self.settings();
        if iteration == 0 {
            return Ok(Some(match s.sampler {
                Sampler::Mc => IterationPlan {
                    stage: "mc".into(),
                    samples: s.samples,
                    proposal: Proposal::nominal(dim),
                    step: None,
                    splitting: None,
                    tilt: None,
                },
                Sampler::Splitting => {
                    let config = s.splitting.as_ref().expect("checked by RunRecord::new");
                    let state =
                        SplittingState::new(config, dim, &self.orientation_blocks(), s.seed)
                            .map_err(|e| SearchError::Run {
                                path: self.dir.clone(),
                                problem: format!("the splitting run: {e}"),
                            })?;
                    IterationPlan {
                        stage: "split".into(),
                        samples: config.particles,
                        proposal: Proposal::nominal(dim),
                        step: None,
                        splitting: Some(state),
                        tilt: None,
                    }
                }
                Sampler::Ce => IterationPlan {
                    stage: "tune".into(),
                    samples: s.ce.samples_per_iteration,
                    proposal: Proposal::tuning_start(dim, s.ce.components)
                        .with_rotation_blocks(&self.rotation_blocks())
                        .map_err(|e| SearchError::Run {
                            path: self.dir.clone(),
                            problem: format!("the starting proposal: {e}"),
                        })?,
                    step: None,
                    splitting: None,
                    tilt: None,
                },
            }));
        }
        read_json_if_present(self.plan_path(iteration), "proposal")
    }

    /// Every iteration's plan, in order, as far as known.
    pub fn plans(&self) -> Result<Vec<IterationPlan>> {
        let mut plans = Vec::new();
        while let Some(plan) = self.plan(plans.len() as u32)? {
            let last = !plan.has_barrier();
            plans.push(plan);
            if last {
                break;
            }
        }
        Ok(plans)
    }

    /// Runs the batches of this shard (`shard` of `num_shards`; batch b belongs to shard
    /// b mod num_shards), waiting at each iteration barrier for the other shards' batches.
    /// Returns when every batch of the run exists (or, for shards other than 0, when this
    /// shard's last batch is done).
    pub fn sample(
        &self,
        space: &SearchSpace,
        sut: &mut dyn Evaluate,
        shard: usize,
        num_shards: usize,
        observer: &mut dyn Observer,
    ) -> Result<()> {
        check_shard(shard, num_shards)?;
        let mut iteration = 0u32;
        loop {
            let plan = self.wait_for_plan(iteration, observer)?;
            let batches = self.batches(plan.samples);
            let mut done = Vec::new();
            for batch in 0..batches {
                let path = self.batch_path(&SEARCH_SAMPLES, iteration, batch);
                if path.exists() {
                    done.extend(read_samples(&path)?);
                }
            }
            observer.iteration(iteration, &plan, &done);
            for batch in (0..batches).filter(|b| b % num_shards == shard) {
                if self.batch_path(&SEARCH_SAMPLES, iteration, batch).exists() {
                    continue;
                }
                self.run_batch(space, sut, iteration, batch, &plan, observer)?;
            }
            if !plan.has_barrier() {
                if shard == 0 {
                    self.wait_for_batches(iteration, batches, observer)?;
                }
                return Ok(());
            }
            self.wait_for_batches(iteration, batches, observer)?;
            if !self.advance(iteration, &plan)? {
                return Ok(());
            }
            iteration += 1;
        }
    }

    /// The work a scheduler can hand out now: the batches of the current iteration that nobody
    /// has committed. Every barrier whose iteration is complete is passed first (the step is
    /// deterministic and published atomically, so any number of processes may call this at
    /// once); `complete` when the last iteration's batches are all committed.
    pub fn pending(&self) -> Result<PendingWork> {
        let mut iteration = 0u32;
        loop {
            let plan = self.plan(iteration)?.ok_or_else(|| SearchError::Run {
                path: self.plan_path(iteration),
                problem: "missing although the previous iteration is complete".into(),
            })?;
            let batches: Vec<usize> = (0..self.batches(plan.samples))
                .filter(|&b| !self.batch_path(&SEARCH_SAMPLES, iteration, b).exists())
                .collect();
            let last =
                batches.is_empty() && plan.has_barrier() && !self.advance(iteration, &plan)?;
            if !batches.is_empty() || !plan.has_barrier() || last {
                return Ok(PendingWork {
                    iteration,
                    stage: plan.stage,
                    samples: plan.samples,
                    batch_size: self.settings().batch_size,
                    complete: batches.is_empty(),
                    batches,
                });
            }
            iteration += 1;
        }
    }

    /// Runs batch `batch` of iteration `iteration` alone, a scheduler's unit of work (see
    /// [`Run::pending`], which makes the iteration's proposal). Returns false, doing nothing,
    /// when the batch is already committed, so a retried task costs nothing.
    pub fn sample_batch(
        &self,
        space: &SearchSpace,
        sut: &mut dyn Evaluate,
        iteration: u32,
        batch: usize,
        observer: &mut dyn Observer,
    ) -> Result<bool> {
        let plan = self.plan(iteration)?.ok_or_else(|| {
            SearchError::Sample(format!(
                "iteration {iteration} has no proposal yet: iteration {} is unfinished \
                 (`boxpose search … --pending` makes the proposal once it is done)",
                iteration.saturating_sub(1)
            ))
        })?;
        let batches = self.batches(plan.samples);
        if batch >= batches {
            return Err(SearchError::Sample(format!(
                "iteration {iteration} has {batches} batches (0 to {}), not batch {batch}",
                batches - 1
            )));
        }
        if self.batch_path(&SEARCH_SAMPLES, iteration, batch).exists() {
            return Ok(false);
        }
        self.run_batch(space, sut, iteration, batch, &plan, observer)?;
        Ok(true)
    }

    fn wait_for_plan(&self, iteration: u32, observer: &mut dyn Observer) -> Result<IterationPlan> {
        loop {
            if let Some(plan) = self.plan(iteration)? {
                return Ok(plan);
            }
            observer.waiting(&format!("the proposal of iteration {iteration}"));
            std::thread::sleep(std::time::Duration::from_secs(1));
        }
    }

    fn wait_for_batches(
        &self,
        iteration: u32,
        batches: usize,
        observer: &mut dyn Observer,
    ) -> Result<()> {
        loop {
            let missing = (0..batches)
                .filter(|&b| !self.batch_path(&SEARCH_SAMPLES, iteration, b).exists())
                .count();
            if missing == 0 {
                return Ok(());
            }
            observer.waiting(&format!(
                "{missing} batches of iteration {iteration} from other shards"
            ));
            std::thread::sleep(std::time::Duration::from_secs(1));
        }
    }

    /// The barrier after tuning iteration `iteration`: the cross-entropy step on all of its
    /// samples, and the next iteration's plan (another tuning iteration, or the frozen final
    /// proposal once the failure level is reached or the iterations run out); after a
    /// splitting step, the next step's state or, at the end, `splitting.json`. Returns whether
    /// an iteration follows.
    fn advance(&self, iteration: u32, plan: &IterationPlan) -> Result<bool> {
        let path = self.plan_path(iteration + 1);
        if path.exists() {
            return Ok(true);
        }
        if let Some(state) = &plan.splitting {
            return self.advance_splitting(iteration, plan, state.clone());
        }
        let rows = self.iteration_rows(iteration, self.batches(plan.samples))?;
        let zs: Vec<Vec<f64>> = rows.iter().map(|r| r.z.clone()).collect();
        let scores: Vec<f64> = rows.iter().map(SampleRow::level_score).collect();
        let ce = &self.settings().ce;
        let step_error = |e: CeError| SearchError::Run {
            path: self.dir.clone(),
            problem: format!("cross-entropy step after iteration {iteration}: {e}"),
        };
        let (current, tilt) = if self.auto_tilt() && iteration == 0 {
            // Iteration 0 drew from the nominal: its scores show what the failures depend on.
            let dim = self.record.dimensions.len();
            let choice = choose_tilt(
                &zs,
                &scores,
                dim,
                &self.orientation_blocks(),
                AUTO_TILT_ALPHA,
            )
            .map_err(step_error)?;
            // The same density as iteration 0's (the nominal), with only the chosen blocks
            // shaped as rotations.
            let start = Proposal::tuning_start(dim, ce.components)
                .with_rotation_blocks(&choice.tilted_blocks())
                .map_err(|e| step_error(e.into()))?;
            (start, Some(choice))
        } else {
            (plan.proposal.clone(), plan.tilt.clone())
        };
        let mut step = ce_step(&current, &zs, &scores, 0.0, ce).map_err(step_error)?;
        step.next = hold_at_nominal(step.next, &self.tilt_mask(tilt.as_ref()));
        let last = step.reached || iteration + 1 >= ce.max_iterations;
        let next = if last {
            IterationPlan {
                stage: "final".into(),
                samples: self.settings().samples,
                proposal: step.next.with_defensive(ce.defensive_lambda),
                step: Some(step),
                splitting: None,
                tilt,
            }
        } else {
            IterationPlan {
                stage: "tune".into(),
                samples: ce.samples_per_iteration,
                proposal: step.next.clone(),
                step: Some(step),
                splitting: None,
                tilt,
            }
        };
        boxpose_data::write_file_atomically(
            &path,
            &serde_json::to_vec_pretty(&next).expect("a plan serialises"),
        )?;
        Ok(true)
    }

    fn splitting_path(&self) -> PathBuf {
        self.dir.join("splitting.json")
    }

    /// The orientation blocks of z (four normals whose direction is a uniform rotation): the
    /// splitting moves turn them as rotations, cross-entropy fits them angular central Gaussians.
    fn orientation_blocks(&self) -> Vec<usize> {
        self.record
            .dimensions
            .iter()
            .enumerate()
            .filter(|&(_, name)| name.ends_with(".orientation.q0"))
            .map(|(i, _)| i)
            .collect()
    }

    /// The barrier after splitting step `iteration`: its candidates' scores (invalid samples
    /// below every level) move the state on; the next step's state becomes the next plan, or
    /// the run's end `splitting.json`.
    fn advance_splitting(
        &self,
        iteration: u32,
        plan: &IterationPlan,
        mut state: SplittingState,
    ) -> Result<bool> {
        if self.splitting_path().exists() {
            return Ok(false);
        }
        let rows = self.iteration_rows(iteration, self.batches(plan.samples))?;
        let scores: Vec<f64> = rows.iter().map(SampleRow::level_score).collect();
        let ended = state.advance(&scores).map_err(|e| SearchError::Run {
            path: self.dir.clone(),
            problem: format!("subset simulation after iteration {iteration}: {e}"),
        })?;
        if let Some(result) = ended {
            boxpose_data::write_file_atomically(
                &self.splitting_path(),
                &serde_json::to_vec_pretty(&result).expect("a splitting run serialises"),
            )?;
            return Ok(false);
        }
        let next = IterationPlan {
            stage: "split".into(),
            samples: state.candidates().len(),
            proposal: plan.proposal.clone(),
            step: None,
            splitting: Some(state),
            tilt: None,
        };
        boxpose_data::write_file_atomically(
            &self.plan_path(iteration + 1),
            &serde_json::to_vec_pretty(&next).expect("a plan serialises"),
        )?;
        Ok(true)
    }

    /// The end of a subset simulation (`splitting.json`), once its last barrier is passed.
    pub fn splitting_result(&self) -> Result<Option<SplittingRun>> {
        read_json_if_present(self.splitting_path(), "splitting result")
    }

    fn iteration_rows(&self, iteration: u32, batches: usize) -> Result<Vec<SampleRow>> {
        let mut rows = Vec::new();
        for batch in 0..batches {
            rows.extend(read_samples(&self.batch_path(
                &SEARCH_SAMPLES,
                iteration,
                batch,
            ))?);
        }
        Ok(rows)
    }

    fn run_batch(
        &self,
        space: &SearchSpace,
        sut: &mut dyn Evaluate,
        iteration: u32,
        batch: usize,
        plan: &IterationPlan,
        observer: &mut dyn Observer,
    ) -> Result<()> {
        let s = self.settings();
        let first = batch * s.batch_size;
        let last = (first + s.batch_size).min(plan.samples);
        let strata = &self.record.strata;
        let mut rows = Vec::new();
        let mut timings = Vec::new();
        let mut counterexamples: Vec<Outcome> = Vec::new();
        let candidates = plan.splitting.as_ref().map(SplittingState::candidates);
        for index in first..last {
            // proportional allocation: every stratum gets its nominal share of every iteration
            let stratum = index % strata.len();
            let (sample_id, z, seed) = match &candidates {
                // a splitting candidate's z comes from its chain; its scene seed is drawn
                // afresh (an independent proposal from the seed's own nominal, so the move
                // still leaves the conditioned nominal of (z, seed) invariant)
                Some(candidates) => {
                    let c = &candidates[index];
                    let mut rng = sample_rng(s.seed, SPLITTING_SEED_STREAM, c.evaluation);
                    let seed = (rng.random::<u64>() >> 1) as i64;
                    (c.evaluation as i64, c.z.clone(), seed)
                }
                None => {
                    let mut rng = sample_rng(s.seed, iteration, index as u64);
                    let z = plan.proposal.sample(&mut rng);
                    let seed = (rng.random::<u64>() >> 1) as i64;
                    (self.first_id(iteration) + index as i64, z, seed)
                }
            };
            let parameters = space.parameters(&z, strata[stratum])?;
            let outcome = sut.evaluate(space, &parameters, sample_id, seed).map_err(|e| {
                SearchError::Sample(format!(
                    "sample {sample_id} (iteration {iteration}, index {index}, seed {seed}, {} neighbours): {e}",
                    strata[stratum]
                ))
            })?;
            let log_p = log_nominal(&z);
            let log_q = plan.proposal.log_density(&z);
            let row = sample_row(
                sample_id,
                s,
                plan,
                iteration,
                strata[stratum],
                seed,
                &z,
                space,
                &parameters,
                log_p,
                log_q,
                &outcome,
            );
            timings.push(TimingRow {
                sample_id,
                settle_s: outcome.seconds.settle,
                render_s: outcome.seconds.render,
                inference_s: outcome.seconds.inference,
                fit_s: outcome.seconds.fit,
            });
            observer.sample(&row);
            if row.failed {
                counterexamples.push(outcome);
            }
            rows.push(row);
        }
        let name = Self::batch_name(iteration, batch);
        if !counterexamples.is_empty() {
            write_counterexamples(&self.dir.join("counterexamples"), &name, &counterexamples)?;
        }
        boxpose_data::write_parquet(
            &self.batch_path(&SEARCH_TIMINGS, iteration, batch),
            Arc::new(SEARCH_TIMINGS.arrow_schema()),
            &[timings_batch(&timings)],
        )?;
        boxpose_data::write_parquet(
            &self.batch_path(&SEARCH_SAMPLES, iteration, batch),
            Arc::new(SEARCH_SAMPLES.arrow_schema()),
            &[samples_batch(&rows)],
        )?;
        Ok(())
    }

    /// Runs sample `row` of this run again, end to end (settle, render, perception, fit), from
    /// its stored z, stratum and seed: the counterexample loop's "does it still fail?". Returns
    /// the new row and the outcome (the scene, frame and peaks, for drawing).
    pub fn replay(
        &self,
        space: &SearchSpace,
        sut: &mut dyn Evaluate,
        row: &SampleRow,
    ) -> Result<(SampleRow, Outcome)> {
        let iteration = row.iteration as u32;
        let plan = self.plan(iteration)?.ok_or_else(|| SearchError::Run {
            path: self.dir.clone(),
            problem: format!(
                "sample {} is in iteration {iteration}, whose proposal is missing",
                row.sample_id
            ),
        })?;
        let parameters = space.parameters(&row.z, row.stratum as u32)?;
        let outcome = sut.evaluate(space, &parameters, row.sample_id, row.seed)?;
        let replayed = sample_row(
            row.sample_id,
            self.settings(),
            &plan,
            iteration,
            row.stratum as u32,
            row.seed,
            &row.z,
            space,
            &parameters,
            log_nominal(&row.z),
            plan.proposal.log_density(&row.z),
            &outcome,
        );
        Ok((replayed, outcome))
    }

    /// Whether every batch of the run exists.
    pub fn complete(&self) -> Result<bool> {
        if self.settings().sampler == Sampler::Splitting {
            return Ok(self.splitting_path().exists());
        }
        let plans = self.plans()?;
        let Some(last) = plans.last().filter(|p| p.stage != "tune") else {
            return Ok(false);
        };
        let iteration = plans.len() as u32 - 1;
        Ok((0..self.batches(last.samples))
            .all(|b| self.batch_path(&SEARCH_SAMPLES, iteration, b).exists()))
    }

    /// Every sample and timing row written so far, in sample_id order.
    pub fn rows(&self) -> Result<(Vec<SampleRow>, Vec<TimingRow>)> {
        let mut samples = Vec::new();
        let mut timings = Vec::new();
        for (iteration, plan) in self.plans()?.iter().enumerate() {
            for batch in 0..self.batches(plan.samples) {
                let path = self.batch_path(&SEARCH_SAMPLES, iteration as u32, batch);
                if path.exists() {
                    samples.extend(read_samples(&path)?);
                    timings.extend(read_timings(&self.batch_path(
                        &SEARCH_TIMINGS,
                        iteration as u32,
                        batch,
                    ))?);
                }
            }
        }
        samples.sort_by_key(|r| r.sample_id);
        timings.sort_by_key(|r| r.sample_id);
        Ok((samples, timings))
    }

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
            .chain(ce_tilt.as_ref().filter(|t| t.nothing_stood_out).map(|t| {
                format!(
                    "--ce-tilt auto: no parameter's effect on the score showed in the first \
                     iteration's {} valid samples, so every parameter was tilted",
                    t.samples
                )
            }))
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

/// `--ce-tilt auto`: what the first tuning iteration's scores chose.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TiltSummary {
    /// Valid samples of iteration 0 the tests were made on.
    pub samples: usize,
    /// The family-wise level α; each test is held to α / the number of tests.
    pub alpha: f64,
    /// No parameter passed its test, so every one was tilted.
    pub nothing_stood_out: bool,
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
            .filter(|t| t.tilted || self.nothing_stood_out)
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

#[allow(clippy::too_many_arguments)]
fn sample_row(
    sample_id: i64,
    settings: &RunSettings,
    plan: &IterationPlan,
    iteration: u32,
    stratum: u32,
    seed: i64,
    z: &[f64],
    space: &SearchSpace,
    parameters: &crate::space::Parameters,
    log_nominal: f64,
    log_proposal: f64,
    outcome: &Outcome,
) -> SampleRow {
    let params = space
        .dimensions
        .iter()
        .zip(z)
        .map(|(d, zi)| {
            if d.distribution.is_some() {
                parameters.values[&d.name]
            } else {
                *zi
            }
        })
        .collect();
    let visible = outcome.rendered.as_ref().and_then(|(_, instances)| {
        let ids = instances
            .column_by_name("object_id")?
            .as_primitive::<Int32Type>()
            .clone();
        let fractions = instances
            .column_by_name("visible_fraction")?
            .as_primitive::<Float32Type>()
            .clone();
        (0..ids.len())
            .find(|&i| ids.value(i) == crate::scene::TARGET_OBJECT_ID)
            .map(|i| fractions.value(i))
    });
    let mut row = SampleRow {
        sample_id,
        sampler: settings.sampler.name().into(),
        stage: plan.stage.clone(),
        iteration: iteration as i32,
        stratum: stratum as i32,
        seed,
        z: z.to_vec(),
        params,
        log_nominal,
        log_proposal,
        log_weight: log_nominal - log_proposal,
        valid: outcome.result.is_ok(),
        invalid_reason: outcome.result.as_ref().err().map(Invalid::to_string),
        target_visible_fraction: visible,
        detected: None,
        fit_error: None,
        paper_error: None,
        paper_error_normalized: None,
        mssd_over_diameter: None,
        cube_mssd_over_diameter: None,
        add_s_m: None,
        rotation_error_deg: None,
        translation_error_m: None,
        score: None,
        fit_confidence: None,
        failed: false,
        fitted_corners_camera_m: None,
        peaks_camera_m: outcome
            .result
            .is_ok()
            .then(|| outcome.peaks.iter().flatten().copied().collect()),
    };
    match &outcome.result {
        Err(_) => {}
        Ok(Perceived::NotDetected) => {
            row.detected = Some(false);
            row.failed = true;
        }
        Ok(Perceived::FitFailed(e)) => {
            row.detected = Some(true);
            row.fit_error = Some(e.clone());
            row.failed = true;
        }
        Ok(Perceived::Fitted(m)) => {
            let score = settings.predicate.score(m);
            row.detected = Some(true);
            row.paper_error = Some(m.paper_error);
            row.paper_error_normalized = Some(m.paper_error_normalized);
            row.mssd_over_diameter = Some(m.mssd_over_diameter);
            row.cube_mssd_over_diameter = Some(m.cube_mssd_over_diameter);
            row.add_s_m = Some(m.add_s_m);
            row.rotation_error_deg = Some(m.rotation_error_deg);
            row.translation_error_m = Some(m.translation_error_m);
            row.score = Some(score);
            row.fit_confidence = m.confidence;
            row.fitted_corners_camera_m =
                Some(m.fitted_corners.iter().flatten().copied().collect());
            row.failed = score > 0.0;
        }
    }
    row
}

fn f64_list<'a>(rows: impl Iterator<Item = Option<&'a Vec<f64>>>) -> ArrayRef {
    Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(
        rows.map(|r| r.map(|v| v.iter().map(|x| Some(*x)).collect::<Vec<_>>())),
    ))
}

/// `rows` as one batch of the `samples` table.
pub fn samples_batch(rows: &[SampleRow]) -> RecordBatch {
    let f = |get: fn(&SampleRow) -> Option<f64>| {
        Arc::new(rows.iter().map(get).collect::<Float64Array>()) as ArrayRef
    };
    let text = |get: fn(&SampleRow) -> Option<&str>| {
        Arc::new(rows.iter().map(get).collect::<StringArray>()) as ArrayRef
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(rows.iter().map(|r| r.sample_id).collect::<Int64Array>()),
        text(|r| Some(r.sampler.as_str())),
        text(|r| Some(r.stage.as_str())),
        Arc::new(rows.iter().map(|r| r.iteration).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.stratum).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.seed).collect::<Int64Array>()),
        f64_list(rows.iter().map(|r| Some(&r.z))),
        f64_list(rows.iter().map(|r| Some(&r.params))),
        f(|r| Some(r.log_nominal)),
        f(|r| Some(r.log_proposal)),
        f(|r| Some(r.log_weight)),
        Arc::new(rows.iter().map(|r| Some(r.valid)).collect::<BooleanArray>()),
        text(|r| r.invalid_reason.as_deref()),
        Arc::new(
            rows.iter()
                .map(|r| r.target_visible_fraction)
                .collect::<Float32Array>(),
        ),
        Arc::new(rows.iter().map(|r| r.detected).collect::<BooleanArray>()),
        text(|r| r.fit_error.as_deref()),
        f(|r| r.paper_error),
        f(|r| r.paper_error_normalized),
        f(|r| r.mssd_over_diameter),
        f(|r| r.cube_mssd_over_diameter),
        f(|r| r.add_s_m),
        f(|r| r.rotation_error_deg),
        f(|r| r.translation_error_m),
        f(|r| r.score),
        f(|r| r.fit_confidence),
        Arc::new(
            rows.iter()
                .map(|r| Some(r.failed))
                .collect::<BooleanArray>(),
        ),
        f64_list(rows.iter().map(|r| r.peaks_camera_m.as_ref())),
        f64_list(rows.iter().map(|r| r.fitted_corners_camera_m.as_ref())),
    ];
    RecordBatch::try_new(Arc::new(SEARCH_SAMPLES.arrow_schema()), columns)
        .expect("columns in contract order and types")
}

fn timings_batch(rows: &[TimingRow]) -> RecordBatch {
    let f = |get: fn(&TimingRow) -> f64| {
        Arc::new(rows.iter().map(get).collect::<Float64Array>()) as ArrayRef
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(rows.iter().map(|r| r.sample_id).collect::<Int64Array>()),
        f(|r| r.settle_s),
        f(|r| r.render_s),
        f(|r| r.inference_s),
        f(|r| r.fit_s),
    ];
    RecordBatch::try_new(Arc::new(SEARCH_TIMINGS.arrow_schema()), columns)
        .expect("columns in contract order and types")
}

/// Reads one `samples` file (validated against the contract).
pub fn read_samples(path: &Path) -> Result<Vec<SampleRow>> {
    let mut rows = Vec::new();
    for batch in boxpose_data::read_shard(path, &SEARCH_SAMPLES)? {
        let col = |name: &str| batch.column_by_name(name).expect("validated").clone();
        let f64s = |name: &str| col(name).as_primitive::<Float64Type>().clone();
        let strings = |name: &str| col(name).as_string::<i32>().clone();
        let bools = |name: &str| col(name).as_boolean().clone();
        let lists = |name: &str| col(name).as_list::<i32>().clone();
        let (ids, sampler, stage) = (
            col("sample_id").as_primitive::<Int64Type>().clone(),
            strings("sampler"),
            strings("stage"),
        );
        let (iteration, stratum, seed) = (
            col("iteration").as_primitive::<Int32Type>().clone(),
            col("stratum").as_primitive::<Int32Type>().clone(),
            col("seed").as_primitive::<Int64Type>().clone(),
        );
        let (z, params, peaks) = (lists("z"), lists("params"), lists("peaks_camera_m"));
        let fitted = lists("fitted_corners_camera_m");
        let (lp, lq, lw) = (
            f64s("log_nominal"),
            f64s("log_proposal"),
            f64s("log_weight"),
        );
        let (valid, reason, visible, detected, fit_error) = (
            bools("valid"),
            strings("invalid_reason"),
            col("target_visible_fraction")
                .as_primitive::<Float32Type>()
                .clone(),
            bools("detected"),
            strings("fit_error"),
        );
        let metrics: Vec<_> = [
            "paper_error",
            "paper_error_normalized",
            "mssd_over_diameter",
            "cube_mssd_over_diameter",
            "add_s_m",
            "rotation_error_deg",
            "translation_error_m",
            "score",
            "fit_confidence",
        ]
        .iter()
        .map(|n| f64s(n))
        .collect();
        let failed = bools("failed");
        let list = |l: &ListArray, i: usize| {
            l.is_valid(i)
                .then(|| l.value(i).as_primitive::<Float64Type>().values().to_vec())
        };
        let opt = |a: &Float64Array, i: usize| a.is_valid(i).then(|| a.value(i));
        for i in 0..batch.num_rows() {
            rows.push(SampleRow {
                sample_id: ids.value(i),
                sampler: sampler.value(i).into(),
                stage: stage.value(i).into(),
                iteration: iteration.value(i),
                stratum: stratum.value(i),
                seed: seed.value(i),
                z: list(&z, i).unwrap_or_default(),
                params: list(&params, i).unwrap_or_default(),
                log_nominal: lp.value(i),
                log_proposal: lq.value(i),
                log_weight: lw.value(i),
                valid: valid.value(i),
                invalid_reason: reason.is_valid(i).then(|| reason.value(i).to_string()),
                target_visible_fraction: visible.is_valid(i).then(|| visible.value(i)),
                detected: detected.is_valid(i).then(|| detected.value(i)),
                fit_error: fit_error
                    .is_valid(i)
                    .then(|| fit_error.value(i).to_string()),
                paper_error: opt(&metrics[0], i),
                paper_error_normalized: opt(&metrics[1], i),
                mssd_over_diameter: opt(&metrics[2], i),
                cube_mssd_over_diameter: opt(&metrics[3], i),
                add_s_m: opt(&metrics[4], i),
                rotation_error_deg: opt(&metrics[5], i),
                translation_error_m: opt(&metrics[6], i),
                score: opt(&metrics[7], i),
                failed: failed.value(i),
                fit_confidence: opt(&metrics[8], i),
                peaks_camera_m: list(&peaks, i),
                fitted_corners_camera_m: list(&fitted, i),
            });
        }
    }
    Ok(rows)
}

fn read_timings(path: &Path) -> Result<Vec<TimingRow>> {
    let mut rows = Vec::new();
    for batch in boxpose_data::read_shard(path, &SEARCH_TIMINGS)? {
        let f = |name: &str| {
            batch
                .column_by_name(name)
                .expect("validated")
                .as_primitive::<Float64Type>()
                .clone()
        };
        let ids = batch
            .column_by_name("sample_id")
            .expect("validated")
            .as_primitive::<Int64Type>()
            .clone();
        let (settle, render, inference, fit) =
            (f("settle_s"), f("render_s"), f("inference_s"), f("fit_s"));
        for i in 0..batch.num_rows() {
            rows.push(TimingRow {
                sample_id: ids.value(i),
                settle_s: settle.value(i),
                render_s: render.value(i),
                inference_s: inference.value(i),
                fit_s: fit.value(i),
            });
        }
    }
    Ok(rows)
}

/// Writes failing samples as a dataset shard per table (`boxpose render DIR --scene SAMPLE_ID`
/// re-renders one; `boxpose predict DIR --scene SAMPLE_ID` reruns the pipeline on it).
fn write_counterexamples(dir: &Path, name: &str, outcomes: &[Outcome]) -> Result<()> {
    let scenes: Vec<Scene> = outcomes.iter().map(|o| o.scene.clone()).collect();
    let objects: Vec<Object> = outcomes.iter().flat_map(|o| o.objects.clone()).collect();
    let (frames, instances): (Vec<RecordBatch>, Vec<RecordBatch>) =
        outcomes.iter().filter_map(|o| o.rendered.clone()).unzip();
    boxpose_data::write_shard(dir, &schema::SCENES, name, &[Scene::to_batch(&scenes)])?;
    boxpose_data::write_shard(dir, &schema::OBJECTS, name, &[Object::to_batch(&objects)])?;
    boxpose_data::write_shard(dir, &schema::FRAMES, name, &frames)?;
    boxpose_data::write_shard(dir, &schema::INSTANCES, name, &instances)?;
    Ok(())
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
        // Monte Carlo's exact interval needs no warning, however few the failures
        let mc: Vec<WeightedSample> = (0..100).map(|i| sample(0.0, i == 0)).collect();
        assert!(warnings(&ImportanceEstimate::compute_ratio(&mc, &[1.0]).unwrap()).is_empty());
    }

    #[test]
    fn a_run_of_another_search_names_each_setting_that_differs() {
        let record = RunRecord {
            format: RUN_FORMAT,
            settings: RunSettings {
                sampler: Sampler::Ce,
                samples: 100,
                batch_size: 25,
                seed: 3,
                crops: Crops::Gt,
                whole_frames: false,
                fit: "paper".into(),
                predicate: Predicate::default(),
                ce: CeConfig::default(),
                ce_tilt: Vec::new(),
                splitting: None,
                model: "models/keypoint-slim".into(),
                segmenter: None,
                sut: None,
            },
            space_toml: "name = \"single_box\"".into(),
            recipe_toml: String::new(),
            dimensions: Vec::new(),
            strata: vec![0],
            pile: None,
        };
        let mut other = record.clone();
        other.settings.seed = 4;
        other.settings.model = "models/keypoint-slm".into();
        other.settings.ce.defensive_lambda = 0.25;
        other.settings.ce.final_samples += 1;
        let mut found = differences(&record, &other);
        found.sort();
        let lambda = record.settings.ce.defensive_lambda;
        assert_eq!(
            found,
            [
                format!("--ce-lambda is {lambda} there, 0.25 here"),
                "--model is models/keypoint-slim there, models/keypoint-slm here".into(),
                "--seed is 3 there, 4 here".into(),
            ]
        );
        other = record.clone();
        other.space_toml = "name = \"clutter\"".into();
        assert_eq!(differences(&record, &other), ["the search space differs"]);
        // splitting's settings by their flags; its particles are --samples, named once
        let mut split = record.clone();
        split.settings.sampler = Sampler::Splitting;
        split.settings.splitting = Some(SplittingConfig {
            particles: 100,
            ..SplittingConfig::default()
        });
        let mut other = split.clone();
        let settings = other.settings.splitting.as_mut().unwrap();
        settings.level_probability = 0.2;
        settings.particles = 200;
        other.settings.samples = 200;
        let mut found = differences(&split, &other);
        found.sort();
        assert_eq!(
            found,
            [
                "--samples is 100 there, 200 here",
                "--splitting-level-probability is 0.1 there, 0.2 here"
            ]
        );
    }
}
