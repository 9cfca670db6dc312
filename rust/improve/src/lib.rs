//! The closed loop of `boxpose improve`. Each round searches the space with the current keypoint
//! network, renders variants around every failure, fine-tunes the network on them (with the
//! counterexamples themselves, every earlier round's, and the original data) — and with
//! `--segmenter-config` the segmenter on the same scenes — and judges the new networks against
//! the old on fresh inputs that no round picked variants from: one Monte Carlo
//! evaluation seed for every network, so rounds compare pair by pair (`search compare`).
//!
//! With `--control`, every round that learns is matched by an equal-budget control arm: as many
//! nominal samples of the space as the loop drew (its search and its variants), every one kept as
//! training data, and the same fine-tuning of the control's own networks on them; the loop's
//! networks are then paired with the control's on the same evaluation inputs and held-out boxes,
//! which says whether learning from failures beat learning more of the world.
//!
//! Every step is one `boxpose` command run as a child process in its own folder of the run, and
//! each of those resumes by itself; the loop only decides which step comes next from what the run
//! folder holds. A kill loses at most the step in flight, and the same command resumes.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context;
use boxpose_data::output_folder::{IMPROVE_SETTINGS_FILE as SETTINGS_FILE, refuse_foreign};
use boxpose_learn::backend::BackendKind;
use boxpose_report::improve_page::{
    AgainstControl, LoopSettings, Round, write_rounds_csv, write_rounds_page,
};
use boxpose_search::compare::{BoxKey, PairedComparison, compare};
use boxpose_search::run::Run;

/// Search seeds of the rounds are `seed + 1 + round`; the evaluation's is far from them.
pub const EVALUATION_SEED_OFFSET: u64 = 1_000_000;

/// The control's nominal samples of round `round` are drawn with seed `seed +
/// CONTROL_SEED_OFFSET + round`: apart from the rounds' searches and the evaluation.
pub const CONTROL_SEED_OFFSET: u64 = 2_000_000;

/// The control's predicate: every sample with a pose fails it (a cube MSSD above a billionth of
/// the diameter; a box not found fails any predicate), so its search keeps every valid sample it
/// renders as a dataset row, rendered as the loop's counterexamples are.
const EVERY_SAMPLE_FAILS: &str = "cube-mssd:0.000000001";

/// The networks of one step of the loop: the keypoint network, and the segmenter that crops
/// for it (with predicted crops).
#[derive(Clone, Debug, PartialEq)]
pub struct Networks {
    pub model: PathBuf,
    pub segmenter: Option<PathBuf>,
}

/// Everything the loop runs with; the options of `boxpose improve` of the same names.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Search space: a name in configs/search/ or a TOML path.
    pub space: String,
    /// Run folder.
    pub out: PathBuf,
    /// The keypoint network the loop starts from.
    pub model: PathBuf,
    /// The segmenter that crops for it (with `crops` "predicted").
    pub segmenter: Option<PathBuf>,
    /// The segmenter's training config, when the loop fine-tunes it too.
    pub segmenter_config: Option<PathBuf>,
    pub segmenter_steps: usize,
    /// "gt" or "predicted".
    pub crops: String,
    pub fit: String,
    pub fail_when: String,
    pub rounds: usize,
    pub search_samples: usize,
    pub eval_samples: usize,
    pub batch_size: usize,
    pub per_failure: usize,
    pub sigma: f64,
    /// The keypoint network's training config.
    pub config: PathBuf,
    /// Original training data, mixed into every fine-tuning.
    pub datasets: Vec<PathBuf>,
    /// Copies per epoch of every learnt set against one of each original dataset.
    pub learnt_repeat: usize,
    pub steps: usize,
    pub learning_rate: f64,
    pub batch_size_train: Option<usize>,
    pub seed: u64,
    pub threads: usize,
    pub held_out_datasets: Vec<PathBuf>,
    /// Held-out scenes: scene_id % held_out == 0.
    pub held_out: u32,
    /// Not part of the loop's identity: a resumed loop may change it.
    pub backend: BackendKind,
    /// Run the equal-budget control arm beside the loop (module documentation).
    pub control: bool,
}

/// What the loop tells as it goes (the binary prints it; the library does not).
pub trait Observer {
    /// A step starts: `boxpose ARGUMENTS` as a child process, which prints its own progress.
    fn step(&mut self, arguments: &[String]);
    /// Round `round`'s search found no failure: the networks stay as they are.
    fn kept(&mut self, round: usize);
    /// Round `round`'s networks paired box by box on a held-out dataset.
    fn held_out(&mut self, round: usize, dataset: &Path, comparison: &PairedComparison<BoxKey>);
    /// A round is done and judged.
    fn round(&mut self, round: &Round);
}

impl Settings {
    /// Refuses settings the loop cannot run with, before anything is written.
    pub fn check(&self) -> anyhow::Result<()> {
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
    pub fn identity(&self) -> serde_json::Value {
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
        if self.control {
            settings["control"] = true.into();
        }
        settings
    }

    /// What the rounds page says the loop ran.
    fn loop_settings(&self) -> LoopSettings<'_> {
        LoopSettings {
            space: &self.space,
            model: &self.model,
            segmenter: self
                .segmenter
                .as_deref()
                .map(|s| (s, self.segmenter_config.is_some())),
            fit: &self.fit,
            crops: &self.crops,
            fail_when: &self.fail_when,
            evaluation_samples: self.eval_samples,
            evaluation_seed: self.seed + EVALUATION_SEED_OFFSET,
            control: self.control,
        }
    }
}

/// Runs the loop's next steps until every round is done (a resumed loop skips what its folder
/// holds), each step as a child process of `executable` (the boxpose binary); returns the last
/// networks and writes `rounds.csv` and `report.html`.
pub fn run(
    settings: &Settings,
    executable: &Path,
    observer: &mut dyn Observer,
) -> anyhow::Result<Networks> {
    settings.check()?;
    let method = boxpose_search::sut::method_named(&settings.fit).map_err(anyhow::Error::msg)?;
    refuse_foreign(&settings.out, "--out", "improve", &[SETTINGS_FILE])?;
    std::fs::create_dir_all(&settings.out)
        .with_context(|| format!("creating {}", settings.out.display()))?;
    let _lock = lock(&settings.out)?;
    claim(&settings.out, &settings.identity())?;
    let mut steps = Steps {
        executable,
        observer,
    };

    let mut networks = Networks {
        model: settings.model.clone(),
        segmenter: settings.segmenter.clone(),
    };
    let mut learnt_from: Vec<PathBuf> = Vec::new();
    let mut rounds = Vec::new();
    evaluate(
        settings,
        &mut steps,
        &evaluation_dir(settings, 0),
        &networks,
    )?;
    // the control starts from the same networks, judged by the same first evaluation
    let mut control = settings.control.then(|| ControlArm {
        networks: networks.clone(),
        learnt_from: Vec::new(),
        evaluation: evaluation_dir(settings, 0),
    });
    for round in 0..settings.rounds {
        let dir = settings.out.join(format!("round-{round:02}"));
        let search = dir.join("search");
        let failures = search_round(settings, &mut steps, round, &networks, &search)?;
        let learnt = if failures > 0 {
            let variants = dir.join("variants");
            steps.run(&variants_command(settings, round, &search, &variants))?;
            learnt_from.push(search.join("counterexamples"));
            learnt_from.push(variants);
            networks = fine_tune(settings, &mut steps, &networks, &learnt_from, &dir)?;
            true
        } else {
            steps.observer.kept(round);
            false
        };
        let (before, after) = (
            evaluation_dir(settings, round),
            evaluation_dir(settings, round + 1),
        );
        evaluate(settings, &mut steps, &after, &networks)?;
        let comparison = compare(&Run::open(&before)?, &Run::open(&after)?)?;
        boxpose_data::write_file_atomically(
            &dir.join("compare.json"),
            serde_json::to_string_pretty(&comparison)?.as_bytes(),
        )?;
        let held_out = compare_held_out(
            settings,
            (&before, &after),
            method.name(),
            &dir.join("held-out-compare.json"),
        )?;
        for (dataset, c) in settings.held_out_datasets.iter().zip(&held_out) {
            steps.observer.held_out(round, dataset, &c.1);
        }
        let against_control = match &mut control {
            Some(arm) => {
                let round_drew = settings.search_samples + settings.per_failure * failures;
                let drew = learnt.then_some(round_drew);
                Some(arm.round(settings, &mut steps, round, drew, &after, method.name())?)
            }
            None => None,
        };
        rounds.push(Round {
            round,
            search_failures: failures,
            fine_tuned: learnt,
            evaluation: comparison,
            held_out,
            against_control,
        });
        steps.observer.round(rounds.last().expect("just pushed"));
    }
    write_rounds_csv(&settings.out.join("rounds.csv"), &rounds)?;
    write_rounds_page(
        &settings.out.join("report.html"),
        &settings.loop_settings(),
        &rounds,
    )?;
    Ok(networks)
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

fn evaluation_dir(settings: &Settings, network: usize) -> PathBuf {
    settings.out.join("eval").join(format!("model-{network}"))
}

/// A round's fine-tuning from `networks` on `learnt_from` and --dataset, in `dir`: the keypoint
/// network, and with --segmenter-config the segmenter (each step kept when done); the new networks.
fn fine_tune(
    settings: &Settings,
    steps: &mut Steps,
    networks: &Networks,
    learnt_from: &[PathBuf],
    dir: &Path,
) -> anyhow::Result<Networks> {
    let train = dir.join("train");
    if !train.join("model").join("network.toml").is_file() {
        steps.run(&train_command(
            settings,
            &networks.model,
            learnt_from,
            &train,
        ))?;
    }
    let mut segmenter = networks.segmenter.clone();
    if let (Some(config), Some(current)) = (&settings.segmenter_config, &networks.segmenter) {
        let segmenter_train = dir.join("train-segmenter");
        if !segmenter_train
            .join("model")
            .join("segmenter.toml")
            .is_file()
        {
            steps.run(&segmenter_train_command(
                settings,
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
    settings: &Settings,
    networks: &Networks,
    samples: usize,
    seed: u64,
    out: &Path,
) -> Vec<String> {
    let mut command: Vec<String> = vec![
        "search".into(),
        settings.space.clone(),
        "--out".into(),
        path_arg(out),
        "--model".into(),
        path_arg(&networks.model),
        "--samples".into(),
        samples.to_string(),
        "--batch-size".into(),
        settings.batch_size.to_string(),
        "--seed".into(),
        seed.to_string(),
        "--crops".into(),
        settings.crops.clone(),
        "--fit".into(),
        settings.fit.clone(),
        "--fail-when".into(),
        settings.fail_when.clone(),
        "--threads".into(),
        settings.threads.to_string(),
        "--backend".into(),
        settings.backend.name().into(),
    ];
    if let Some(segmenter) = &networks.segmenter {
        command.extend(["--segmenter".into(), path_arg(segmenter)]);
    }
    command
}

/// Round `round`'s search (resumed, or read when done); returns its number of valid failures.
fn search_round(
    settings: &Settings,
    steps: &mut Steps,
    round: usize,
    networks: &Networks,
    out: &Path,
) -> anyhow::Result<usize> {
    if !out.join("summary.json").is_file() {
        let seed = settings.seed + 1 + round as u64;
        steps.run(&search_command(
            settings,
            networks,
            settings.search_samples,
            seed,
            out,
        ))?;
    }
    let (rows, _) = Run::open(out)?.rows()?;
    Ok(rows.iter().filter(|r| r.valid && r.failed).count())
}

/// The evaluation of `networks` into `out` on the loop's common evaluation inputs and on every
/// held-out dataset (resumed, or kept).
fn evaluate(
    settings: &Settings,
    steps: &mut Steps,
    out: &Path,
    networks: &Networks,
) -> anyhow::Result<()> {
    if !out.join("summary.json").is_file() {
        let seed = settings.seed + EVALUATION_SEED_OFFSET;
        steps.run(&search_command(
            settings,
            networks,
            settings.eval_samples,
            seed,
            out,
        ))?;
    }
    for dataset in &settings.held_out_datasets {
        let out = held_out_dir(out, dataset);
        if out.join("summary.json").is_file() {
            continue;
        }
        let mut command: Vec<String> = vec![
            "eval".into(),
            path_arg(dataset),
            "--held-out".into(),
            settings.held_out.to_string(),
            "--crops".into(),
            settings.crops.clone(),
            "--model".into(),
            path_arg(&networks.model),
            "--out".into(),
            path_arg(&out),
            "--backend".into(),
            settings.backend.name().into(),
        ];
        if let Some(segmenter) = &networks.segmenter {
            command.extend(["--segmenter".into(), path_arg(segmenter)]);
        }
        steps.run(&command)?;
    }
    Ok(())
}

/// A held-out dataset's name in the loop's folders: its folder's name.
fn held_out_name(dataset: &Path) -> String {
    dataset
        .file_name()
        .map_or_else(|| path_arg(dataset), |n| n.to_string_lossy().into_owned())
}

/// Where an evaluation keeps its run on `dataset`'s held-out scenes.
fn held_out_dir(evaluation: &Path, dataset: &Path) -> PathBuf {
    evaluation.join("held-out").join(held_out_name(dataset))
}

/// One held-out dataset's pairing of a round's two networks.
type HeldOutComparison = (String, PairedComparison<BoxKey>);

/// Two evaluations' networks paired box by box on every held-out dataset (`method`'s fit, cube
/// MSSD < 0.1 d), written to `path`.
fn compare_held_out(
    settings: &Settings,
    (before, after): (&Path, &Path),
    method: &str,
    path: &Path,
) -> anyhow::Result<Vec<HeldOutComparison>> {
    let mut comparisons = Vec::new();
    if settings.held_out_datasets.is_empty() {
        return Ok(comparisons);
    }
    let mut all = serde_json::Map::new();
    for dataset in &settings.held_out_datasets {
        let outcomes = |evaluation: &Path| {
            let table = held_out_dir(evaluation, dataset).join("eval.parquet");
            boxpose_search::compare::eval_outcomes(&table, method, 0.1)
        };
        let c = boxpose_search::compare::pair(&outcomes(before)?, &outcomes(after)?);
        all.insert(held_out_name(dataset), serde_json::to_value(&c)?);
        comparisons.push((held_out_name(dataset), c));
    }
    boxpose_data::write_file_atomically(path, serde_json::to_string_pretty(&all)?.as_bytes())?;
    Ok(comparisons)
}

/// The equal-budget control's state as the rounds go: its networks, the nominal sets it learnt
/// from, and the evaluation of its current networks.
struct ControlArm {
    networks: Networks,
    learnt_from: Vec<PathBuf>,
    evaluation: PathBuf,
}

impl ControlArm {
    /// The control's round `round` (each step resumed, or kept): when the loop learnt this
    /// round, having drawn `drew` samples (its search and its variants), as many nominal samples,
    /// every one kept, and the loop's fine-tuning of the control's networks on them and every
    /// earlier round's (with --dataset, the same mix), then their evaluation. Either way the
    /// control's current networks are paired with the loop's of the round (evaluated in
    /// `loop_evaluation`), on the evaluation inputs and every held-out dataset, written to the
    /// round's `control-compare.json` with the control "before" and the loop "after".
    fn round(
        &mut self,
        settings: &Settings,
        steps: &mut Steps,
        round: usize,
        drew: Option<usize>,
        loop_evaluation: &Path,
        method: &str,
    ) -> anyhow::Result<AgainstControl> {
        let dir = settings.out.join(format!("round-{round:02}"));
        if let Some(samples) = drew {
            let control_dir = dir.join("control");
            let nominal = control_dir.join("nominal");
            if !nominal.join("summary.json").is_file() {
                let seed = settings.seed + CONTROL_SEED_OFFSET + round as u64;
                let mut command = search_command(settings, &self.networks, samples, seed, &nominal);
                let predicate = command
                    .iter()
                    .position(|a| a == "--fail-when")
                    .expect("set")
                    + 1;
                command[predicate] = EVERY_SAMPLE_FAILS.into();
                steps.run(&command)?;
            }
            // a search without a valid sample writes no rows: the round adds nothing to learn
            let rows = nominal.join("counterexamples");
            if rows.is_dir() {
                self.learnt_from.push(rows);
            }
            self.networks = fine_tune(
                settings,
                steps,
                &self.networks,
                &self.learnt_from,
                &control_dir,
            )?;
            self.evaluation = settings
                .out
                .join("eval")
                .join(format!("control-{}", round + 1));
            evaluate(settings, steps, &self.evaluation, &self.networks)?;
        }
        let evaluation = compare(&Run::open(&self.evaluation)?, &Run::open(loop_evaluation)?)?;
        let held_out = compare_held_out(
            settings,
            (&self.evaluation, loop_evaluation),
            method,
            &dir.join("control-held-out-compare.json"),
        )?;
        boxpose_data::write_file_atomically(
            &dir.join("control-compare.json"),
            serde_json::to_string_pretty(&evaluation)?.as_bytes(),
        )?;
        Ok(AgainstControl {
            evaluation,
            held_out,
        })
    }
}

fn variants_command(settings: &Settings, round: usize, search: &Path, out: &Path) -> Vec<String> {
    vec![
        "search".into(),
        "variants".into(),
        path_arg(search),
        "--out".into(),
        path_arg(out),
        "--per-failure".into(),
        settings.per_failure.to_string(),
        "--sigma".into(),
        settings.sigma.to_string(),
        "--seed".into(),
        (settings.seed + round as u64).to_string(),
        "--threads".into(),
        settings.threads.to_string(),
        "--backend".into(),
        settings.backend.name().into(),
    ]
}

fn train_command(
    settings: &Settings,
    model: &Path,
    learnt_from: &[PathBuf],
    out: &Path,
) -> Vec<String> {
    let step = FineTuning {
        command: "train",
        config: &settings.config,
        init: model,
        steps: settings.steps,
    };
    let mut command = step.arguments(settings, learnt_from, out);
    if let Some(batch) = settings.batch_size_train {
        command.extend(["--batch-size".into(), batch.to_string()]);
    }
    command
}

/// The segmenter's fine-tuning from `segmenter` on the keypoint network's data; its batch size
/// is its config's (whole frames, not crops).
fn segmenter_train_command(
    settings: &Settings,
    config: &Path,
    segmenter: &Path,
    learnt_from: &[PathBuf],
    out: &Path,
) -> Vec<String> {
    let step = FineTuning {
        command: "train-segmenter",
        config,
        init: segmenter,
        steps: settings.segmenter_steps,
    };
    step.arguments(settings, learnt_from, out)
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
    fn arguments(&self, settings: &Settings, learnt_from: &[PathBuf], out: &Path) -> Vec<String> {
        let mut command: Vec<String> = vec![
            self.command.into(),
            "--config".into(),
            path_arg(self.config),
            "--init".into(),
            path_arg(self.init),
            "--steps".into(),
            self.steps.to_string(),
            "--learning-rate".into(),
            settings.learning_rate.to_string(),
            "--out".into(),
            path_arg(out),
            "--backend".into(),
            settings.backend.name().into(),
        ];
        command.extend(training_data(settings, learnt_from));
        command
    }
}

/// `--dataset` for --dataset and every learnt set, and the mix (`--repeat`) of a fine-tuning.
fn training_data(settings: &Settings, learnt_from: &[PathBuf]) -> Vec<String> {
    let mut arguments = Vec::new();
    for dataset in settings.datasets.iter().chain(learnt_from) {
        arguments.extend(["--dataset".into(), path_arg(dataset)]);
    }
    if settings.learnt_repeat != 1 {
        let counts: Vec<String> = std::iter::repeat_n("1".to_string(), settings.datasets.len())
            .chain(std::iter::repeat_n(
                settings.learnt_repeat.to_string(),
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

/// Runs the loop's steps: `boxpose ARGUMENTS` as a child process of the loop.
struct Steps<'a> {
    executable: &'a Path,
    observer: &'a mut dyn Observer,
}

impl Steps<'_> {
    /// Runs `boxpose ARGUMENTS` and waits for it. The child dies with the loop (a killed loop
    /// leaves no step running that would hold its folder's lock on resume).
    fn run(&mut self, arguments: &[String]) -> anyhow::Result<()> {
        self.observer.step(arguments);
        let mut command = Command::new(self.executable);
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
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(out: &Path) -> Settings {
        Settings {
            space: "single_box".into(),
            out: out.to_path_buf(),
            model: "models/keypoint-slim".into(),
            segmenter: None,
            segmenter_config: None,
            segmenter_steps: 1000,
            crops: "gt".into(),
            fit: "paper".into(),
            fail_when: "paper".into(),
            rounds: 2,
            search_samples: 400,
            eval_samples: 1000,
            batch_size: 25,
            per_failure: 8,
            sigma: 0.3,
            config: "configs/keypoint-slim.toml".into(),
            datasets: vec!["data/a".into(), "data/b".into()],
            learnt_repeat: 1,
            steps: 2000,
            learning_rate: 3e-4,
            batch_size_train: None,
            seed: 0,
            threads: 0,
            held_out_datasets: Vec::new(),
            held_out: 10,
            backend: BackendKind::Flex,
            control: false,
        }
    }

    #[test]
    fn a_resumed_loop_must_have_the_same_settings_and_is_told_which_differ() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = settings(dir.path());
        claim(dir.path(), &s.identity()).unwrap();
        claim(dir.path(), &s.identity()).unwrap();
        // the backend is not part of the identity
        s.backend = BackendKind::Wgpu;
        claim(dir.path(), &s.identity()).unwrap();
        s.steps = 500;
        let err = claim(dir.path(), &s.identity()).unwrap_err().to_string();
        assert!(err.contains("--steps is 2000 there, 500 here"), "{err}");
    }

    #[test]
    fn a_second_loop_in_one_folder_is_refused_while_the_first_holds_it() {
        let dir = tempfile::tempdir().unwrap();
        let first = lock(dir.path()).unwrap();
        let err = lock(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("another `boxpose improve` is running"),
            "{err}"
        );
        drop(first);
        lock(dir.path()).unwrap();
    }

    #[test]
    fn the_mix_repeats_only_the_learnt_sets() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = settings(dir.path());
        let learnt = [
            PathBuf::from("r0/search/counterexamples"),
            PathBuf::from("r0/variants"),
        ];
        let plain = training_data(&s, &learnt);
        assert_eq!(plain.iter().filter(|a| *a == "--dataset").count(), 4);
        assert!(!plain.contains(&"--repeat".to_string()));
        s.learnt_repeat = 3;
        let mixed = training_data(&s, &learnt);
        assert_eq!(mixed[mixed.len() - 2..], ["--repeat", "1,1,3,3"]);
    }

    #[test]
    fn every_network_is_judged_on_one_seed_that_no_round_searches() {
        let dir = tempfile::tempdir().unwrap();
        let s = settings(dir.path());
        let networks = Networks {
            model: "m".into(),
            segmenter: Some("seg".into()),
        };
        let seed_of = |command: &[String]| {
            let i = command.iter().position(|a| a == "--seed").unwrap();
            command[i + 1].parse::<u64>().unwrap()
        };
        let evaluation = search_command(
            &s,
            &networks,
            s.eval_samples,
            s.seed + EVALUATION_SEED_OFFSET,
            dir.path(),
        );
        assert!(evaluation.windows(2).any(|w| w == ["--segmenter", "seg"]));
        for round in 0..s.rounds as u64 {
            let search = search_command(
                &s,
                &networks,
                s.search_samples,
                s.seed + 1 + round,
                dir.path(),
            );
            assert_ne!(seed_of(&search), seed_of(&evaluation));
        }
    }
}
