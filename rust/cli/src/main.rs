//! `boxpose`: the command-line entry point of every Rust stage.

mod dump;
mod eval_geometry;
mod inspect;
mod render;
mod settle;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "boxpose", version, about = "Synthetic box datasets, 3D-keypoint pose recovery and failure search.")]
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
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Schema { markdown: true } => print!("{}", boxpose_data::schema::to_markdown()),
        Command::Schema { markdown: false } => {
            println!("{}", serde_json::to_string_pretty(&boxpose_data::schema::to_json())?)
        }
        Command::Inspect { dataset } => inspect::run(&dataset)?,
        Command::Dump { dataset } => dump::run(&dataset)?,
        Command::EvalGeometry(args) => eval_geometry::run(&args)?,
        Command::Settle(args) => settle::run(&args)?,
        Command::Render(args) => render::run(&args)?,
    }
    Ok(())
}
