//! `boxpose export bop|coco`: a dataset in the BOP scene-wise format that bop_toolkit reads, or
//! as COCO instances (RLE masks, optionally the 8 corners as keypoints) for segmentation and
//! keypoint tooling, written by `boxpose_formats`; this module opens the dataset, publishes the
//! folder and draws the progress. See docs/export.md.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, ensure};
use boxpose_data::Dataset;
use boxpose_data::schema::FRAMES;
use boxpose_formats::{BopOptions, CocoOptions};
use indicatif::{ProgressBar, ProgressStyle};

/// Command-line options of `boxpose export`.
#[derive(clap::Args)]
#[command(
    about = "Export a dataset to the BOP scene-wise format (bop_toolkit) or to COCO instances",
    long_about = "Export a dataset to the BOP scene-wise format (bop_toolkit) or to COCO instances.\n\n\
        `bop` writes one folder per scene (rgb/, depth/ as uint16 PNG with a depth_scale, mask/ and \
        mask_visib/, scene_camera.json, scene_gt.json, scene_gt_info.json), the box models (models/, \
        models_eval/: one PLY per distinct box size, in mm, with models_info.json and the box's discrete \
        symmetries), camera.json, test_targets_bop19.json and dataset_info.md. Poses and models are in \
        millimetres, as BOP expects.\n\n\
        `coco` writes annotations.json (one `box` category; per visible box a COCO RLE of its visible mask, \
        bbox, area, and the amodal silhouette as amodal_segmentation/amodal_bbox) and the images as PNG \
        files under images/; with --keypoints also the box's 8 corners as COCO keypoints (visibility \
        0/1/2) and the category's corner names and 12-edge skeleton.\n\n\
        Visible masks come from the exact instance mask; amodal masks (BOP mask/, COCO amodal_*) are the \
        box's projected silhouette (its convex hull clipped to the near plane), the same silhouette the \
        dataset's visible_fraction is measured against. The output folder is written under OUT.partial \
        and renamed to OUT when complete; OUT must not exist or be empty.",
    after_help = "Examples:\n  \
        boxpose export bop datasets/generated/demo build/bop/boxposedemo\n  \
        boxpose export bop datasets/generated/demo build/bop/boxposedemo --split val --min-visib-fract 0.2\n  \
        boxpose export coco datasets/generated/demo build/coco/demo\n  \
        boxpose export coco datasets/generated/demo build/coco/demo_keypoints --keypoints\n\n\
        See docs/export.md for every file, field and unit."
)]
pub struct Args {
    #[command(subcommand)]
    pub format: Format,
}

#[derive(clap::Subcommand)]
pub enum Format {
    /// BOP scene-wise format: OUT/SPLIT/{scene_id:06d}/…, OUT/models/, OUT/models_eval/, camera.json,
    /// test_targets_bop19.json, dataset_info.md (millimetres; depth as uint16 × depth_scale = mm).
    Bop(BopArgs),
    /// COCO instances: OUT/annotations.json (RLE visible and amodal masks, bbox, area) and OUT/images/*.png.
    Coco(CocoArgs),
}

#[derive(clap::Args)]
pub struct BopArgs {
    /// Dataset folder (scenes/, objects/, frames/, instances/).
    pub dataset: PathBuf,
    /// Output folder (the BOP dataset root); must not exist or be empty.
    pub out: PathBuf,
    /// Split folder the scenes go to (BOP: test, val or train, optionally with a _TYPE suffix).
    #[arg(long, default_value = "test", value_name = "NAME")]
    pub split: String,
    /// Smallest visib_fract of an instance listed in test_targets_bop19.json (BOP'19 uses 0.1).
    #[arg(long, default_value_t = 0.1, value_name = "F")]
    pub min_visib_fract: f64,
}

#[derive(clap::Args)]
pub struct CocoArgs {
    /// Dataset folder (scenes/, objects/, frames/, instances/).
    pub dataset: PathBuf,
    /// Output folder (annotations.json and images/); must not exist or be empty.
    pub out: PathBuf,
    /// Also write the box's 8 corners per annotation as COCO `keypoints` (visibility 2 visible,
    /// 1 occluded or self-occluded, 0 outside the image) with `num_keypoints`, and the corner
    /// names and the 12-edge `skeleton` in the category.
    #[arg(long)]
    pub keypoints: bool,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.format {
        Format::Bop(a) => {
            let options = BopOptions {
                split: a.split.clone(),
                min_visib_fract: a.min_visib_fract,
                source: dataset_name(&a.dataset),
                name: a
                    .out
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            };
            let written = export(&a.dataset, &a.out, "bop", |dataset, tmp, on_frame| {
                Ok(boxpose_formats::write_bop(
                    dataset, &options, tmp, on_frame,
                )?)
            })?;
            println!(
                "{} scenes, {} images, {} instances, {} models",
                written.scenes, written.images, written.instances, written.models
            );
            println!("wrote {}", a.out.display());
        }
        Format::Coco(a) => {
            let options = CocoOptions {
                keypoints: a.keypoints,
                source: dataset_name(&a.dataset),
            };
            let written = export(&a.dataset, &a.out, "coco", |dataset, tmp, on_frame| {
                Ok(boxpose_formats::write_coco(
                    dataset, &options, tmp, on_frame,
                )?)
            })?;
            println!(
                "{} images, {} annotations",
                written.images, written.annotations
            );
            println!("wrote {}", a.out.display());
        }
    }
    Ok(())
}

/// Opens the dataset, writes it with `write` into the staged folder with a progress bar, and
/// publishes the folder as `out`; returns what `write` says it wrote.
fn export<T>(
    dataset: &Path,
    out: &Path,
    what: &str,
    write: impl FnOnce(&Dataset, &Path, &mut dyn FnMut()) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let dataset = Dataset::open(dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let bar = progress(&dataset, what)?;
    let written = with_partial(out, |tmp| write(&dataset, tmp, &mut || bar.inc(1)))?;
    bar.finish_and_clear();
    Ok(written)
}

/// Writes into `OUT.partial` (cleared first) and renames it to `OUT` once `write` succeeded;
/// removes it when `write` fails.
fn with_partial<T>(
    out: &Path,
    write: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    if out.exists() {
        let empty = out.is_dir() && fs::read_dir(out)?.next().is_none();
        ensure!(
            empty,
            "{} exists and is not an empty folder: choose a new output folder",
            out.display()
        );
        fs::remove_dir(out)?;
    }
    let name = out
        .file_name()
        .with_context(|| format!("{} has no folder name", out.display()))?;
    let tmp = out.with_file_name(format!("{}.partial", name.to_string_lossy()));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).with_context(|| format!("cannot clear {}", tmp.display()))?;
    }
    fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let written = match write(&tmp) {
        Ok(written) => written,
        Err(e) => {
            let _ = fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    boxpose_data::publish_folder(&tmp, out)?;
    Ok(written)
}

/// The dataset's folder name, as an export records its source: not the absolute path, which
/// would leak the exporting machine's layout into a shared dataset.
fn dataset_name(dataset: &Path) -> String {
    fs::canonicalize(dataset)
        .unwrap_or_else(|_| dataset.to_path_buf())
        .file_name()
        .map_or_else(
            || dataset.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
}

fn progress(dataset: &Dataset, what: &str) -> anyhow::Result<ProgressBar> {
    let frames = dataset.count(&FRAMES)?;
    let bar = ProgressBar::new(frames as u64).with_style(ProgressStyle::with_template(&format!(
        "{what} {{bar:30}} {{pos}}/{{len}} frames [{{elapsed_precise}}<{{eta_precise}}]"
    ))?);
    Ok(bar)
}
