//! Training batches, prepared on worker threads ahead of the optimizer. No burn here: an example
//! is a pair of flat arrays, and the trainer makes tensors of a batch.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::LearnError;

/// What the loader draws from: training items 0..n, each an augmented (input, target) pair.
pub trait ExampleSource: Send + Sync + 'static {
    fn train_items(&self) -> usize;
    /// One augmented training example (input, target), flat in the task's shapes.
    fn training_example(
        &self,
        item: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<(Vec<f32>, Vec<f32>), LearnError>;
}

/// One training example as the loader hands it over: (input tensor data, target tensor data).
type Example = (Vec<f32>, Vec<f32>);

/// A batch as flat arrays: inputs `[B, C, H, W]`, targets `[B, C', H', W']`.
pub(crate) struct Batch {
    pub step: usize,
    pub size: usize,
    pub inputs: Vec<f32>,
    pub targets: Vec<f32>,
}

/// Which training example fills slot `slot` of step `step`: epochs are seeded shuffles of the
/// training set, so the sequence depends only on the seed, and a resumed run continues it.
fn sampled_item(
    order_cache: &mut (u64, Vec<usize>),
    n: usize,
    seed: u64,
    position: usize,
) -> usize {
    let epoch = (position / n) as u64;
    if order_cache.0 != epoch || order_cache.1.len() != n {
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut ChaCha8Rng::seed_from_u64(
            seed ^ epoch.wrapping_mul(0x9E37_79B9_7F4A_7C15),
        ));
        *order_cache = (epoch, order);
    }
    order_cache.1[position % n]
}

/// Prepares training batches of `task` for steps `start_step..end_step`, on `threads` worker
/// threads, at most two batches ahead of the optimizer; each example's augmentation is seeded by
/// (seed, step, slot), so the batches do not depend on the thread count.
pub(crate) fn spawn_loader<T: ExampleSource>(
    task: Arc<T>,
    batch_size: usize,
    seed: u64,
    start_step: usize,
    end_step: usize,
    threads: usize,
) -> Result<Receiver<Result<Batch, LearnError>>, LearnError> {
    let items = task.train_items();
    if items == 0 {
        return Err(LearnError::Data(
            "nothing to train on (is every scene held out, or every box hidden?)".into(),
        ));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .thread_name(|i| format!("boxpose-loader-{i}"))
        .build()
        .map_err(|e| LearnError::Data(format!("cannot start the loader threads: {e}")))?;
    let (sender, receiver): (SyncSender<_>, _) = sync_channel(2);
    std::thread::spawn(move || {
        let mut order = (u64::MAX, Vec::new());
        for step in start_step..end_step {
            let picks: Vec<usize> = (0..batch_size)
                .map(|slot| sampled_item(&mut order, items, seed, step * batch_size + slot))
                .collect();
            let examples: Result<Vec<Example>, LearnError> = pool.install(|| {
                picks
                    .par_iter()
                    .enumerate()
                    .map(|(slot, &pick)| {
                        let mut rng = ChaCha8Rng::seed_from_u64(
                            seed ^ ((step * batch_size + slot) as u64)
                                .wrapping_mul(0xD1B5_4A32_D192_ED03),
                        );
                        task.training_example(pick, &mut rng)
                    })
                    .collect()
            });
            let batch = examples.map(|examples| Batch {
                step,
                size: examples.len(),
                inputs: examples
                    .iter()
                    .flat_map(|(input, _)| input.iter().copied())
                    .collect(),
                targets: examples
                    .iter()
                    .flat_map(|(_, target)| target.iter().copied())
                    .collect(),
            });
            if sender.send(batch).is_err() {
                return; // the trainer stopped
            }
        }
    });
    Ok(receiver)
}
