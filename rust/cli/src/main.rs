//! `boxpose`: the command-line entry point of every Rust stage.

mod dump;
mod eval;
mod eval_geometry;
mod eval_results;
mod export;
mod fit_table;
mod inspect;
mod plots;
mod predict;
mod render;
mod search;
mod search_report;
mod settle;
mod train;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "boxpose",
    version,
    about = "Synthetic box datasets, 3D-keypoint pose recovery and failure search."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the dataset contract (tables, columns, types, units) as JSON or Markdown.
    Schema {
        /// Markdown column reference (as in docs/dataset.md) instead of JSON.
        #[arg(long)]
        markdown: bool,
    },
    /// Validate every shard of a dataset folder and summarize it.
    ///
    /// Checks schema version, column types, finite poses, unit quaternions, decodable images and
    /// that every frame's instances exist; exits non-zero with the file and problem otherwise.
    Inspect {
        /// Dataset folder (holding scenes/, objects/, frames/, instances/).
        dataset: PathBuf,
    },
    /// Print every scene, object and decoded frame (with its instances) as JSON lines.
    ///
    /// Meant for small datasets, debugging and tests; pipe it to `jq`.
    Dump {
        /// Dataset folder.
        dataset: PathBuf,
    },
    /// Evaluate the heatmap → pose stage on a dataset's ground truth (no network involved).
    ///
    /// Draws, for each instance, the heatmap a perfect network would output (a Gaussian at each
    /// true corner, jittered by --noise-m), optionally with confident spurious peaks (the paper's
    /// failure mode), then runs NMS, back-projection and every pose fit (paper-exact search, fast
    /// exact search, robust fit, pose-and-size fit) and scores them against the true pose.
    EvalGeometry(eval_geometry::Args),
    Settle(settle::Args),
    Render(render::Args),
    /// Train the keypoint network on rendered datasets (resumes an interrupted run folder).
    ///
    /// Validates on held-out scenes every `validate_every` steps (heatmap loss, corner recall,
    /// pose MSSD recall) and checkpoints there; the finished model is written to OUT/model.
    Train(train::Args),
    /// Train the instance segmenter (foreground, object centres, offsets; bottom-up grouping)
    /// on whole frames; validates mask and bounding-box AP on held-out scenes.
    TrainSegmenter(train::SegmenterArgs),
    /// Predict box poses in one RGBD frame with a trained model; writes Parquet, JSON and an
    /// overlay PNG (true box white, NMS peaks black, fitted box grey).
    Predict(predict::Args),
    /// Evaluate a trained model over a dataset: per-instance metrics (Parquet), a summary table
    /// and the error histogram (the paper's Fig. 6).
    Eval(eval::Args),
    Search(search::Args),
    Export(export::Args),
    EvalResults(eval_results::Args),
}

/// Prints a failure as one line, its causes joined by ": ", and never a backtrace: anyhow's
/// default report appends one whenever RUST_BACKTRACE is set, as it often is on developer
/// machines, burying the message a user needs under 20 frames.
fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Schema { markdown: true } => print!("{}", boxpose_data::schema::to_markdown()),
        Command::Schema { markdown: false } => {
            println!(
                "{}",
                serde_json::to_string_pretty(&boxpose_data::schema::to_json())?
            )
        }
        Command::Inspect { dataset } => inspect::run(&dataset)?,
        Command::Dump { dataset } => dump::run(&dataset)?,
        Command::EvalGeometry(args) => eval_geometry::run(&args)?,
        Command::Settle(args) => settle::run(&args)?,
        Command::Render(args) => render::run(&args)?,
        Command::Train(args) => train::run(&args)?,
        Command::TrainSegmenter(args) => train::run_segmenter(&args)?,
        Command::Predict(args) => predict::run(&args)?,
        Command::Eval(args) => eval::run(&args)?,
        Command::Search(args) => search::run(&args)?,
        Command::Export(args) => export::run(&args)?,
        Command::EvalResults(args) => eval_results::run(&args)?,
    }
    Ok(())
}
