//! `boxpose improve`: the closed loop. Each round searches the space with the current keypoint
//! network, renders variants around every failure, fine-tunes the network on them (with the
//! counterexamples themselves, every earlier round's, and the original data) — and with
//! `--segmenter-config` the segmenter on the same scenes — and judges the new networks against
//! the old on fresh inputs that no round picked variants from: one Monte Carlo
//! evaluation seed for every network, so rounds compare pair by pair (`search compare`).
//!
//! Every step is one `boxpose` command run as a child process in its own folder of the run, and
//! each of those resumes by itself; the loop only decides which step comes next from what the run
//! folder holds. A kill loses at most the step in flight, and the same command resumes.

use std::io::Write;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context;
use boxpose_learn::backend::BackendKind;
use boxpose_search::compare::{PairedComparison, Rate, compare};
use boxpose_search::run::Run;

use boxpose_data::output_folder::{IMPROVE_SETTINGS_FILE as SETTINGS_FILE, refuse_foreign};

/// Search seeds of the rounds are `seed + 1 + round`; the evaluation's is far from them.
const EVALUATION_SEED_OFFSET: u64 = 1_000_000;

/// The networks of one step of the loop: the keypoint network, and the segmenter that crops
/// for it (with --crops predicted).
struct Networks {
    model: PathBuf,
    segmenter: Option<PathBuf>,
}

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
    /// Backend of every step's networks (searches, variants, fine-tuning; a binary built with
    /// it, e.g. `make train BACKEND=tch`'s). Not part of the loop's identity: a resumed loop
    /// may change it.
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
}

impl Args {
    /// Refuses settings the loop cannot run with, before anything is written.
    fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.rounds >= 1, "--rounds must be at least 1");
        anyhow::ensure!(
            self.learnt_repeat >= 1,
            "--learnt-repeat must be at least 1 (one copy of each learnt set per epoch)"
        );
        anyhow::ensure!(
            self.model.join("network.toml").is_file(),
            "--model {}: not a keypoint network folder (no network.toml)",
            self.model.display()
        );
        if self.segmenter_config.is_some() {
            anyhow::ensure!(
                self.crops == "predicted",
                "--segmenter-config fine-tunes the segmenter that crops for the keypoint network: \
                 it needs --crops predicted"
            );
        }
        if let Some(segmenter) = &self.segmenter {
            anyhow::ensure!(
                segmenter.join("segmenter.toml").is_file(),
                "--segmenter {}: not a segmenter folder (no segmenter.toml)",
                segmenter.display()
            );
        }
        let names: std::collections::BTreeSet<String> = self
            .held_out_datasets
            .iter()
            .map(|d| held_out_name(d))
            .collect();
        anyhow::ensure!(
            names.len() == self.held_out_datasets.len(),
            "--held-out-dataset: two datasets with one folder name; their evaluations would share a folder"
        );
        Ok(())
    }

    /// Everything that shapes the loop's results, as recorded in `improve.json`.
    fn settings(&self) -> serde_json::Value {
        let mut settings = serde_json::json!({
            "space": self.space,
            "model": self.model,
            "segmenter": self.segmenter,
            "crops": self.crops,
            "fit": self.fit,
            "fail_when": self.fail_when,
            "rounds": self.rounds,
            "search_samples": self.search_samples,
            "eval_samples": self.eval_samples,
            "batch_size": self.batch_size,
            "per_failure": self.per_failure,
            "sigma": self.sigma,
            "config": self.config,
            "datasets": self.datasets,
            "steps": self.steps,
            "learning_rate": self.learning_rate,
            "batch_size_train": self.batch_size_train,
            "seed": self.seed,
        });
        // recorded only when set, so that loops started before the options resume
        if self.learnt_repeat != 1 {
            settings["learnt_repeat"] = self.learnt_repeat.into();
        }
        if !self.held_out_datasets.is_empty() {
            settings["held_out_datasets"] = serde_json::json!(self.held_out_datasets);
            settings["held_out"] = self.held_out.into();
        }
        if let Some(config) = &self.segmenter_config {
            settings["segmenter_config"] = serde_json::json!(config);
            settings["segmenter_steps"] = self.segmenter_steps.into();
        }
        settings
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    args.check()?;
    let method = boxpose_search::sut::method_named(&args.fit).map_err(anyhow::Error::msg)?;
    refuse_foreign(&args.out, "--out", "improve", &[SETTINGS_FILE])?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let _lock = lock(&args.out)?;
    claim(&args.out, &args.settings())?;

    let mut networks = Networks {
        model: args.model.clone(),
        segmenter: args.segmenter.clone(),
    };
    let mut learnt_from: Vec<PathBuf> = Vec::new();
    let mut rows = Vec::new();
    let mut held_out = Vec::new();
    evaluate(args, 0, &networks)?;
    for round in 0..args.rounds {
        let dir = args.out.join(format!("round-{round:02}"));
        let search = dir.join("search");
        let failures = search_round(args, round, &networks, &search)?;
        let learnt = if failures > 0 {
            let variants = dir.join("variants");
            boxpose(&variants_command(args, round, &search, &variants))?;
            learnt_from.push(search.join("counterexamples"));
            learnt_from.push(variants);
            networks = fine_tune(args, &networks, &learnt_from, &dir)?;
            true
        } else {
            println!("round {round}: no failure in the search, the networks stay as they are");
            false
        };
        evaluate(args, round + 1, &networks)?;
        let comparison = compare(
            &Run::open(&evaluation_dir(args, round))?,
            &Run::open(&evaluation_dir(args, round + 1))?,
        )?;
        boxpose_data::write_file_atomically(
            &dir.join("compare.json"),
            serde_json::to_string_pretty(&comparison)?.as_bytes(),
        )?;
        print_round(round, failures, learnt, &comparison);
        held_out.push(compare_held_out(args, round, method.name(), &dir)?);
        rows.push((round, failures, learnt, comparison));
    }
    write_rounds(&args.out.join("rounds.csv"), &rows)?;
    write_rounds_page(args, &rows, &held_out)?;
    println!(
        "{}: rounds.csv, report.html; the last network is {}{}",
        args.out.display(),
        networks.model.display(),
        networks
            .segmenter
            .filter(|_| args.segmenter_config.is_some())
            .map_or(String::new(), |s| format!(
                ", the last segmenter {}",
                s.display()
            ))
    );
    Ok(())
}

/// An exclusive lock on the run folder while the loop runs: two loops in one folder would start
/// the same steps.
fn lock(out: &Path) -> anyhow::Result<std::fs::File> {
    let path = out.join(".improve.lock");
    let file =
        std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => anyhow::bail!(
            "--out {}: another `boxpose improve` is running in it; wait for it or stop it",
            out.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => Err(e).context(path.display().to_string()),
    }
}

/// Records the settings in a new run folder, or checks that a resumed one has the same, naming
/// every setting that differs.
fn claim(out: &Path, settings: &serde_json::Value) -> anyhow::Result<()> {
    let path = out.join(SETTINGS_FILE);
    if !path.is_file() {
        let text = serde_json::to_string_pretty(settings)?;
        return Ok(boxpose_data::write_file_atomically(&path, text.as_bytes())?);
    }
    let found: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path)?)
        .with_context(|| format!("{}: unreadable", path.display()))?;
    let (Some(found), Some(ours)) = (found.as_object(), settings.as_object()) else {
        anyhow::bail!("{}: not an improve run's settings", path.display());
    };
    let differ: Vec<String> = ours
        .iter()
        .filter(|(key, value)| found.get(*key) != Some(value))
        .map(|(key, value)| {
            let theirs = found.get(key).map_or("none".into(), |v| v.to_string());
            format!(
                "--{} is {theirs} there, {value} here",
                key.replace('_', "-")
            )
        })
        .collect();
    anyhow::ensure!(
        differ.is_empty(),
        "--out {} holds another improve run ({}); resume it with its own settings or choose a new --out",
        out.display(),
        differ.join("; ")
    );
    Ok(())
}

fn evaluation_dir(args: &Args, network: usize) -> PathBuf {
    args.out.join("eval").join(format!("model-{network}"))
}

/// A round's fine-tuning from `networks` on `learnt_from` and --dataset, in `dir`: the keypoint
/// network, and with --segmenter-config the segmenter (each step kept when done); the new networks.
fn fine_tune(
    args: &Args,
    networks: &Networks,
    learnt_from: &[PathBuf],
    dir: &Path,
) -> anyhow::Result<Networks> {
    let train = dir.join("train");
    if !train.join("model").join("network.toml").is_file() {
        boxpose(&train_command(args, &networks.model, learnt_from, &train))?;
    }
    let mut segmenter = networks.segmenter.clone();
    if let (Some(config), Some(current)) = (&args.segmenter_config, &networks.segmenter) {
        let segmenter_train = dir.join("train-segmenter");
        if !segmenter_train
            .join("model")
            .join("segmenter.toml")
            .is_file()
        {
            boxpose(&segmenter_train_command(
                args,
                config,
                current,
                learnt_from,
                &segmenter_train,
            ))?;
        }
        segmenter = Some(segmenter_train.join("model"));
    }
    Ok(Networks {
        model: train.join("model"),
        segmenter,
    })
}

/// The arguments of a Monte Carlo `boxpose search` of the loop's space with `networks`.
fn search_command(
    args: &Args,
    networks: &Networks,
    samples: usize,
    seed: u64,
    out: &Path,
) -> Vec<String> {
    let mut command: Vec<String> = vec![
        "search".into(),
        args.space.clone(),
        "--out".into(),
        path_arg(out),
        "--model".into(),
        path_arg(&networks.model),
        "--samples".into(),
        samples.to_string(),
        "--batch-size".into(),
        args.batch_size.to_string(),
        "--seed".into(),
        seed.to_string(),
        "--crops".into(),
        args.crops.clone(),
        "--fit".into(),
        args.fit.clone(),
        "--fail-when".into(),
        args.fail_when.clone(),
        "--threads".into(),
        args.threads.to_string(),
        "--backend".into(),
        args.backend.name().into(),
    ];
    if let Some(segmenter) = &networks.segmenter {
        command.extend(["--segmenter".into(), path_arg(segmenter)]);
    }
    command
}

/// Round `round`'s search (resumed, or read when done); returns its number of valid failures.
fn search_round(
    args: &Args,
    round: usize,
    networks: &Networks,
    out: &Path,
) -> anyhow::Result<usize> {
    if !out.join("summary.json").is_file() {
        let seed = args.seed + 1 + round as u64;
        boxpose(&search_command(
            args,
            networks,
            args.search_samples,
            seed,
            out,
        ))?;
    }
    let (rows, _) = Run::open(out)?.rows()?;
    Ok(rows.iter().filter(|r| r.valid && r.failed).count())
}

/// Network `network`'s evaluation on the loop's common evaluation inputs and on every held-out
/// dataset (resumed, or kept).
fn evaluate(args: &Args, network: usize, networks: &Networks) -> anyhow::Result<()> {
    let out = evaluation_dir(args, network);
    if !out.join("summary.json").is_file() {
        let seed = args.seed + EVALUATION_SEED_OFFSET;
        boxpose(&search_command(
            args,
            networks,
            args.eval_samples,
            seed,
            &out,
        ))?;
    }
    for dataset in &args.held_out_datasets {
        let out = held_out_dir(args, network, dataset);
        if out.join("summary.json").is_file() {
            continue;
        }
        let mut command: Vec<String> = vec![
            "eval".into(),
            path_arg(dataset),
            "--held-out".into(),
            args.held_out.to_string(),
            "--crops".into(),
            args.crops.clone(),
            "--model".into(),
            path_arg(&networks.model),
            "--out".into(),
            path_arg(&out),
            "--backend".into(),
            args.backend.name().into(),
        ];
        if let Some(segmenter) = &networks.segmenter {
            command.extend(["--segmenter".into(), path_arg(segmenter)]);
        }
        boxpose(&command)?;
    }
    Ok(())
}

/// A held-out dataset's name in the loop's folders: its folder's name.
fn held_out_name(dataset: &Path) -> String {
    dataset
        .file_name()
        .map_or_else(|| path_arg(dataset), |n| n.to_string_lossy().into_owned())
}

fn held_out_dir(args: &Args, network: usize, dataset: &Path) -> PathBuf {
    evaluation_dir(args, network)
        .join("held-out")
        .join(held_out_name(dataset))
}

/// One held-out dataset's pairing of a round's two networks.
type HeldOutComparison = (String, PairedComparison<boxpose_search::compare::BoxKey>);

/// Round `round`'s networks paired box by box on every held-out dataset (`method`'s fit, cube
/// MSSD < 0.1 d), printed and written to the round's `held-out-compare.json`.
fn compare_held_out(
    args: &Args,
    round: usize,
    method: &str,
    dir: &Path,
) -> anyhow::Result<Vec<HeldOutComparison>> {
    let mut comparisons = Vec::new();
    if args.held_out_datasets.is_empty() {
        return Ok(comparisons);
    }
    let mut all = serde_json::Map::new();
    for dataset in &args.held_out_datasets {
        let outcomes = |network: usize| {
            let table = held_out_dir(args, network, dataset).join("eval.parquet");
            boxpose_search::compare::eval_outcomes(&table, method, 0.1)
        };
        let c = boxpose_search::compare::pair(&outcomes(round)?, &outcomes(round + 1)?);
        let success = |r: &boxpose_search::compare::Rate| {
            100.0 * (r.samples - r.failures) as f64 / r.samples.max(1) as f64
        };
        println!(
            "round {round}: held-out {}: {} boxes, cube MSSD < 0.1 d {:.1} % → {:.1} %, fixed {}, new {}, McNemar p = {:.3e}",
            dataset.display(),
            c.pairs,
            success(&c.before),
            success(&c.after),
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p
        );
        all.insert(held_out_name(dataset), serde_json::to_value(&c)?);
        comparisons.push((held_out_name(dataset), c));
    }
    boxpose_data::write_file_atomically(
        &dir.join("held-out-compare.json"),
        serde_json::to_string_pretty(&all)?.as_bytes(),
    )?;
    Ok(comparisons)
}

/// `RUN/report.html`: the rounds at a glance — each round's failure rate before and after on the
/// common evaluation inputs with its interval, the fixed and new failures and McNemar's p, the
/// held-out pairings, and a link to each network's evaluation report (its worst remaining
/// counterexamples, drawn).
fn write_rounds_page(
    args: &Args,
    rows: &[(usize, usize, bool, PairedComparison)],
    held_out: &[Vec<HeldOutComparison>],
) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    let mut h = String::new();
    writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>boxpose improve: {space}</title>\
         <style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}</style></head><body>\
         <h1>The loop on <code>{space}</code></h1><p>From <code>{model}</code>{segmenter}, fit {fit}, {crops} crops; a sample \
         fails when {fail}. Each round is judged on the same {n} evaluation samples (seed {seed}), never searched.</p>",
        space = escape(&args.space),
        model = escape(&args.model.display().to_string()),
        segmenter = match (&args.segmenter, &args.segmenter_config) {
            (Some(s), Some(_)) => format!(
                " and the segmenter <code>{}</code>, both fine-tuned in every round that learns",
                escape(&s.display().to_string())
            ),
            (Some(s), None) => format!(
                " with the segmenter <code>{}</code> (not fine-tuned)",
                escape(&s.display().to_string())
            ),
            _ => String::new(),
        },
        fit = escape(&args.fit),
        crops = escape(&args.crops),
        fail = escape(&args.fail_when),
        n = args.eval_samples,
        seed = args.seed + EVALUATION_SEED_OFFSET,
    )?;
    writeln!(
        h,
        "<table><tr><th>round</th><th>search failures</th><th>fine-tuned</th><th>p̂ before</th>\
         <th>p̂ after</th><th>fixed</th><th>new</th><th>McNemar p</th><th>held out: success before → after (fixed / new, p)</th></tr>"
    )?;
    for ((round, failures, learnt, c), held) in rows.iter().zip(held_out) {
        writeln!(
            h,
            "<tr><td>{round}</td><td>{failures}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3e}</td><td>{}</td></tr>",
            if *learnt { "yes" } else { "no failure" },
            percent(&c.before),
            percent(&c.after),
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p,
            held_out_cell(held)
        )?;
    }
    writeln!(h, "</table><h2>Each network's evaluation</h2><ul>")?;
    for network in 0..=rows.len() {
        writeln!(
            h,
            "<li>network {network}: <a href=\"eval/model-{network}/report/index.html\">its evaluation report</a> \
             (the worst remaining counterexamples, drawn)</li>"
        )?;
    }
    writeln!(h, "</ul></body></html>")?;
    Ok(boxpose_data::write_file_atomically(
        &args.out.join("report.html"),
        h.as_bytes(),
    )?)
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;")
}

/// A failure rate as the rounds page shows it: percent with its interval and counts.
fn percent(r: &Rate) -> String {
    format!(
        "{:.2} % [{:.2}, {:.2}] ({} of {})",
        100.0 * r.p_hat,
        100.0 * r.ci95.0,
        100.0 * r.ci95.1,
        r.failures,
        r.samples
    )
}

/// One round's held-out pairings: each set's success before → after, fixed / new, McNemar's p.
fn held_out_cell(held: &[HeldOutComparison]) -> String {
    let success = |r: &Rate| 100.0 * (r.samples - r.failures) as f64 / r.samples.max(1) as f64;
    held.iter()
        .map(|(name, c)| {
            format!(
                "{}: {:.1} → {:.1} % ({} / {}, {:.2e})",
                escape(name),
                success(&c.before),
                success(&c.after),
                c.fixed.len(),
                c.new.len(),
                c.mcnemar_p
            )
        })
        .collect::<Vec<_>>()
        .join("<br>")
}

fn variants_command(args: &Args, round: usize, search: &Path, out: &Path) -> Vec<String> {
    vec![
        "search".into(),
        "variants".into(),
        path_arg(search),
        "--out".into(),
        path_arg(out),
        "--per-failure".into(),
        args.per_failure.to_string(),
        "--sigma".into(),
        args.sigma.to_string(),
        "--seed".into(),
        (args.seed + round as u64).to_string(),
        "--threads".into(),
        args.threads.to_string(),
        "--backend".into(),
        args.backend.name().into(),
    ]
}

fn train_command(args: &Args, model: &Path, learnt_from: &[PathBuf], out: &Path) -> Vec<String> {
    let step = FineTuning {
        command: "train",
        config: &args.config,
        init: model,
        steps: args.steps,
    };
    let mut command = step.arguments(args, learnt_from, out);
    if let Some(batch) = args.batch_size_train {
        command.extend(["--batch-size".into(), batch.to_string()]);
    }
    command
}

/// The segmenter's fine-tuning from `segmenter` on the keypoint network's data; its batch size
/// is its config's (whole frames, not crops).
fn segmenter_train_command(
    args: &Args,
    config: &Path,
    segmenter: &Path,
    learnt_from: &[PathBuf],
    out: &Path,
) -> Vec<String> {
    let step = FineTuning {
        command: "train-segmenter",
        config,
        init: segmenter,
        steps: args.segmenter_steps,
    };
    step.arguments(args, learnt_from, out)
}

/// One network's fine-tuning step of a round: `boxpose COMMAND --init INIT` with the loop's
/// learning rate and backend on --dataset and the learnt sets.
struct FineTuning<'a> {
    command: &'static str,
    config: &'a Path,
    init: &'a Path,
    steps: usize,
}

impl FineTuning<'_> {
    fn arguments(&self, args: &Args, learnt_from: &[PathBuf], out: &Path) -> Vec<String> {
        let mut command: Vec<String> = vec![
            self.command.into(),
            "--config".into(),
            path_arg(self.config),
            "--init".into(),
            path_arg(self.init),
            "--steps".into(),
            self.steps.to_string(),
            "--learning-rate".into(),
            args.learning_rate.to_string(),
            "--out".into(),
            path_arg(out),
            "--backend".into(),
            args.backend.name().into(),
        ];
        command.extend(training_data(args, learnt_from));
        command
    }
}

/// `--dataset` for --dataset and every learnt set, and the mix (`--repeat`) of a fine-tuning.
fn training_data(args: &Args, learnt_from: &[PathBuf]) -> Vec<String> {
    let mut arguments = Vec::new();
    for dataset in args.datasets.iter().chain(learnt_from) {
        arguments.extend(["--dataset".into(), path_arg(dataset)]);
    }
    if args.learnt_repeat != 1 {
        let counts: Vec<String> = std::iter::repeat_n("1".to_string(), args.datasets.len())
            .chain(std::iter::repeat_n(
                args.learnt_repeat.to_string(),
                learnt_from.len(),
            ))
            .collect();
        arguments.extend(["--repeat".into(), counts.join(",")]);
    }
    arguments
}

fn path_arg(path: &Path) -> String {
    path.to_string_lossy().into_owned()
}

/// Runs `boxpose ARGS` (this executable) and waits for it. The child dies with the loop (a
/// killed loop leaves no step running that would hold its folder's lock on resume).
fn boxpose(arguments: &[String]) -> anyhow::Result<()> {
    println!("$ boxpose {}", arguments.join(" "));
    std::io::stdout().flush()?;
    let executable = std::env::current_exe().context("finding the boxpose executable")?;
    let mut command = Command::new(executable);
    command.args(arguments);
    // SAFETY: prctl is async-signal-safe and touches no memory of the parent.
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let status = command.status().context("starting a boxpose step")?;
    anyhow::ensure!(
        status.success(),
        "the step `boxpose {}` failed ({status}); fix what it says and re-run this command to resume",
        arguments.join(" ")
    );
    Ok(())
}

fn print_round(round: usize, failures: usize, learnt: bool, c: &PairedComparison) {
    println!(
        "round {round}: {failures} search failures{}; on {} paired evaluation samples p̂ {:.3e} \
         [{:.2e}, {:.2e}] → {:.3e} [{:.2e}, {:.2e}], fixed {}, new {}, McNemar p = {:.3e}",
        if learnt { " learnt from" } else { "" },
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
}

/// One row per round: what it learnt from and its paired evaluation.
fn write_rounds(
    path: &Path,
    rows: &[(usize, usize, bool, PairedComparison)],
) -> anyhow::Result<()> {
    let mut text = String::from(
        "round,search_failures,fine_tuned,pairs,failures_before,p_before,p_before_lo,p_before_hi,\
         failures_after,p_after,p_after_lo,p_after_hi,fixed,new,mcnemar_p\n",
    );
    for (round, failures, learnt, c) in rows {
        text.push_str(&format!(
            "{round},{failures},{learnt},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            c.pairs,
            c.before.failures,
            c.before.p_hat,
            c.before.ci95.0,
            c.before.ci95.1,
            c.after.failures,
            c.after.p_hat,
            c.after.ci95.0,
            c.after.ci95.1,
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p,
        ));
    }
    Ok(boxpose_data::write_file_atomically(path, text.as_bytes())?)
}
