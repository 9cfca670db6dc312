//! `boxpose view`: one frame's ground truth as a PNG sheet — of a dataset's scene, or of a search
//! run's sample with the network's peaks, its fit and the sample's parameters.

use std::path::{Path, PathBuf};

use anyhow::Context;
use boxpose_data::Dataset;
use boxpose_search::run::Run;

use boxpose_report::plots::{self, SheetExtras};
use boxpose_report::search_report;

/// Command-line options of `boxpose view`.
#[derive(clap::Args)]
#[command(
    about = "Draw one frame's ground truth as a PNG: the image with every box's corners by visibility, depth, masks",
    long_about = "Draw one frame's ground truth as a PNG sheet of three panels: the RGB image with every \
        box's true edges and its corners coloured by visibility (visible, occluded by another box, \
        self-occluded, outside the image), the depth (near bright, no surface black) and the instance \
        masks (a colour per box, its object_id at its centre).\n\n\
        Given a search run folder and --sample, it draws that sample's counterexample frame (the run's \
        counterexamples/ dataset, scene_id = sample id) with the network's NMS peaks and fitted box of \
        the target, and the sample's errors and parameter values beside it: what `boxpose search` found, \
        as `boxpose search replay` would run it again.",
    after_help = "Examples:\n  \
        boxpose view datasets/generated/demo --scene 0 --frame 1 --out demo-0-1.png\n  \
        boxpose view results/shift-wide/shift_support-predicted --sample 17"
)]
pub struct Args {
    /// A dataset folder, or a search run folder (with its run.json).
    pub path: PathBuf,
    /// The dataset's scene to draw (a dataset).
    #[arg(long, value_name = "N", conflicts_with = "sample")]
    pub scene: Option<i64>,
    /// The run's sample to draw (a search run folder); it must be a counterexample the run kept.
    #[arg(long, value_name = "ID")]
    pub sample: Option<i64>,
    /// The scene's view.
    #[arg(long, value_name = "F", default_value_t = 0)]
    pub frame: i32,
    /// The PNG to write [default: view-scene-N-frame-F.png or view-sample-ID.png here].
    #[arg(long, value_name = "PNG")]
    pub out: Option<PathBuf>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let is_run = args.path.join("run.json").is_file();
    let (dataset_dir, scene_id, extras, default_name) = match (is_run, args.scene, args.sample) {
        (true, _, Some(sample)) => {
            let extras = sample_extras(&args.path, sample)?;
            let name = format!("view-sample-{sample}.png");
            (args.path.join("counterexamples"), sample, extras, name)
        }
        (true, _, None) => anyhow::bail!(
            "{} is a search run folder: give --sample ID (one of its counterexamples)",
            args.path.display()
        ),
        (false, Some(scene), None) => {
            let extras = SheetExtras {
                title: format!(
                    "{} — scene {scene}, frame {}",
                    args.path.display(),
                    args.frame
                ),
                overlay: None,
                text: Vec::new(),
            };
            let name = format!("view-scene-{scene}-frame-{}.png", args.frame);
            (args.path.clone(), scene, extras, name)
        }
        (false, _, _) => anyhow::bail!(
            "{} is a dataset folder (no run.json): give --scene N (and --frame F)",
            args.path.display()
        ),
    };
    let dataset = Dataset::open(&dataset_dir)?;
    let frame = dataset
        .frame(scene_id, args.frame)?
        .with_context(|| no_frame(&dataset_dir, scene_id, args.frame, is_run))?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(default_name));
    anyhow::ensure!(
        !out.is_dir(),
        "--out {}: is a folder; give the PNG's path",
        out.display()
    );
    plots::frame_sheet(&out, &frame, &extras)?;
    println!("{}", out.display());
    Ok(())
}

fn no_frame(dataset: &Path, scene: i64, frame: i32, is_run: bool) -> String {
    if is_run {
        format!(
            "{} holds no frame {frame} of sample {scene}: the run keeps the frames of its \
             failing samples only (its report lists them)",
            dataset.display()
        )
    } else {
        format!(
            "{} has no frame {frame} of scene {scene} (`boxpose inspect` lists what it holds)",
            dataset.display()
        )
    }
}

/// The title, the target's peaks and fit, and the text panel (errors, then the parameters) of
/// a search run's sample.
fn sample_extras(run_dir: &Path, sample: i64) -> anyhow::Result<SheetExtras> {
    let run = Run::open(run_dir)?;
    let (rows, _) = run.rows()?;
    let row = rows
        .iter()
        .find(|r| r.sample_id == sample)
        .with_context(|| format!("{} has no sample {sample}", run_dir.display()))?;
    Ok(search_report::sample_sheet(
        &run,
        row,
        format!("{} — sample {sample}", run_dir.display()),
    ))
}
