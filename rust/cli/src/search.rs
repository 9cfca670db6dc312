//! `boxpose search`: the counterexample search — sample scenes from a search space, settle,
//! render and score them end to end, and estimate the pipeline's failure probability (Monte
//! Carlo or cross-entropy importance sampling) with its 95% interval; `search report` draws a
//! run, `search merge` joins the shards of one, `search compare` pairs two runs' samples.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use boxpose_learn::backend::BackendKind;
use boxpose_learn::inference::KeypointModel;
use boxpose_learn::segmentation::SegmenterModel;
use boxpose_search::external::{self, ExternalSut};
use boxpose_search::run::{
    IterationPlan, Observer, Run, RunRecord, RunSettings, SampleRow, Sampler, SplittingSummary,
    StratumSummary, Summary,
};
use boxpose_search::space::SearchSpace;
use boxpose_search::sut::{self, Crops, Predicate};
use boxpose_search::system;
use boxpose_search::variants::VariantDraw;
use boxpose_search_stats::{
    CeConfig, CiMethod, EstimatorKind, ImportanceEstimate, SplittingConfig, clopper_pearson,
};
use indicatif::{ProgressBar, ProgressStyle};

use boxpose_report::search_report;

#[derive(clap::Args)]
#[command(
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    about = "Search for the scenes where the perception pipeline fails, and estimate how rare failure is",
    long_about = "Search for the scenes where the perception pipeline fails, and estimate how rare failure is.\n\n\
        Each sample draws the scene's inputs from the search space (SPACE: a name in configs/search/ or a TOML \
        path; docs/search.md), drops and settles the boxes with MuJoCo (a scene that is not certified stable is \
        counted, never scored), renders it with the embedded Blender, runs the keypoint network on the target box's \
        crop (ground-truth or the segmenter's) and the chosen pose fit, and scores the fit against the truth. \
        A sample fails when its error is above the threshold (--fail-when) or the box is not found.\n\n\
        --sampler mc draws from the nominal distribution and reports the failure probability with the exact \
        Clopper–Pearson interval. --sampler ce (cross-entropy importance sampling) first tunes a proposal towards \
        failures (--ce-* options), then draws --samples fresh samples from the frozen proposal mixed with the \
        nominal, and reports the weighted (ratio) estimate, its 95% interval, the effective sample size and \
        the largest weight's share, with a warning when the weights are too uneven to trust the interval \
        (--ce-tilt keeps parameters the failures do not depend on at their nominal; --ce-tilt auto chooses them \
        by testing which parameters the first tuning iteration's scores depend on). --sampler splitting \
        (subset simulation, adaptive multilevel splitting) draws --samples particles from the nominal, keeps \
        the highest-scoring share --splitting-level-probability of them and grows Markov chains from them \
        that stay above that level, stage after stage, until that share fails: p̂ is the product of the \
        stages' shares, with a log-normal interval that counts the chains' correlation, and each stage's \
        level, share and move acceptance in summary.json (docs/search.md). All estimate \
        P(fail | valid scene) and report P(valid).\n\n\
        The run folder (--out) resumes: re-run the same command after an interruption. Several processes can \
        split one run with --shard/--num-shards (same --out). Failing samples are written as dataset rows in \
        OUT/counterexamples, which `boxpose render` re-renders; `boxpose search replay` runs any sample again.",
    after_help = "Examples:\n  \
        boxpose search single_box --samples 500 --out results/search/mc\n  \
        boxpose search single_box --sampler ce --samples 500 --ce-samples-per-iteration 200 --out results/search/ce\n  \
        boxpose search single_box --sampler splitting --samples 500 --batch-size 50 --out results/search/split\n  \
        boxpose search clutter --crops predicted --fit robust --fail-when mssd:0.1 --out results/search/clutter\n  \
        boxpose search report results/search/ce"
)]
pub struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Draw a finished run: error histogram, estimate against samples spent, where failures sit
    /// in parameter space, the worst counterexamples; one offline HTML page (RUN/report/index.html).
    Report {
        /// Run folder.
        run: PathBuf,
        /// Counterexamples to draw.
        #[arg(long, default_value_t = 6)]
        worst: usize,
    },
    /// Run one sample of a run again, end to end, from its stored inputs and seed, and compare
    /// with what the run recorded: does a counterexample still fail (after a change to the
    /// networks or the fits, pass --model)? Draws the replayed frame and a 3D view into --out.
    Replay {
        /// Run folder.
        run: PathBuf,
        /// The sample's id (the samples table's sample_id; counterexamples' scene_id).
        #[arg(long)]
        sample: i64,
        /// Keypoint network to replay with (default: the run's).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Folder for the replayed frame's overlay and 3D view.
        #[arg(long, default_value = "results/replay")]
        out: PathBuf,
        /// Cycles threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
        backend: BackendKind,
    },
    /// A training dataset around a run's counterexamples: for each failing sample, scenes whose
    /// inputs are its own moved by Gaussian noise (in the space's standard-normal coordinates),
    /// settled and rendered as whole frames like the run's. Fine-tune on it mixed with the
    /// original data: `boxpose train --init MODEL --dataset ORIGINAL --dataset OUT`. One shard per
    /// failure: an interrupted command resumes where it stopped.
    Variants {
        /// Run folder.
        run: PathBuf,
        /// Dataset folder to write (scenes, objects, frames, instances).
        #[arg(long)]
        out: PathBuf,
        /// Scenes drawn around each failing sample.
        #[arg(long, default_value_t = 8)]
        per_failure: usize,
        /// Standard deviation of the move, in the space's standard-normal coordinates (0: the
        /// failing scene itself, K times).
        #[arg(long, default_value_t = 0.3)]
        sigma: f64,
        /// Seed of the moves.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Cycles threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
        backend: BackendKind,
    },
    /// Merge a run's batches (after every shard finished) into samples.parquet, timings.parquet
    /// and summary.json, and print the estimate.
    Merge {
        /// Run folder.
        run: PathBuf,
    },
    /// Compare two Monte Carlo runs of one search, sample by sample: the same space, seed and
    /// settings, the networks or the fit changed (common random numbers: sample i is the same
    /// scene in both). Prints the failure rate before and after over the paired samples with
    /// their 95% intervals, the discordant pairs (fixed: failed before only; new: failed after
    /// only) and McNemar's exact p-value.
    #[command(after_help = "Example:
          boxpose search shift_size --samples 1000 --seed 5 --out results/before
          boxpose search shift_size --samples 1000 --seed 5 --model runs/tuned/model --out results/after
          boxpose search compare results/before results/after --json results/compare.json")]
    Compare {
        /// The run before the change.
        before: PathBuf,
        /// The run after it.
        after: PathBuf,
        /// Also write the comparison (and the fixed and new sample ids) to this JSON file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Check that independent runs of one search agree: each run's estimate with its 95 %
    /// interval, and an error (exit status 1) when two intervals do not overlap — at least one
    /// run missed failures the other found (an importance sampler that never drew a failure
    /// mode) or claims too narrow an interval. The runs must estimate the same event (space,
    /// recipe, crops, networks or --sut, fit, predicate); sampler, seed and budget may differ.
    #[command(after_help = "Example:
          boxpose search single_box --sampler ce --ce-tilt auto --seed 1 --out results/ce1
          boxpose search single_box --sampler splitting --seed 2 --out results/split2
          boxpose search agree results/ce1 results/split2 --json results/agree.json")]
    Agree {
        /// Finished run folders (two or more).
        #[arg(required = true, num_args = 2..)]
        runs: Vec<PathBuf>,
        /// Also write the estimates and the disagreeing pairs to this JSON file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Serve this project's pipeline (keypoint network and fit, ground-truth crops) as an external
    /// system under test on stdin and stdout, protocol boxpose-sut/1: the protocol's reference,
    /// whose samples equal the built-in path's (`--whole-frames`). Not for a terminal.
    #[command(after_help = "Example:
          boxpose search single_box --samples 50 --sut 'exec:boxpose search serve --fit robust' --out results/via-protocol")]
    Serve {
        /// Keypoint network folder.
        #[arg(long, default_value = "models/keypoint-slim", value_parser = crate::shipped_path)]
        model: PathBuf,
        /// The pose fit: paper, fast, robust or size.
        #[arg(long, default_value = "paper", value_parser = clap::builder::PossibleValuesParser::new(sut::FIT_NAMES))]
        fit: String,
        #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
        backend: BackendKind,
    },
}

#[derive(clap::Args)]
struct RunArgs {
    /// Search space: a name in configs/search/ (single_box, clutter) or a TOML path.
    #[arg(required = true)]
    space: Option<String>,
    /// Run folder (created, or resumed when it holds the same search).
    #[arg(long, required = true)]
    out: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "mc")]
    sampler: SamplerArg,
    /// Monte Carlo: samples in all. Cross-entropy: samples from the frozen proposal (the estimate);
    /// its tuning samples come on top. Splitting: particles per stage (N; N × the level
    /// probability must be a whole number).
    #[arg(long, default_value_t = 200)]
    samples: usize,
    /// Samples per batch: the unit of resumption (a kill loses at most one batch) and of sharding.
    #[arg(long, default_value_t = 25)]
    batch_size: usize,
    /// Run seed: sample i's inputs depend on (seed, iteration, i) only.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where the keypoint network's crop comes from: the target's ground-truth box, or the segmenter.
    #[arg(long, value_enum, default_value = "gt")]
    crops: Crops,
    /// Render whole frames at the recipe's resolution, the reference for `make bench-search`. By
    /// default a sample renders only what its perception reads: with ground-truth crops the
    /// region the network's window reaches; with segmenter crops the whole frame at the
    /// segmenter's input width, then the network's window around the detection at full
    /// resolution.
    #[arg(long)]
    whole_frames: bool,
    /// Lay the fitted pose on the depth image: Gauss–Newton on the points of the box's visible
    /// faces inside its projection (a known-size fit only; a refinement that would turn the box
    /// by more than 10° is discarded). With `--fit robust` the depth image first chooses among
    /// the poses the fit's peaks allow (docs/geometry.md). A setting of the run, kept in run.json.
    #[arg(long, conflicts_with = "sut")]
    refine_depth: bool,
    /// Perceive the simulated structured-light depth instead of the exact render depth: the
    /// recipe's sensor model (projector shadows, no return at depth edges and grazing angles,
    /// disparity noise growing with depth²), read by the network, the mirror check,
    /// --refine-depth and a --sut alike. Poses are still scored against the exact truth. A
    /// setting of the run, kept in run.json.
    #[arg(long)]
    sensor_depth: bool,
    /// The pose fit under test: paper (the paper's search over the 5 best peaks), fast, robust, size.
    #[arg(long, default_value = "paper", value_parser = clap::builder::PossibleValuesParser::new(sut::FIT_NAMES))]
    fit: String,
    /// Failure predicate: paper[:T] (the paper's error over diag²/3 above T, default 0.005),
    /// cube-mssd[:F] (the corners' real displacement, the cube-group corner MSSD, above F ×
    /// diameter, default 0.1: the primary correctness metric) or mssd[:F] (the exact-symmetry
    /// MSSD, which also fails a quarter turn of a nearly square box); not detecting the box is a
    /// failure either way.
    #[arg(long, default_value = "paper", value_parser = Predicate::parse)]
    fail_when: Predicate,
    /// Keypoint network folder.
    #[arg(long, default_value = "models/keypoint-slim", value_parser = crate::shipped_path)]
    model: PathBuf,
    /// Test another perception system instead of this project's networks and fit:
    /// `exec:COMMAND` (a long-lived process speaking boxpose-sut/1 on stdin and stdout) or
    /// `python:MODULE:CALLABLE` (a Python function of one request, served by `python3 -m
    /// boxpose_io.sut`). It gets each sample's whole frame (RGB, depth, intrinsics, the target's
    /// true size; with --crops gt its visible box and mask) and answers a pose (docs/search.md).
    /// A crash or timeout is counted apart, never scored; the process is started again.
    #[arg(long, value_name = "SPEC", conflicts_with_all = ["fit", "whole_frames"])]
    sut: Option<String>,
    /// Seconds the --sut process may take to answer one sample (or to start).
    #[arg(long, default_value_t = 60.0, value_name = "SECONDS", requires = "sut")]
    sut_timeout: f64,
    /// Segmenter folder (with --crops predicted).
    #[arg(long, default_value = "models/segmenter-slim", value_parser = crate::shipped_path)]
    segmenter: PathBuf,
    /// Cross-entropy: samples per tuning iteration.
    #[arg(long, default_value_t = 100)]
    ce_samples_per_iteration: usize,
    /// Cross-entropy: most tuning iterations (fewer when the failure level is reached).
    #[arg(long, default_value_t = 8)]
    ce_max_iterations: u32,
    /// Cross-entropy: elite quantile ρ (the top 1 − ρ of scores move the proposal).
    #[arg(long, default_value_t = 0.9)]
    ce_rho: f64,
    /// Cross-entropy: smoothing α of each update (1 = no smoothing).
    #[arg(long, default_value_t = 0.8)]
    ce_alpha: f64,
    /// Cross-entropy: the nominal's weight λ in the frozen proposal (weights stay below 1/λ).
    #[arg(long, default_value_t = 0.1)]
    ce_lambda: f64,
    /// Cross-entropy: Gaussian mixture components of the proposal (more where failures are multimodal).
    #[arg(long, default_value_t = 1)]
    ce_components: usize,
    /// Cross-entropy: tilt only these parameters (comma-separated names or prefixes, e.g.
    /// `target.size_m,target.orientation`); the others keep their nominal and add no weight
    /// variance. `auto`: tilt those the nominal tuning iterations' scores depend on (a rank test
    /// per parameter at family-wise level 1 %, repeated on every nominal sample so far until one
    /// shows; if none ever does, the estimate is plain Monte Carlo's; summary.json's `ce_tilt`
    /// lists every test). Default: all.
    #[arg(long, value_delimiter = ',')]
    ce_tilt: Vec<String>,
    /// Splitting: the share p₀ of each stage's particles above the next level (Au & Beck: 0.1).
    #[arg(long, default_value_t = 0.1)]
    splitting_level_probability: f64,
    /// Splitting: most stages, the first included (p₀ to this power bounds the smallest p it reaches).
    #[arg(long, default_value_t = 10)]
    splitting_max_levels: u32,
    /// Splitting: the move acceptance its step size adapts towards.
    #[arg(long, default_value_t = 0.3)]
    splitting_target_acceptance: f64,
    /// Splitting: the correlation ρ of the first stage's moves (z' = ρ z + √(1 − ρ²) ξ).
    #[arg(long, default_value_t = 0.8)]
    splitting_initial_rho: f64,
    /// Splitting: the probability that a move keeps its chain's scene seed — what the space does
    /// not search (the box's appearance, mass and friction, the render's noise) — instead of
    /// drawing a new one. Runs begun before 2026-12-07 drew a new one at every move: resume one
    /// with 0.
    #[arg(long, default_value_t = SplittingConfig::default().keep_scene_seed)]
    splitting_keep_scene_seed: f64,
    /// Print the work a scheduler can hand out now as one JSON line (the current iteration, its
    /// uncommitted batches, whether the run is complete), passing every finished iteration's
    /// cross-entropy barrier first, and exit: what `python -m boxpose_ray search` asks between
    /// batches.
    #[arg(long, conflicts_with_all = ["shard", "num_shards", "batch"])]
    pending: bool,
    /// Run only batch INDEX of iteration ITERATION (`ITERATION:INDEX`, as `--pending` lists
    /// them) and exit without merging: one task of a scheduler. A committed batch is skipped.
    #[arg(long, value_name = "ITERATION:INDEX", value_parser = parse_batch,
          conflicts_with_all = ["shard", "num_shards"])]
    batch: Option<(u32, usize)>,
    /// This process's shard (batches b with b mod N = shard).
    #[arg(long, default_value_t = 0)]
    shard: usize,
    /// Processes splitting the run.
    #[arg(long, default_value_t = 1)]
    num_shards: usize,
    /// Cycles threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Folder of the base recipes the spaces name.
    #[arg(long, default_value = "datasets/recipes", value_parser = crate::shipped_path)]
    recipes: PathBuf,
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum SamplerArg {
    /// Naive Monte Carlo from the nominal distribution.
    Mc,
    /// Cross-entropy adaptive importance sampling.
    Ce,
    /// Subset simulation (adaptive multilevel splitting) with level-preserving Markov chains.
    Splitting,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.command {
        Some(Command::Report { run, worst }) => write_report(run, *worst),
        Some(Command::Replay {
            run,
            sample,
            model,
            out,
            threads,
            backend,
        }) => replay(run, *sample, model.as_deref(), out, *threads, *backend),
        Some(Command::Variants {
            run,
            out,
            per_failure,
            sigma,
            seed,
            threads,
            backend,
        }) => variants(
            run,
            out,
            &VariantDraw {
                per_failure: *per_failure,
                sigma: *sigma,
                seed: *seed,
            },
            *threads,
            *backend,
        ),
        Some(Command::Merge { run }) => {
            let run = Run::open(run)?;
            let summary = run.merge()?;
            print_summary(&run.dir, &summary);
            // the report draws the merged tables, and names the folder it is in now
            write_report(&run.dir, 6)
        }
        Some(Command::Compare {
            before,
            after,
            json,
        }) => compare(before, after, json.as_deref()),
        Some(Command::Agree { runs, json }) => agree(runs, json.as_deref()),
        Some(Command::Serve {
            model,
            fit,
            backend,
        }) => serve(model, fit, *backend),
        None => search(&args.run),
    }
}

/// `search serve`: the own pipeline behind the protocol, until stdin ends.
fn serve(model: &Path, fit: &str, backend: BackendKind) -> anyhow::Result<()> {
    let method = sut::method_named(fit).map_err(anyhow::Error::msg)?;
    let network = KeypointModel::load(model, backend.device()?)
        .with_context(|| format!("--model {}", model.display()))?;
    let name = format!(
        "boxpose {} ({}, fit {fit})",
        env!("CARGO_PKG_VERSION"),
        model.display()
    );
    let stdin = std::io::stdin().lock();
    external::serve(&name, stdin, std::io::stdout().lock(), |request| {
        sut::own_answer(&network, method, request)
    })?;
    Ok(())
}

fn compare(before: &Path, after: &Path, json: Option<&Path>) -> anyhow::Result<()> {
    let comparison = boxpose_search::compare::compare(&Run::open(before)?, &Run::open(after)?)?;
    let rate = |r: &boxpose_search::compare::Rate| {
        format!(
            "{:.3e} [{:.2e}, {:.2e}] ({} of {})",
            r.p_hat, r.ci95.0, r.ci95.1, r.failures, r.samples
        )
    };
    let c = &comparison;
    println!(
        "{} paired samples (valid in both runs; {} unpaired)\n  before {}  {}\n  after  {}  {}\n  \
         fixed {} (failed before only), new {} (failed after only), failed both {}\n  \
         McNemar exact p = {:.3e}",
        c.pairs,
        c.unpaired,
        rate(&c.before),
        before.display(),
        rate(&c.after),
        after.display(),
        c.fixed.len(),
        c.new.len(),
        c.failed_both,
        c.mcnemar_p,
    );
    if let Some(path) = json {
        boxpose_data::write_file_atomically(path, serde_json::to_string_pretty(c)?.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn agree(runs: &[PathBuf], json: Option<&Path>) -> anyhow::Result<()> {
    let runs = runs
        .iter()
        .map(|dir| Run::open(dir))
        .collect::<Result<Vec<_>, _>>()?;
    let a = boxpose_search::compare::agreement(&runs)?;
    for e in &a.estimates {
        println!(
            "{}: {}, seed {}, p̂ {:.3e} [{:.2e}, {:.2e}], {} samples{}",
            e.run.display(),
            e.sampler.name(),
            e.seed,
            e.p_hat,
            e.ci95.0,
            e.ci95.1,
            e.samples_spent,
            if e.warnings.is_empty() {
                String::new()
            } else {
                format!(" ({} warnings of its own)", e.warnings.len())
            }
        );
    }
    if let Some(path) = json {
        boxpose_data::write_file_atomically(path, serde_json::to_string_pretty(&a)?.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let name = |i: usize| a.estimates[i].run.display().to_string();
    for &(i, j) in &a.same_seed {
        println!(
            "warning: {} and {} use the same sampler and seed: the same samples, not independent \
             evidence; run one again with another --seed",
            name(i),
            name(j)
        );
    }
    if let Some(pairs) = (!a.disjoint.is_empty()).then_some(&a.disjoint) {
        let listed: Vec<String> = pairs
            .iter()
            .map(|&(i, j)| format!("{} and {}", name(i), name(j)))
            .collect();
        anyhow::bail!(
            "the runs disagree: the 95 % intervals of {} do not overlap — at least one missed \
             failures the other found (a failure mode its proposal never drew) or claims too narrow \
             an interval; trust neither alone, and look at where each found its failures \
             (`boxpose search report`)",
            listed.join(", ")
        );
    }
    println!(
        "the {} runs agree: every two 95 % intervals overlap",
        a.estimates.len()
    );
    Ok(())
}

fn search(args: &RunArgs) -> anyhow::Result<()> {
    let space_name = args.space.as_deref().context("give a search space")?;
    let out = args
        .out
        .as_deref()
        .context("give a run folder with --out")?;
    let space = SearchSpace::load(space_name, &args.recipes)?;
    // everything that can be refused is checked before run.json is written (a refused command
    // leaves no run behind to refuse the corrected one) and before the networks and Blender load
    let record = RunRecord::new(&space, run_settings(args))?;
    check_run_args(args)?;
    // another system under test starts (and introduces itself) before the run folder is made
    let mut external = match (&args.sut, args.pending) {
        (Some(spec), false) => Some(ExternalSut::start(
            spec,
            Duration::from_secs_f64(args.sut_timeout),
        )?),
        _ => None,
    };
    let run = Run::create(out, record)?;
    if args.pending {
        println!("{}", serde_json::to_string(&run.pending()?)?);
        return Ok(());
    }
    let load_system = |external| {
        system::load(
            &space,
            &run.record.settings,
            None,
            external,
            args.threads,
            args.backend,
        )
    };
    if let Some((iteration, batch)) = args.batch {
        let mut sut = load_system(external.take())?;
        let ran = run.sample_batch(&space, &mut sut, iteration, batch, &mut Silent)?;
        let what = if ran { "done" } else { "was already done" };
        println!("batch {iteration}:{batch} {what}");
        return Ok(());
    }
    let _shard_lock = run.lock_shard(args.shard, args.num_shards)?;
    if run.complete()? {
        println!("{}: every batch is already done", out.display());
        if args.shard != 0 {
            return Ok(()); // shard 0 merges
        }
    } else {
        let mut sut = load_system(external.take())?;
        let mut progress = Progress::new();
        run.sample(&space, &mut sut, args.shard, args.num_shards, &mut progress)?;
        progress.bar.finish_and_clear();
        // shard 0 merges (it waits for the others): two merging processes would race
        if args.shard != 0 || !run.complete()? {
            println!(
                "shard {} of {} done; shard 0 merges once every shard has finished (or run `boxpose search merge {}`)",
                args.shard,
                args.num_shards,
                out.display()
            );
            return Ok(());
        }
    }
    let summary = run.merge()?;
    print_summary(out, &summary);
    write_report(out, 6)
}

/// `RUN/report/` with the `worst` counterexamples drawn, and where it is.
fn write_report(run: &Path, worst: usize) -> anyhow::Result<()> {
    let page = search_report::write(run, worst)?;
    println!("report: {}", page.display());
    Ok(())
}

/// A merged run's levels or tilt, estimate and warnings.
fn print_summary(out: &Path, summary: &Summary) {
    if let Some(splitting) = &summary.splitting {
        print_levels(splitting);
    }
    if let Some(tilt) = &summary.ce_tilt {
        let tilted = tilt.tilted();
        println!(
            "cross-entropy tilted {} (chosen from {} valid nominal samples)",
            match tilted.is_empty() {
                true => "nothing".to_string(),
                false => tilted.join(", "),
            },
            tilt.samples
        );
    }
    print_estimate(out, &summary.estimate, summary.samples_spent);
    print_strata(&summary.strata);
    print_warnings(&summary.warnings);
}

/// Each stratum's own estimate, when there are several (clutter's numbers of neighbours).
fn print_strata(strata: &[StratumSummary]) {
    if strata.len() < 2 {
        return;
    }
    for s in strata {
        let estimate = match (s.p_hat, s.ci95) {
            (Some(p), Some((lo, hi))) => format!("{p:.3e}  95% CI [{lo:.3e}, {hi:.3e}]"),
            (Some(p), None) => format!("{p:.3e}"),
            _ => "no valid sample".to_string(),
        };
        println!(
            "  {} neighbours: {estimate}  ({} failing of {} valid)",
            s.neighbours, s.failures, s.valid
        );
    }
}

/// The run's settings from the command line: with another system under test, the networks and
/// the fit are its own.
fn run_settings(args: &RunArgs) -> RunSettings {
    let crops = args.crops;
    RunSettings {
        sampler: match args.sampler {
            SamplerArg::Mc => Sampler::Mc,
            SamplerArg::Ce => Sampler::Ce,
            SamplerArg::Splitting => Sampler::Splitting,
        },
        samples: args.samples,
        batch_size: args.batch_size,
        seed: args.seed,
        crops,
        whole_frames: args.whole_frames || args.sut.is_some(),
        two_resolutions: crops == Crops::Predicted && !args.whole_frames && args.sut.is_none(),
        refine_depth: args.refine_depth,
        sensor_depth: args.sensor_depth,
        fit: match args.sut {
            Some(_) => EXTERNAL_FIT.into(),
            None => args.fit.clone(),
        },
        predicate: args.fail_when,
        ce: CeConfig {
            samples_per_iteration: args.ce_samples_per_iteration,
            max_iterations: args.ce_max_iterations,
            rho: args.ce_rho,
            alpha: args.ce_alpha,
            defensive_lambda: args.ce_lambda,
            final_samples: args.samples,
            components: args.ce_components,
            ..CeConfig::default()
        },
        ce_tilt: args.ce_tilt.clone(),
        splitting: matches!(args.sampler, SamplerArg::Splitting).then(|| SplittingConfig {
            particles: args.samples,
            level_probability: args.splitting_level_probability,
            target_acceptance: args.splitting_target_acceptance,
            initial_rho: args.splitting_initial_rho,
            keep_scene_seed: args.splitting_keep_scene_seed,
            max_levels: args.splitting_max_levels,
        }),
        // with another system under test, the networks and the fit are its own
        model: match args.sut {
            Some(_) => String::new(),
            None => args.model.display().to_string(),
        },
        segmenter: (crops == Crops::Predicted && args.sut.is_none())
            .then(|| args.segmenter.display().to_string()),
        sut: args.sut.clone(),
    }
}

/// The shard and the system under test's settings, checked before anything loads.
fn check_run_args(args: &RunArgs) -> anyhow::Result<()> {
    boxpose_search::run::check_shard(args.shard, args.num_shards)?;
    if let Some(spec) = &args.sut {
        external::command_of(spec).map_err(anyhow::Error::msg)?;
        anyhow::ensure!(
            args.sut_timeout.is_finite() && args.sut_timeout > 0.0,
            "--sut-timeout {} must be a positive number of seconds",
            args.sut_timeout
        );
    } else {
        KeypointModel::check_folder(&args.model)
            .with_context(|| format!("--model {}", args.model.display()))?;
        if args.crops == Crops::Predicted {
            SegmenterModel::check_folder(&args.segmenter)
                .with_context(|| format!("--segmenter {}", args.segmenter.display()))?;
        }
    }
    Ok(())
}

/// What `fit` records for a run of another system under test (its fit is its own).
const EXTERNAL_FIT: &str = "external";

fn variants(
    run_dir: &Path,
    out: &Path,
    draw: &VariantDraw,
    threads: usize,
    backend: BackendKind,
) -> anyhow::Result<()> {
    // drawn once the run is read and checked: a refused command shows no bar
    let bar = ProgressBar::hidden().with_style(ProgressStyle::with_template(
        "rendering variants {bar:30} {pos}/{len} failures [{elapsed_precise}<{eta_precise}]",
    )?);
    let rendered = boxpose_search::variants::render_around_failures(
        run_dir,
        out,
        draw,
        threads,
        backend,
        |done, total| {
            if bar.is_hidden() {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            }
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )?;
    bar.finish_and_clear();
    println!(
        "{} scenes rendered around {} failures of {} in {}",
        rendered.scenes,
        rendered.failures,
        run_dir.display(),
        out.display()
    );
    println!(
        "fine-tune: boxpose train --init {} --dataset ORIGINAL --dataset {} --out RUN",
        rendered.model,
        out.display()
    );
    Ok(())
}

fn replay(
    run_dir: &Path,
    sample: i64,
    model: Option<&Path>,
    out: &Path,
    threads: usize,
    backend: BackendKind,
) -> anyhow::Result<()> {
    let _claim = boxpose_data::output_folder::claim(out, "--out", "search replay", &[])?;
    let run = Run::open(run_dir)?;
    let (rows, _) = run.rows()?;
    let recorded = rows
        .iter()
        .find(|r| r.sample_id == sample)
        .with_context(|| {
            format!(
                "{}: no sample {sample} (the run holds {} samples)",
                run_dir.display(),
                rows.len()
            )
        })?;
    let space = system::space_of(&run)?;
    let mut sut = system::load(&space, &run.record.settings, model, None, threads, backend)?;
    let (replayed, outcome) = run.replay(&space, &mut sut, recorded)?;
    let describe = |r: &SampleRow| match (r.valid, r.score) {
        (false, _) => format!("invalid ({})", r.invalid_reason.as_deref().unwrap_or("")),
        (true, Some(score)) => format!(
            "{} score {score:.4} (paper error / (diag²/3) {:.3e}, cube MSSD/d {:.3}, MSSD/d {:.3})",
            if r.failed { "FAILS," } else { "passes," },
            r.paper_error_normalized.unwrap_or(f64::NAN),
            r.cube_mssd_over_diameter.unwrap_or(f64::NAN),
            r.mssd_over_diameter.unwrap_or(f64::NAN)
        ),
        (true, None) => format!(
            "FAILS, nothing fitted ({})",
            r.fit_error.as_deref().unwrap_or("not detected")
        ),
    };
    println!(
        "sample {sample} of {}:\n  recorded  {}\n  replayed  {}",
        run_dir.display(),
        describe(recorded),
        describe(&replayed)
    );
    std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
    if let Some((frames, instances)) = &outcome.rendered {
        let frame = boxpose_data::decode_frames(Path::new("<replayed render>"), frames, instances)?
            .remove(0);
        let peaks = outcome.peaks.iter().map(|p| (*p).into()).collect();
        let title = format!("sample {sample}, replayed");
        let overlay = search_report::draw_sample(out, &frame, peaks, &replayed, &title)?;
        println!("  drawn: {}", out.join(overlay).display());
    }
    if recorded.failed != replayed.failed || recorded.valid != replayed.valid {
        println!(
            "  the outcome changed: {}",
            if replayed.failed {
                "it fails now"
            } else {
                "it no longer fails"
            }
        );
    } else {
        println!(
            "  reproduced: it {} as recorded",
            if replayed.failed { "fails" } else { "passes" }
        );
    }
    Ok(())
}

fn print_warnings(warnings: &[String]) {
    for w in warnings {
        println!("  warning: {w}");
    }
}

/// A subset simulation's stages: level, conditional share, correlation and acceptance.
fn print_levels(s: &SplittingSummary) {
    println!("stage  level (score)  share above  γ      chains  acceptance  evaluations");
    for (i, l) in s.levels.iter().enumerate() {
        println!(
            "{i:>5}  {:>13.4}  {:>11.4}  {:<5.2}  {:>6}  {:>10}  {:>11}",
            l.threshold,
            l.conditional_probability,
            l.correlation_factor,
            l.chains,
            l.acceptance_rate
                .map_or("—".to_string(), |a| format!("{:.1}%", 100.0 * a)),
            l.evaluations
        );
    }
    if let Some(e) = &s.estimate {
        println!(
            "P(score > 0) = {:.3e}: coefficient of variation {:.2} (Au & Beck {:.2}, lineages {:.2}); the final failures descend from {} first-stage samples",
            e.p_hat,
            e.coefficient_of_variation,
            e.au_beck_coefficient_of_variation,
            e.lineage_coefficient_of_variation,
            s.distinct_ancestors
        );
    }
}

fn print_estimate(run: &Path, e: &ImportanceEstimate, spent: usize) {
    let ci = e
        .ci95
        .map_or("no interval (no failure)".to_string(), |(lo, hi)| {
            format!("95% CI [{lo:.3e}, {hi:.3e}] ({:?})", e.ci_method)
        });
    let p_valid = if e.valid == e.samples {
        "1 (every sample valid)".to_string()
    } else {
        format!("{:.3} ± {:.3}", e.p_valid, e.p_valid_std_error)
    };
    // weight diagnostics only where the samples carry importance weights
    let weights = match (e.ci_method, e.estimator) {
        (CiMethod::ClopperPearson, _) | (_, EstimatorKind::Splitting) => String::new(),
        _ => format!(
            "; ESS {:.0}, failure ESS {:.1}, largest weight share {:.2}",
            e.kish_ess, e.failure_ess, e.max_weight_share
        ),
    };
    println!(
        "P(fail | valid) = {:.3e}  {ci}\n  {} samples in the estimate ({} valid, {} failing), {spent} spent in all; P(valid) = {p_valid}{weights}",
        e.p_hat, e.samples, e.valid, e.failures
    );
    // counterexamples/ exists once a sample failed
    let counterexamples = if run.join("counterexamples").is_dir() {
        "counterexamples/, "
    } else {
        ""
    };
    println!(
        "run: {}  (samples.parquet, summary.json, {counterexamples}report/index.html)",
        run.display()
    );
}

/// The progress bar: samples/s, failures so far, the running estimate of this iteration's
/// samples (Monte Carlo: p̂ with its Clopper–Pearson interval; the cross-entropy final stage: the
/// ratio estimate Σ w·1{fail} / Σ w·1{valid}), counting the batches already committed.
/// `--batch`: one batch of a scheduler, whose driver draws the progress.
struct Silent;

impl Observer for Silent {}

fn parse_batch(text: &str) -> Result<(u32, usize), String> {
    let parse = || {
        let (iteration, index) = text.split_once(':')?;
        Some((iteration.parse().ok()?, index.parse().ok()?))
    };
    parse().ok_or_else(|| format!("`{text}` is not ITERATION:INDEX (two whole numbers, e.g. 0:3)"))
}

struct Progress {
    bar: ProgressBar,
    stage: String,
    valid: u64,
    failures: u64,
    weight_valid: f64,
    weight_failed: f64,
    total_failures: u64,
    started: Instant,
    /// Where the bar cannot be drawn (stderr not a terminal: a log file, a Ray worker, a CI
    /// job), a plain line every [`PLAIN_PROGRESS_EVERY`] and at the end of each iteration, when
    /// the last one was written.
    plain: Option<Instant>,
}

/// How often a run whose stderr is not a terminal writes a progress line.
const PLAIN_PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

impl Progress {
    fn new() -> Self {
        let bar = ProgressBar::new(0).with_style(
            ProgressStyle::with_template("{prefix} {bar:25} {pos}/{len} samples [{elapsed_precise}<{eta_precise}, {per_sec}] {msg}").expect("a valid template"),
        );
        Self {
            bar,
            stage: String::new(),
            valid: 0,
            failures: 0,
            weight_valid: 0.0,
            weight_failed: 0.0,
            total_failures: 0,
            started: Instant::now(),
            plain: (!std::io::stderr().is_terminal()).then(Instant::now),
        }
    }

    /// The plain progress line, when stderr is not a terminal and it is due.
    fn write_plain(&mut self) {
        let Some(last) = self.plain else { return };
        let (done, total) = (self.bar.position(), self.bar.length().unwrap_or(0));
        if last.elapsed() < PLAIN_PROGRESS_EVERY && done < total {
            return;
        }
        let eta = self.bar.eta().as_secs();
        eprintln!(
            "{}: {done}/{total} samples, {}, ETA {}:{:02}",
            self.bar.prefix(),
            self.bar.message(),
            eta / 60,
            eta % 60
        );
        self.plain = Some(Instant::now());
    }

    fn count(&mut self, row: &SampleRow) {
        let w = row.log_weight.exp();
        self.valid += row.valid as u64;
        self.failures += row.failed as u64;
        self.total_failures += row.failed as u64;
        self.weight_valid += if row.valid { w } else { 0.0 };
        self.weight_failed += if row.failed { w } else { 0.0 };
    }

    fn show(&self) {
        let estimate = match self.stage.as_str() {
            "mc" if self.valid > 0 => {
                let (lo, hi) = clopper_pearson(self.failures, self.valid, 0.95);
                format!(
                    "p̂ {:.2e} [{lo:.1e}, {hi:.1e}]",
                    self.failures as f64 / self.valid as f64
                )
            }
            "final" if self.weight_valid > 0.0 => {
                format!("p̂ ≈ {:.2e}", self.weight_failed / self.weight_valid)
            }
            _ => format!("{} valid", self.valid),
        };
        self.bar.set_message(format!(
            "{} failures, {estimate}, {:.0} s",
            self.total_failures,
            self.started.elapsed().as_secs_f64()
        ));
    }
}

impl Observer for Progress {
    fn iteration(&mut self, iteration: u32, plan: &IterationPlan, done: &[SampleRow]) {
        self.bar.set_length(plan.samples as u64);
        self.bar.set_position(done.len() as u64);
        self.bar.set_prefix(format!("{} {}", plan.stage, iteration));
        if let Some(state) = &plan.splitting {
            self.bar.set_prefix(format!(
                "splitting stage {} step {}",
                state.stage, state.step
            ));
            if let (0, Some(level)) = (state.step, state.levels().last()) {
                self.bar.suspend(|| {
                    println!(
                        "splitting stage {} done: level {:.3} (failure at 0), {:.1}% of its particles above; growing {} chains",
                        state.stage - 1,
                        level.threshold,
                        100.0 * level.conditional_probability,
                        state.candidates().len()
                    )
                });
            }
        }
        self.stage = plan.stage.clone();
        (
            self.valid,
            self.failures,
            self.weight_valid,
            self.weight_failed,
        ) = (0, 0, 0.0, 0.0);
        if let Some(step) = &plan.step {
            self.bar.suspend(|| {
                println!(
                    "cross-entropy iteration {} done: level {:.3} (failure at 0), {} elites{}",
                    iteration - 1,
                    step.level,
                    step.elites,
                    if step.reached {
                        " — failure level reached"
                    } else {
                        ""
                    }
                )
            });
        }
        if plan.stage == "final" {
            self.bar.suspend(|| {
                println!(
                    "frozen proposal: {} fresh samples for the estimate",
                    plan.samples
                )
            });
        }
        for row in done {
            self.count(row);
        }
        self.show();
    }

    fn sample(&mut self, row: &SampleRow) {
        self.bar.inc(1);
        self.count(row);
        self.show();
        self.write_plain();
    }

    fn waiting(&mut self, what: &str) {
        self.bar.set_message(format!("waiting for {what}"));
    }
}
