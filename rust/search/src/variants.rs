//! Training data around a run's counterexamples (`boxpose search variants`): for each failing
//! sample, scenes whose inputs are its own moved by Gaussian noise in the space's standard-normal
//! coordinates, settled and rendered by the run's system, written as a dataset (one shard per
//! failure, so that an interrupted command resumes where it stopped).

use std::path::Path;

use boxpose_data::output_folder::{VARIANTS_FILE, refuse_foreign};
use boxpose_data::{Object, Scene, schema, shard_file_name, write_shard};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::error::{Result, SearchError};
use crate::run::{Run, SampleRow};
use crate::space::SearchSpace;
use crate::sut::Evaluate;

/// How the scenes around each failure are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VariantDraw {
    /// Scenes drawn around each failing sample.
    pub per_failure: usize,
    /// Standard deviation of the move in z (0: the failing scene itself, `per_failure` times).
    pub sigma: f64,
    pub seed: u64,
}

impl VariantDraw {
    /// Refuses a draw that would write nothing or move by a meaningless amount.
    pub fn check(&self) -> Result<()> {
        if self.per_failure < 1 {
            return Err(SearchError::Settings(
                "--per-failure must be at least 1".into(),
            ));
        }
        if !(self.sigma.is_finite() && self.sigma >= 0.0) {
            return Err(SearchError::Settings(format!(
                "--sigma {} must be finite and non-negative",
                self.sigma
            )));
        }
        Ok(())
    }

    /// The inputs of variant `k` of `failure`: its z moved by N(0, σ²) noise drawn from
    /// (seed, sample id, k) alone, and its nuisance seed + k.
    pub fn inputs(&self, failure: &SampleRow, k: usize) -> Result<(Vec<f64>, i64)> {
        let noise = Normal::new(0.0, self.sigma)
            .map_err(|e| SearchError::Sample(format!("sigma {}: {e}", self.sigma)))?;
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed
                ^ (failure.sample_id as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ (k as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
        );
        let z = failure
            .z
            .iter()
            .map(|z| z + noise.sample(&mut rng))
            .collect();
        Ok((z, failure.seed.wrapping_add(k as i64)))
    }
}

/// What `search variants` writes into its output folder, and may find there when it resumes.
pub const OUTPUT: [&str; 5] = [
    schema::SCENES.name,
    schema::OBJECTS.name,
    schema::FRAMES.name,
    schema::INSTANCES.name,
    VARIANTS_FILE,
];

/// Claims `out` for the variants of `run` drawn by `draw`, so that a resume continues only its
/// own shards: the folder records the run and draw it holds (`variants.json`, written before the
/// first shard), and a folder holding another dataset, another run or the variants of other
/// settings is refused, untouched.
pub fn claim_folder(out: &Path, run: &Run, draw: &VariantDraw) -> Result<()> {
    let claim = serde_json::json!({
        "run": run.record,
        "per_failure": draw.per_failure,
        "sigma": draw.sigma,
        "seed": draw.seed,
    });
    let path = out.join(VARIANTS_FILE);
    let io = |e: std::io::Error| SearchError::Io {
        path: path.clone(),
        message: e.to_string(),
    };
    if path.is_file() {
        let text = std::fs::read_to_string(&path).map_err(io)?;
        let found: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| SearchError::Io {
                path: path.clone(),
                message: format!("unreadable: {e}"),
            })?;
        if found != claim {
            return Err(SearchError::Io {
                path: out.to_path_buf(),
                message: format!(
                    "--out holds variants of another run or other settings (its \
                     {VARIANTS_FILE}): choose a new folder for --out, or rerun with that run and \
                     its --per-failure, --sigma and --seed to resume"
                ),
            });
        }
    } else {
        // tables without the claim are another dataset's (or an older command's)
        refuse_foreign(out, "--out", "search variants", &[VARIANTS_FILE])?;
        std::fs::create_dir_all(out).map_err(io)?;
        let text = serde_json::to_string_pretty(&claim).expect("a claim serialises");
        boxpose_data::write_file_atomically(&path, text.as_bytes())?;
    }
    Ok(())
}

/// Draws, settles and renders the variants of `failures` with `system` into the dataset folder
/// `out`: failure i's scenes (ids i·per_failure + k) in shard i, its frames table written last, so
/// that a shard with frames is a finished failure and is skipped on resume. A scene that does not
/// settle is not rendered and not written. `finished` is called after each failure; returns the
/// scenes written by this call.
pub fn write(
    space: &SearchSpace,
    system: &mut impl Evaluate,
    failures: &[&SampleRow],
    draw: &VariantDraw,
    out: &Path,
    mut finished: impl FnMut(),
) -> Result<usize> {
    let mut written = 0;
    for (index, failure) in failures.iter().enumerate() {
        let name = shard_file_name(index, failures.len());
        if out.join(schema::FRAMES.name).join(&name).is_file() {
            finished();
            continue;
        }
        let (mut scenes, mut objects, mut frames, mut instances) = (vec![], vec![], vec![], vec![]);
        for k in 0..draw.per_failure {
            let scene_id = (index * draw.per_failure + k) as i64;
            let (z, scene_seed) = draw.inputs(failure, k)?;
            let parameters = space.parameters(&z, failure.stratum as u32)?;
            let outcome = system.evaluate(space, &parameters, scene_id, scene_seed)?;
            let Some((frame, frame_instances)) = outcome.rendered else {
                continue;
            };
            scenes.push(outcome.scene);
            objects.extend(outcome.objects);
            frames.push(frame);
            instances.push(frame_instances);
        }
        written += scenes.len();
        write_shard(out, &schema::SCENES, &name, &[Scene::to_batch(&scenes)])?;
        write_shard(out, &schema::OBJECTS, &name, &[Object::to_batch(&objects)])?;
        write_shard(out, &schema::INSTANCES, &name, &instances)?;
        write_shard(out, &schema::FRAMES, &name, &frames)?;
        finished();
    }
    Ok(written)
}

/// What [`render_around_failures`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    /// Scenes written by this call (a resumed call skips finished failures).
    pub scenes: usize,
    /// The run's valid failing samples, one shard each.
    pub failures: usize,
    /// The run's keypoint network (what to fine-tune from).
    pub model: String,
}

/// `boxpose search variants`: claims `out` (a folder of another dataset or run, or inside the run,
/// is refused untouched), loads the run's own system (its space, networks and fit, rendering
/// whole frames, `threads` Cycles threads, `backend`) and writes the variants of every valid
/// failing sample of the run in `run_dir`. `progress(done, total)` is called after each failure.
pub fn render_around_failures(
    run_dir: &Path,
    out: &Path,
    draw: &VariantDraw,
    threads: usize,
    backend: boxpose_learn::backend::BackendKind,
    mut progress: impl FnMut(usize, usize),
) -> Result<Rendered> {
    draw.check()?;
    // before the run is read: a folder of another dataset or run is refused whatever the run
    let _claim = boxpose_data::output_folder::claim(out, "--out", "search variants", &OUTPUT)?;
    let run = Run::open(run_dir)?;
    let absolute = |p: &Path| {
        std::path::absolute(p).map_err(|e| SearchError::Io {
            path: p.to_path_buf(),
            message: e.to_string(),
        })
    };
    if absolute(out)?.starts_with(absolute(run_dir)?) {
        return Err(SearchError::Settings(format!(
            "--out {} is inside the run folder {}: choose a folder of its own",
            out.display(),
            run_dir.display()
        )));
    }
    let (rows, _) = run.rows()?;
    let failures: Vec<&SampleRow> = rows.iter().filter(|r| r.valid && r.failed).collect();
    if failures.is_empty() {
        return Err(SearchError::Run {
            path: run_dir.to_path_buf(),
            problem: "no valid sample failed, so there is nothing to vary".into(),
        });
    }
    claim_folder(out, &run, draw)?;
    let space = crate::system::space_of(&run)?;
    let mut system =
        crate::system::load(&space, &run.record.settings, None, None, threads, backend)?;
    // Whole frames: a training frame shows every box, not only the target's region.
    system.whole_frames = true;
    progress(0, failures.len());
    let mut done = 0;
    let scenes = write(&space, &mut system, &failures, draw, out, || {
        done += 1;
        progress(done, failures.len());
    })?;
    Ok(Rendered {
        scenes,
        failures: failures.len(),
        model: run.record.settings.model.clone(),
    })
}
