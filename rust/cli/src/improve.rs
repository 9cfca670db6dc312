//! `boxpose improve`: the options of the closed loop and what it prints; the loop itself is
//! `boxpose_improve::run`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use boxpose_improve::{Observer, Settings};
use boxpose_learn::backend::BackendKind;
use boxpose_report::improve_page::{Round, success_percent};
use boxpose_search::compare::{BoxKey, PairedComparison};

#[derive(clap::Args)]
#[command(
    about = "The closed loop: search → variants → fine-tune → paired evaluation, round after round",
    long_about = "The closed loop: find the pipeline's failures in a search space, learn from them, and show \
        with paired statistics whether the failure rate fell.\n\n\
        Each round: (1) `search SPACE` with the current network (--search-samples, a seed of its own per \
        round); (2) `search variants` around every failure (--per-failure scenes, --sigma); (3) `train \
        --init` from the current network on the counterexamples and variants of this and every earlier \
        round plus --dataset (the original data; the mix is instance by instance, or --learnt-repeat copies of the learnt sets), \
        and with --segmenter-config `train-segmenter --init` from the current segmenter on the same data; (4) a Monte Carlo \
        evaluation of the new networks on --eval-samples fresh samples whose seed no round searched with, \
        the same for every network, paired with the previous network's (`search compare`: p̂ before and \
        after with their intervals, fixed and new failures, McNemar's exact p). A round without failures \
        keeps its network.\n\n\
        RUN/round-NN/{search,variants,train,train-segmenter}, RUN/eval/model-K (network K: 0 is --model), \
        RUN/round-NN/compare.json, RUN/rounds.csv and RUN/report.html (the rounds, linking each network's evaluation report). Re-run the same command to resume; other \
        settings are refused.",
    after_help = "Example:\n  \
        boxpose improve shift_camera_low --model models/keypoint-slim --dataset datasets/generated/train \\\n    \
        --rounds 2 --search-samples 400 --eval-samples 1000 --steps 2000 --out results/improve/low"
)]
pub struct Args {
    /// Search space: a name in configs/search/ or a TOML path.
    space: String,
    /// Run folder (created, or resumed when it holds the same loop).
    #[arg(long)]
    out: PathBuf,
    /// The keypoint network the loop starts from.
    #[arg(long, default_value = "models/keypoint-slim", value_parser = crate::shipped_path)]
    model: PathBuf,
    /// Segmenter folder (with --crops predicted); fine-tuned too with --segmenter-config.
    #[arg(long)]
    segmenter: Option<PathBuf>,
    /// Fine-tune the segmenter too, with this training config (its [segmenter] must be
    /// --segmenter's, e.g. configs/segmenter-slim.toml): every round that learns trains it from
    /// the current segmenter on the same data as the keypoint network (the failing scenes, their
    /// variants and --dataset), so that boxes it missed, merged or split are learnt from; the
    /// round's searches and evaluations then use both new networks. Needs --segmenter and
    /// --crops predicted.
    #[arg(long, value_name = "CONFIG", requires = "segmenter")]
    segmenter_config: Option<PathBuf>,
    /// The segmenter's fine-tuning steps per round (with --segmenter-config).
    #[arg(long, default_value_t = 1000, requires = "segmenter_config")]
    segmenter_steps: usize,
    /// Where the keypoint network's crop comes from: gt or predicted (the segmenter's).
    #[arg(long, default_value = "gt", value_parser = ["gt", "predicted"])]
    crops: String,
    /// The pose fit under test (as `boxpose search --fit`).
    #[arg(long, default_value = "paper")]
    fit: String,
    /// Failure predicate (as `boxpose search --fail-when`).
    #[arg(long, default_value = "paper")]
    fail_when: String,
    /// Rounds of search, variants, fine-tuning and evaluation.
    #[arg(long, default_value_t = 2)]
    rounds: usize,
    /// Monte Carlo samples of each round's search (whose failures are learnt from).
    #[arg(long, default_value_t = 400)]
    search_samples: usize,
    /// Monte Carlo samples of each network's evaluation (fresh inputs, common to all networks).
    #[arg(long, default_value_t = 1000)]
    eval_samples: usize,
    /// Samples per batch of the searches (their unit of resumption).
    #[arg(long, default_value_t = 25)]
    batch_size: usize,
    /// Scenes drawn around each failure (`search variants --per-failure`).
    #[arg(long, default_value_t = 8)]
    per_failure: usize,
    /// Standard deviation of the variants' moves (`search variants --sigma`).
    #[arg(long, default_value_t = 0.3)]
    sigma: f64,
    /// Training config of the fine-tuning (its [network] must be --model's).
    #[arg(long, default_value = "configs/keypoint-slim.toml", value_parser = crate::shipped_path)]
    config: PathBuf,
    /// Original training data, mixed into every fine-tuning (repeatable).
    #[arg(long = "dataset")]
    datasets: Vec<PathBuf>,
    /// The mix: copies per epoch of every counterexample and variant set against one of each
    /// --dataset (`train --repeat`); 1 mixes them instance by instance.
    #[arg(long, default_value_t = 1)]
    learnt_repeat: usize,
    /// Fine-tuning steps per round.
    #[arg(long, default_value_t = 2000)]
    steps: usize,
    /// Fine-tuning learning rate.
    #[arg(long, default_value_t = 3e-4)]
    learning_rate: f64,
    /// Fine-tuning batch size (default: the config's).
    #[arg(long)]
    batch_size_train: Option<usize>,
    /// Seed of the loop: round r searches with seed + 1 + r, every evaluation with seed + 1e6.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Cycles threads of the renders (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Held-out nominal data, evaluated with every network of the loop (`boxpose eval
    /// --held-out N --crops C`) and paired box by box with the network before it (`eval
    /// compare`, the loop's fit, cube MSSD < 0.1 d): a gain on the space that costs the nominal
    /// world shows. Repeatable.
    #[arg(long = "held-out-dataset", value_name = "DATASET")]
    held_out_datasets: Vec<PathBuf>,
    /// The held-out scenes of --held-out-dataset: scene_id % N == 0 (the training config's
    /// val_modulus).
    #[arg(long, value_name = "N", default_value_t = 10, value_parser = clap::value_parser!(u32).range(2..))]
    held_out: u32,
    /// Run the equal-budget control beside the loop: in every round that learns, as many
    /// nominal samples of the space as the loop drew (its search and variants; seed + 2e6 + r),
    /// every one kept, and the same fine-tuning of the control's own networks on them with
    /// --dataset; its networks are evaluated on the same inputs and held-out boxes and paired
    /// with the loop's (RUN/round-NN/control/, RUN/eval/control-K, control-compare.json, the
    /// control columns of rounds.csv): does learning from failures beat learning more of the world?
    #[arg(long)]
    control: bool,
    /// Backend of every step's networks (searches, variants, fine-tuning; a binary built with
    /// it, e.g. `make train BACKEND=tch`'s). Not part of the loop's identity: a resumed loop
    /// may change it.
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

impl Args {
    /// The loop's settings: every option as given.
    fn settings(&self) -> Settings {
        Settings {
            space: self.space.clone(),
            out: self.out.clone(),
            model: self.model.clone(),
            segmenter: self.segmenter.clone(),
            segmenter_config: self.segmenter_config.clone(),
            segmenter_steps: self.segmenter_steps,
            crops: self.crops.clone(),
            fit: self.fit.clone(),
            fail_when: self.fail_when.clone(),
            rounds: self.rounds,
            search_samples: self.search_samples,
            eval_samples: self.eval_samples,
            batch_size: self.batch_size,
            per_failure: self.per_failure,
            sigma: self.sigma,
            config: self.config.clone(),
            datasets: self.datasets.clone(),
            learnt_repeat: self.learnt_repeat,
            steps: self.steps,
            learning_rate: self.learning_rate,
            batch_size_train: self.batch_size_train,
            seed: self.seed,
            threads: self.threads,
            held_out_datasets: self.held_out_datasets.clone(),
            held_out: self.held_out,
            backend: self.backend,
            control: self.control,
        }
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let settings = args.settings();
    let executable = std::env::current_exe().context("finding the boxpose executable")?;
    let last = boxpose_improve::run(&settings, &executable, &mut Printer)?;
    println!(
        "{}: rounds.csv, report.html; the last network is {}{}",
        args.out.display(),
        last.model.display(),
        last.segmenter
            .filter(|_| args.segmenter_config.is_some())
            .map_or(String::new(), |s| format!(
                ", the last segmenter {}",
                s.display()
            ))
    );
    Ok(())
}

/// Prints each step's command line and each round's paired figures.
struct Printer;

impl Observer for Printer {
    fn step(&mut self, arguments: &[String]) {
        println!("$ boxpose {}", arguments.join(" "));
        // before the child's own lines
        let _ = std::io::stdout().flush();
    }

    fn kept(&mut self, round: usize) {
        println!("round {round}: no failure in the search, the networks stay as they are");
    }

    fn held_out(&mut self, round: usize, dataset: &Path, c: &PairedComparison<BoxKey>) {
        println!(
            "round {round}: held-out {}: {} boxes, cube MSSD < 0.1 d {:.1} % → {:.1} %, fixed {}, new {}, McNemar p = {:.3e}",
            dataset.display(),
            c.pairs,
            success_percent(&c.before),
            success_percent(&c.after),
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p
        );
    }

    fn round(&mut self, r: &Round) {
        let c = &r.evaluation;
        println!(
            "round {}: {} search failures{}; on {} paired evaluation samples p̂ {:.3e} \
             [{:.2e}, {:.2e}] → {:.3e} [{:.2e}, {:.2e}], fixed {}, new {}, McNemar p = {:.3e}",
            r.round,
            r.search_failures,
            if r.fine_tuned { " learnt from" } else { "" },
            c.pairs,
            c.before.p_hat,
            c.before.ci95.0,
            c.before.ci95.1,
            c.after.p_hat,
            c.after.ci95.0,
            c.after.ci95.1,
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p,
        );
        if let Some(a) = &r.against_control {
            let c = &a.evaluation;
            println!(
                "round {}: against the equal-budget control's {:.3e} on {} pairs, the loop fixed {} and newly failed {}, McNemar p = {:.3e}",
                r.round,
                c.before.p_hat,
                c.pairs,
                c.fixed.len(),
                c.new.len(),
                c.mcnemar_p
            );
        }
    }
}
