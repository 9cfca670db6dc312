//! The search's run folder without Blender or networks: a closed-form evaluator (a failure set
//! of known probability in the real `single_box` space) drives Monte Carlo, cross-entropy and
//! subset simulation runs through `Run`, so that resume after an interruption, shards, the
//! barriers and the splitting levels are tested in seconds.

use std::path::{Path, PathBuf};

use boxpose_data::Scene;
use boxpose_search::run::{Observer, Run, RunRecord, RunSettings, Sampler};
use boxpose_search::space::{Parameters, SearchSpace};
use boxpose_search::sut::{Crops, Evaluate, Metrics, Outcome, Perceived, Predicate, StageSeconds};
use boxpose_search::{Result, SearchError};
use boxpose_search_stats::splitting::run_in_memory;
use boxpose_search_stats::{CeConfig, SplittingConfig, normal_cdf};

/// The parameter whose nominal quantile decides failure: `camera.distance_m`, uniform on
/// [0.6, 0.9] in `single_box` (the evaluator reads it as `parameters.camera.distance_m`).
const DECIDING: &str = "camera.distance_m";
const DISTANCE_RANGE: [f64; 2] = [0.6, 0.9];

/// A sample fails iff the deciding parameter's quantile u exceeds 1 − p (probability exactly p
/// under the nominal); its paper's error is 0.005 · 10^(10 (u − (1 − p))), so that the search's
/// score is 10 (u − (1 − p)). `interrupt_after`: the evaluation that errors, as a kill would.
struct ClosedForm {
    p: f64,
    calls: usize,
    interrupt_after: Option<usize>,
    /// The score never below this (a flat error far from failing), if set.
    plateau: Option<f64>,
}

impl ClosedForm {
    fn new(p: f64) -> Self {
        Self {
            p,
            calls: 0,
            interrupt_after: None,
            plateau: None,
        }
    }

    /// The score flat below quantile 1 − `off`: only samples above it show the dependence.
    fn with_plateau(p: f64, off: f64) -> Self {
        Self {
            plateau: Some(10.0 * (p - off)),
            ..Self::new(p)
        }
    }

    fn score_of_quantile(&self, u: f64) -> f64 {
        let score = 10.0 * (u - (1.0 - self.p));
        self.plateau.map_or(score, |floor| score.max(floor))
    }
}

impl Evaluate for ClosedForm {
    fn evaluate(
        &mut self,
        _space: &SearchSpace,
        parameters: &Parameters,
        scene_id: i64,
        seed: i64,
    ) -> Result<Outcome> {
        if self.interrupt_after == Some(self.calls) {
            return Err(SearchError::Sample("interrupted".into()));
        }
        self.calls += 1;
        let [lo, hi] = DISTANCE_RANGE;
        let u = (parameters.camera.distance_m - lo) / (hi - lo);
        let error = 0.005 * 10f64.powf(self.score_of_quantile(u));
        Ok(Outcome {
            result: Ok(Perceived::Fitted(Metrics {
                paper_error: error,
                paper_error_normalized: error,
                mssd_over_diameter: error,
                cube_mssd_over_diameter: error,
                add_s_m: error,
                rotation_error_deg: 0.0,
                translation_error_m: 0.0,
                confidence: Some(1.0),
                fitted_corners: [[0.0; 3]; 8],
            })),
            seconds: StageSeconds::default(),
            scene: Scene {
                scene_id,
                seed,
                recipe: "single_box".into(),
                recipe_toml: String::new(),
                tool_versions: String::new(),
                physics_backend: "closed form".into(),
                support: "floor".into(),
                num_objects: 1,
                solver: String::new(),
                solver_status: String::new(),
                solve_attempts: 0,
                settle_time_s: 0.0,
                max_linear_speed_mps: 0.0,
                max_angular_speed_radps: 0.0,
                min_signed_distance_m: 0.0,
                stable: true,
            },
            objects: Vec::new(),
            rendered: None,
            peaks: Vec::new(),
        })
    }
}

struct Quiet;
impl Observer for Quiet {}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn space() -> SearchSpace {
    let path = repo().join("configs/search/single_box.toml");
    SearchSpace::load(path.to_str().unwrap(), &repo().join("datasets/recipes")).unwrap()
}

fn settings(sampler: Sampler, samples: usize, batch_size: usize) -> RunSettings {
    RunSettings {
        sampler,
        samples,
        batch_size,
        seed: 7,
        crops: Crops::Gt,
        whole_frames: false,
        refine_depth: false,
        sensor_depth: false,
        two_resolutions: false,
        fit: "paper".into(),
        predicate: Predicate::default(),
        ce: CeConfig {
            samples_per_iteration: 200,
            max_iterations: 6,
            final_samples: samples,
            ..CeConfig::default()
        },
        ce_tilt: Vec::new(),
        splitting: (sampler == Sampler::Splitting).then(|| SplittingConfig {
            particles: samples,
            max_levels: 8,
            ..SplittingConfig::default()
        }),
        model: "closed form".into(),
        segmenter: None,
        sut: None,
    }
}

/// Runs a whole search in `dir` with `evaluator`, merged.
fn run(dir: &Path, settings: &RunSettings, evaluator: &mut dyn Evaluate) -> Result<()> {
    let space = space();
    let run = Run::create(dir, RunRecord::new(&space, settings.clone())?)?;
    run.sample(&space, evaluator, 0, 1, &mut Quiet)?;
    run.merge()?;
    Ok(())
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&read(&dir.join("summary.json"))).unwrap()
}

/// Interrupted at evaluation `at` (the batch in flight is lost), then resumed with a fresh
/// evaluator: the tables equal the uninterrupted run's byte for byte.
fn check_resume(sampler: Sampler, samples: usize, batch_size: usize, p: f64, at: usize) {
    check_resume_of(&settings(sampler, samples, batch_size), p, at);
}

fn check_resume_of(s: &RunSettings, p: f64, at: usize) {
    check_resume_of_with(s, || ClosedForm::new(p), at);
}

fn check_resume_of_with(s: &RunSettings, evaluator: impl Fn() -> ClosedForm, at: usize) {
    let root = tempfile::tempdir().unwrap();
    let (sampler, batch_size) = (s.sampler, s.batch_size);
    let whole = root.path().join("whole");
    let mut uninterrupted = evaluator();
    run(&whole, s, &mut uninterrupted).unwrap();
    assert!(
        at < uninterrupted.calls,
        "the interruption falls inside the run"
    );
    let resumed = root.path().join("resumed");
    let mut interrupted = ClosedForm {
        interrupt_after: Some(at),
        ..evaluator()
    };
    assert!(run(&resumed, s, &mut interrupted).is_err(), "interrupted");
    assert!(!resumed.join("samples.parquet").exists());
    let mut fresh = evaluator();
    run(&resumed, s, &mut fresh).unwrap();
    // the committed batches were kept: only the batch in flight is evaluated twice
    assert!(
        fresh.calls < uninterrupted.calls
            && interrupted.calls + fresh.calls - uninterrupted.calls < batch_size,
        "{sampler:?}: {} + {} evaluations against {}",
        interrupted.calls,
        fresh.calls,
        uninterrupted.calls
    );
    for name in ["samples.parquet", "summary.json"] {
        assert_eq!(
            read(&whole.join(name)),
            read(&resumed.join(name)),
            "{sampler:?}: {name}"
        );
    }
}

#[test]
fn monte_carlo_estimates_a_known_probability_and_resumes_to_the_same_table() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("mc");
    run(
        &dir,
        &settings(Sampler::Mc, 400, 50),
        &mut ClosedForm::new(0.05),
    )
    .unwrap();
    let e = &summary(&dir)["estimate"];
    let (lo, hi) = (
        e["ci95"][0].as_f64().unwrap(),
        e["ci95"][1].as_f64().unwrap(),
    );
    assert!(
        lo < 0.05 && 0.05 < hi,
        "Clopper–Pearson [{lo}, {hi}] covers p = 0.05"
    );
    assert_eq!(e["samples"], 400);
    check_resume(Sampler::Mc, 400, 50, 0.05, 130);
}

#[test]
fn two_shards_merge_to_the_single_process_table() {
    let root = tempfile::tempdir().unwrap();
    let s = settings(Sampler::Mc, 300, 40);
    let single = root.path().join("single");
    run(&single, &s, &mut ClosedForm::new(0.1)).unwrap();
    let sharded = root.path().join("sharded");
    let space = space();
    let folder = Run::create(&sharded, RunRecord::new(&space, s.clone()).unwrap()).unwrap();
    // shard 1 first: it returns once its own batches are done; shard 0 then does the rest
    let (mut one, mut zero) = (ClosedForm::new(0.1), ClosedForm::new(0.1));
    folder.sample(&space, &mut one, 1, 2, &mut Quiet).unwrap();
    assert!(!folder.complete().unwrap());
    folder.sample(&space, &mut zero, 0, 2, &mut Quiet).unwrap();
    assert_eq!(one.calls + zero.calls, 300);
    assert_eq!((one.calls, zero.calls), (140, 160), "batches b mod 2");
    folder.merge().unwrap();
    assert_eq!(
        read(&single.join("samples.parquet")),
        read(&sharded.join("samples.parquet"))
    );
}

#[test]
fn cross_entropy_resumes_across_its_barriers() {
    // interrupted in its second tuning iteration, after the first barrier wrote a proposal
    check_resume(Sampler::Ce, 200, 50, 1e-3, 250);
}

#[test]
fn cross_entropy_chooses_the_deciding_parameter_itself_and_resumes() {
    let p = 1e-3;
    let mut s = settings(Sampler::Ce, 1000, 100);
    s.ce_tilt = vec!["auto".into()];
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("auto");
    run(&dir, &s, &mut ClosedForm::new(p)).unwrap();
    let summary = summary(&dir);
    let tests = summary["ce_tilt"]["tests"].as_array().unwrap();
    let tilted: Vec<&str> = tests
        .iter()
        .filter(|t| t["tilted"] == true)
        .map(|t| t["parameter"].as_str().unwrap())
        .collect();
    assert_eq!(tilted, [DECIDING], "{tests:?}");
    // the orientation block is tested once, as a whole
    assert!(tests.iter().any(|t| t["parameter"] == "target.orientation"));
    let ci = &summary["estimate"]["ci95"];
    let (lo, hi) = (ci[0].as_f64().unwrap(), ci[1].as_f64().unwrap());
    assert!(lo < p && p < hi, "[{lo}, {hi}] covers {p}");
    // every later proposal holds the other parameters at their nominal
    let plan: serde_json::Value =
        serde_json::from_slice(&read(&dir.join("proposals/iter-0001.json"))).unwrap();
    let names = RunRecord::new(&space(), s.clone()).unwrap().dimensions;
    let component = &plan["proposal"]["components"][0];
    for (d, name) in names.iter().enumerate() {
        let (mean, std) = (
            component["mean"][d].as_f64().unwrap(),
            component["std"][d].as_f64().unwrap(),
        );
        assert_eq!(
            name == DECIDING,
            (mean, std) != (0.0, 1.0),
            "{name}: mean {mean}, std {std}"
        );
    }
    // "auto" with names is refused; resumed across the choice, the same tables
    let mut mixed = s.clone();
    mixed.ce_tilt.push("target.size_m".into());
    let refused = RunRecord::new(&space(), mixed).unwrap_err().to_string();
    assert!(refused.contains("--ce-tilt auto"), "{refused}");
    let mut few = s.clone();
    few.ce.samples_per_iteration = 10;
    let refused = RunRecord::new(&space(), few).unwrap_err().to_string();
    assert!(refused.contains("--ce-samples-per-iteration"), "{refused}");
    s.samples = 200;
    s.ce.final_samples = 200;
    check_resume_of(&s, p, 250);
}

#[test]
fn cross_entropy_auto_tilt_waits_at_the_nominal_until_a_parameter_shows() {
    // one sample in 200 leaves the plateau: the first iteration's 200 show nothing, so the
    // next iterations draw from the nominal again and the tests pool them
    let (p, off) = (1e-3, 5e-3);
    let mut s = settings(Sampler::Ce, 200, 100);
    s.ce_tilt = vec!["auto".into()];
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("auto");
    run(&dir, &s, &mut ClosedForm::with_plateau(p, off)).unwrap();
    let plan = |i: u32| -> serde_json::Value {
        serde_json::from_slice(&read(&dir.join(format!("proposals/iter-{i:04}.json")))).unwrap()
    };
    let first = plan(1);
    assert_eq!(first["tilt"]["samples"], 200);
    assert!(
        first["tilt"]["tests"]
            .as_array()
            .unwrap()
            .iter()
            .all(|t| t["tilted"] == false),
        "{first}"
    );
    let component = &first["proposal"]["components"][0];
    for d in 0..component["mean"].as_array().unwrap().len() {
        assert_eq!(
            (component["mean"][d].as_f64(), component["std"][d].as_f64()),
            (Some(0.0), Some(1.0)),
            "nothing chosen: the second iteration draws from the nominal"
        );
    }
    let summary = summary(&dir);
    let tilt = &summary["ce_tilt"];
    let chosen: Vec<&str> = tilt["tests"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t["tilted"] == true)
        .map(|t| t["parameter"].as_str().unwrap())
        .collect();
    assert!(
        tilt["samples"].as_u64().unwrap() > 200 && chosen == [DECIDING],
        "the pooled looks found the deciding parameter: {tilt}"
    );
    // resumed across the barriers of the waiting iterations, the same tables
    check_resume_of_with(&s, || ClosedForm::with_plateau(p, off), 250);
}

#[test]
fn subset_simulation_in_a_run_folder_is_the_in_memory_run_and_resumes() {
    let p = 1e-3;
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("split");
    let s = settings(Sampler::Splitting, 500, 60);
    run(&dir, &s, &mut ClosedForm::new(p)).unwrap();
    let result: serde_json::Value =
        serde_json::from_slice(&read(&dir.join("splitting.json"))).unwrap();
    // the same algorithm on the same z, scored in memory: the same levels
    let space = space();
    let record = RunRecord::new(&space, s.clone()).unwrap();
    let k = record
        .dimensions
        .iter()
        .position(|d| d == DECIDING)
        .unwrap();
    let blocks: Vec<usize> = record
        .dimensions
        .iter()
        .enumerate()
        .filter(|(_, d)| d.ends_with(".orientation.q0"))
        .map(|(i, _)| i)
        .collect();
    let closed = ClosedForm::new(p);
    let memory = run_in_memory(
        s.splitting.as_ref().unwrap(),
        record.dimensions.len(),
        &blocks,
        s.seed,
        |z, _| closed.score_of_quantile(normal_cdf(z[k])),
    )
    .unwrap();
    let levels = result["levels"].as_array().unwrap();
    assert_eq!(levels.len(), memory.levels.len());
    assert!(memory.levels.len() >= 3, "several levels to p = 1e-3");
    for (folder, memory) in levels.iter().zip(&memory.levels) {
        assert!((folder["threshold"].as_f64().unwrap() - memory.threshold).abs() < 1e-9);
        assert_eq!(
            folder["conditional_probability"].as_f64().unwrap(),
            memory.conditional_probability
        );
        assert_eq!(folder["evaluations"].as_u64().unwrap(), memory.evaluations);
    }
    assert_eq!(result["evaluations"].as_u64().unwrap(), memory.evaluations);
    // the summary reports it as every sampler does, and it covers the known p
    let summary = summary(&dir);
    let e = &summary["estimate"];
    assert_eq!(e["ci_method"], "log_normal");
    assert_eq!(e["samples"].as_u64().unwrap(), memory.evaluations);
    let (lo, hi) = (
        e["ci95"][0].as_f64().unwrap(),
        e["ci95"][1].as_f64().unwrap(),
    );
    assert!(lo < p && p < hi, "[{lo}, {hi}] covers p = {p}");
    assert_eq!(
        summary["splitting"]["levels"].as_array().unwrap().len(),
        levels.len()
    );
    // interrupted inside its second stage's chains, resumed: the same run
    check_resume(Sampler::Splitting, 500, 60, p, 700);
}

#[test]
fn two_shards_of_a_subset_simulation_meet_at_its_barriers_and_merge_to_the_single_run() {
    let p = 1e-3;
    let root = tempfile::tempdir().unwrap();
    let s = settings(Sampler::Splitting, 200, 10);
    let single = root.path().join("single");
    run(&single, &s, &mut ClosedForm::new(p)).unwrap();
    let sharded = root.path().join("sharded");
    let space = space();
    Run::create(&sharded, RunRecord::new(&space, s.clone()).unwrap()).unwrap();
    // two processes' worth: each its own Run and evaluator, meeting at every barrier
    let calls: Vec<usize> = std::thread::scope(|scope| {
        let shards: Vec<_> = (0..2)
            .map(|shard| {
                let (space, sharded) = (&space, &sharded);
                scope.spawn(move || {
                    let folder = Run::open(sharded).unwrap();
                    let mut evaluator = ClosedForm::new(p);
                    folder
                        .sample(space, &mut evaluator, shard, 2, &mut Quiet)
                        .unwrap();
                    evaluator.calls
                })
            })
            .collect();
        shards.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let folder = Run::open(&sharded).unwrap();
    assert!(folder.complete().unwrap());
    assert!(
        calls.iter().all(|&c| c > 0),
        "both shards worked: {calls:?}"
    );
    folder.merge().unwrap();
    for name in ["samples.parquet", "splitting.json"] {
        assert_eq!(
            read(&single.join(name)),
            read(&sharded.join(name)),
            "{name}"
        );
    }
}

#[test]
fn a_segmenter_run_recorded_before_two_resolution_renders_resumes_as_it_began() {
    let space = space();
    let dir = tempfile::tempdir().unwrap();
    let mut before = settings(Sampler::Mc, 10, 5);
    before.crops = Crops::Predicted;
    let recorded =
        Run::create(dir.path(), RunRecord::new(&space, before.clone()).unwrap()).unwrap();
    // what run.json held before the setting existed: no two_resolutions key at all
    let path = dir.path().join("run.json");
    let mut json: serde_json::Value = serde_json::from_slice(&read(&path)).unwrap();
    json["settings"]
        .as_object_mut()
        .unwrap()
        .remove("two_resolutions")
        .expect("run.json records two_resolutions");
    std::fs::write(&path, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
    // today's command for the same search asks for two resolutions; the run goes on with whole frames
    let today = RunSettings {
        two_resolutions: true,
        ..before.clone()
    };
    let resumed = Run::create(dir.path(), RunRecord::new(&space, today.clone()).unwrap()).unwrap();
    assert!(!resumed.record.settings.two_resolutions);
    assert!(resumed.record == recorded.record);
    // a run recorded with two resolutions is another search for a command with --whole-frames,
    // named by that flag
    let other = tempfile::tempdir().unwrap();
    Run::create(other.path(), RunRecord::new(&space, today).unwrap()).unwrap();
    let whole_frames = RunSettings {
        whole_frames: true,
        ..before
    };
    let refused = Run::create(other.path(), RunRecord::new(&space, whole_frames).unwrap());
    let message = refused.err().expect("refused").to_string();
    assert!(
        message.contains("--whole-frames is false there, true here")
            && !message.contains("two-resolutions"),
        "{message}"
    );
}
