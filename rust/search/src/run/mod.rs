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

mod plan;
mod record;
mod summary;
mod tables;

pub use plan::*;
pub use record::*;
pub use summary::*;
pub use tables::*;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use boxpose_data::schema::{SEARCH_SAMPLES, SEARCH_TIMINGS, Table};
use boxpose_search_stats::{
    CeError, Proposal, SplittingRun, SplittingState, TiltChoice, ce_step, choose_tilt,
    hold_at_nominal, log_nominal, sample_rng,
};
use rand::Rng;

use crate::error::{Result, SearchError};
use crate::space::SearchSpace;
use crate::sut::{Evaluate, Outcome};

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
            let mut asked = record;
            // a run recorded before two-resolution renders existed goes on as it began: whole
            // frames at full resolution (nothing recorded since stores false where this asks true)
            if !run.record.settings.two_resolutions {
                asked.settings.two_resolutions = false;
            }
            if run.record != asked {
                return Err(SearchError::Run {
                    path: dir.to_path_buf(),
                    problem: format!(
                        "it holds another search ({}); resume it with its own settings or choose a new --out",
                        differences(&run.record, &asked).join("; ")
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
    /// before the first look).
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
        let ce = &self.settings().ce;
        let step_error = |e: CeError| SearchError::Run {
            path: self.dir.clone(),
            problem: format!("cross-entropy step after iteration {iteration}: {e}"),
        };
        let choosing = self.auto_tilt()
            && (iteration == 0 || plan.tilt.as_ref().is_some_and(TiltChoice::undecided));
        // While the tilt is undecided every iteration drew from the nominal: the tests and the
        // step see all of their samples.
        let first = if choosing { 0 } else { iteration };
        let mut rows = Vec::new();
        for i in first..=iteration {
            let samples = match i == iteration {
                true => plan.samples,
                false => self.plan(i)?.map_or(0, |p| p.samples),
            };
            rows.extend(self.iteration_rows(i, self.batches(samples))?);
        }
        let zs: Vec<Vec<f64>> = rows.iter().map(|r| r.z.clone()).collect();
        let scores: Vec<f64> = rows.iter().map(SampleRow::level_score).collect();
        let (current, tilt) = if choosing {
            let dim = self.record.dimensions.len();
            let choice = choose_tilt(
                &zs,
                &scores,
                dim,
                &self.orientation_blocks(),
                AUTO_TILT_ALPHA / f64::from(ce.max_iterations),
            )
            .map_err(step_error)?;
            // The same density as the nominal, with only the chosen blocks shaped as rotations.
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
                // a splitting candidate's z and scene seed come from its chain (the seed kept or
                // drawn afresh: `boxpose_search_stats::splitting`)
                Some(candidates) => {
                    let c = &candidates[index];
                    (c.evaluation as i64, c.z.clone(), c.scene_seed as i64)
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
}
