//! `boxpose samples`: the keypoint network's training examples on stdin and stdout, for another
//! framework's training loop (`boxpose_io.torch`), drawn as `boxpose train` draws them
//! (`boxpose_learn::sample_server`).

use std::io::{BufWriter, ErrorKind};
use std::path::PathBuf;

use anyhow::Context;
use boxpose_learn::LearnError;
use boxpose_learn::config::TrainConfig;
use boxpose_learn::keypoint::KeypointTask;
use boxpose_learn::sample_server;

#[derive(clap::Args)]
#[command(
    about = "Serve the keypoint network's training examples to another framework (protocol boxpose-samples/1)",
    long_about = "Serve the keypoint network's training examples to another framework's training loop, \
        on stdin and stdout (protocol boxpose-samples/1, docs/learning.md \"Training in PyTorch\"). \
        Each example is what `boxpose train` with the same config computes: the RGB-D crop as the \
        network's input, the target heatmap, the box's mask in the crop, its corners with their \
        visibility, the intrinsics and the crop window; a training item with a seed is augmented as \
        training augments it. boxpose_io.torch.KeypointSamples starts one such process per \
        DataLoader worker. Not for a terminal.",
    after_help = "Example (Python, with torch installed):\n  \
        from boxpose_io.torch import KeypointSamples\n  \
        samples = KeypointSamples(\"configs/keypoint-slim.toml\", datasets=[\"datasets/generated/demo\"])"
)]
pub struct Args {
    /// Training config (TOML): the network's input and heatmap, the data and the augmentation
    /// the examples follow, as for `boxpose train --config`.
    #[arg(long, value_parser = crate::shipped_path)]
    config: PathBuf,
    /// Serve these dataset folders instead of the config's [data] datasets (and its repeat).
    #[arg(long = "dataset")]
    datasets: Vec<PathBuf>,
    /// Copies of each dataset's training scenes, one count per dataset in order (as `boxpose
    /// train --repeat`).
    #[arg(long, value_delimiter = ',', value_name = "K,K,…")]
    repeat: Vec<usize>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut config = TrainConfig::load(&args.config)?;
    crate::train::override_datasets(&mut config.data, &args.datasets, &args.repeat);
    config
        .validate()
        .with_context(|| format!("{} with the command-line overrides", args.config.display()))?;
    let task = KeypointTask::load(config)?;
    let mut input = std::io::stdin().lock();
    let mut output = BufWriter::new(std::io::stdout().lock());
    match sample_server::serve(&task, &mut input, &mut output) {
        // the client closed its end: the exchange is over
        Err(LearnError::Io(_, e)) if e.kind() == ErrorKind::BrokenPipe => Ok(()),
        result => Ok(result?),
    }
}
