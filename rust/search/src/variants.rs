//! Training data around a run's counterexamples (`boxpose search variants`): for each failing
//! sample, scenes whose inputs are its own moved by Gaussian noise in the space's standard-normal
//! coordinates, settled and rendered by the run's system, written as a dataset (one shard per
//! failure, so that an interrupted command resumes where it stopped).

use std::path::Path;

use boxpose_data::{Object, Scene, schema, shard_file_name, write_shard};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::error::{Result, SearchError};
use crate::run::SampleRow;
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
