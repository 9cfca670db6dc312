//! `boxpose eval-results bop RESULTS.csv DATASET`: score another method's BOP-format pose results
//! (`scene_id,im_id,obj_id,score,R,t,time`) against a boxpose dataset with the project's metrics.
//! The ids are those `boxpose export bop` wrote: scene_id, im_id = frame_id, and obj_id one per
//! distinct box size. The scoring is `boxpose_formats::bop_results`; this module writes and prints
//! it. See docs/export.md, "Scoring other methods' results".

use std::fs;
use std::path::PathBuf;

use anyhow::Context;
use boxpose_data::Dataset;
use boxpose_formats::{ResultsScore, score_bop_results};

/// Command-line options of `boxpose eval-results`.
#[derive(clap::Args)]
#[command(
    about = "Score another method's pose results (BOP CSV) on a boxpose dataset with the project's metrics",
    after_help = "Example:\n  \
        boxpose export bop datasets/generated/demo build/bop/demo\n  \
        # … run a BOP method on build/bop/demo, giving results.csv …\n  \
        boxpose eval-results bop results.csv datasets/generated/demo --out results/eval_bop\n\n\
        See docs/export.md, \"Scoring other methods' results\"."
)]
pub struct Args {
    #[command(subcommand)]
    pub format: Format,
}

#[derive(clap::Subcommand)]
pub enum Format {
    /// BOP results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm), with ids as
    /// `boxpose export bop` numbered them.
    Bop(BopArgs),
}

#[derive(clap::Args)]
pub struct BopArgs {
    /// Results CSV (an optional `scene_id,im_id,…` header line is skipped).
    pub results: PathBuf,
    /// The boxpose dataset folder the BOP export was made from.
    pub dataset: PathBuf,
    /// Output folder: eval_results.parquet and summary.json.
    #[arg(long, default_value = "results/eval_results")]
    pub out: PathBuf,
    /// Count and report malformed lines instead of stopping at the first one.
    #[arg(long)]
    pub skip_malformed: bool,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.format {
        Format::Bop(a) => bop(a),
    }
}

fn bop(args: &BopArgs) -> anyhow::Result<()> {
    let _claim = boxpose_data::output_folder::claim(
        &args.out,
        "--out",
        "eval-results",
        &["eval_results.parquet"],
    )?;
    let dataset = Dataset::open(&args.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let scored = score_bop_results(&dataset, &args.results, args.skip_malformed)?;
    fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let table = args.out.join("eval_results.parquet");
    scored.write_table(&table)?;
    let summary = scored.summary(&args.results, &args.dataset);
    boxpose_data::write_file_atomically(
        &args.out.join("summary.json"),
        (serde_json::to_string_pretty(&summary)? + "\n").as_bytes(),
    )?;
    print_table(&scored);
    println!("per-instance metrics: {}", table.display());
    Ok(())
}

/// The counts, each skipped line, and a table with a line per obj_id and the total.
fn print_table(scored: &ResultsScore) {
    let (lines, valid) = (scored.valid + scored.malformed.len(), scored.valid);
    let (instances, matched) = (
        scored.rows.len(),
        scored.rows.iter().filter(|r| r.matched.is_some()).count(),
    );
    println!(
        "{lines} result lines: {valid} valid, {} malformed; {instances} instances, {matched} matched, {} missed; {} results unmatched",
        scored.malformed.len(),
        instances - matched,
        valid - matched
    );
    for m in &scored.malformed {
        println!("  skipped {m}");
    }
    println!(
        "{:>8} {:>9} {:>8} {:>12} {:>11} {:>12} {:>13} {:>9}",
        "obj_id",
        "instances",
        "matched",
        "cube@0.05d",
        "cube@0.1d",
        "MSSD@0.1d",
        "MSSD mm",
        "e_R deg"
    );
    let mean = |m: Option<f64>| m.map_or("-".to_string(), |m| format!("{m:.2}"));
    for line in scored.per_object() {
        println!(
            "{:>8} {:>9} {:>8} {:>12.3} {:>11.3} {:>12.3} {:>13} {:>9}",
            line.obj_id.map_or("all".to_string(), |k| k.to_string()),
            line.instances,
            line.matched,
            line.cube_mssd_005,
            line.cube_mssd_01,
            line.mssd_01,
            mean(line.mean_mssd_mm),
            mean(line.mean_rotation_error_deg)
        );
    }
}
