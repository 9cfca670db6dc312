//! `boxpose`: the command-line entry point of every Rust stage.

mod dump;
mod eval;
mod eval_external;
mod eval_geometry;
mod eval_results;
mod export;
mod fit_table;
mod improve;
mod inspect;
mod output_folder;
mod plots;
mod predict;
mod render;
mod search;
mod search_report;
mod settle;
mod settle_drops;
mod train;
mod view;

use std::io::{BufWriter, ErrorKind, Write};
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
        #[arg(long, conflicts_with = "recipes_markdown")]
        markdown: bool,
        /// Markdown reference of every recipe key: type, accepted values, default, unit and
        /// meaning (docs/recipes.md).
        #[arg(long)]
        recipes_markdown: bool,
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
    SettleDrops(settle_drops::Args),
    View(view::Args),
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
    Improve(improve::Args),
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
            eprintln!("error: {}", one_line(&error));
            if let Some(hint) = outside_the_repository_hint(&error) {
                eprintln!("{hint}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// The shipped defaults (`--model models/keypoint-slim`, `--segmenter`, `--recipes
/// datasets/recipes`, search space names in `configs/search/`) are paths relative to the
/// repository root: a missing file, met from another working directory, gets a hint that says so.
fn outside_the_repository_hint(error: &anyhow::Error) -> Option<&'static str> {
    const SHIPPED: [&str; 3] = ["models/", "configs/search/", "datasets/recipes/"];
    let message = one_line(error);
    let missing_shipped_file = message.contains("No such file or directory")
        && SHIPPED.iter().any(|prefix| {
            message.starts_with(prefix)
                || message.contains(&format!(" {prefix}"))
                || message.contains(&format!(": {prefix}"))
        });
    let at_the_root =
        std::path::Path::new("configs/search").is_dir() && std::path::Path::new("models").is_dir();
    (missing_shipped_file && !at_the_root).then_some(
        "hint: the default models, recipes and search spaces are paths relative to the boxpose \
         repository root; run from there, or pass --model, --segmenter, --recipes and a search \
         space's path",
    )
}

/// The error and its causes joined by ": ", each cause once: many errors already print their
/// cause in their own message (`path: No such file or directory`), and repeating it reads as two
/// failures.
fn one_line(error: &anyhow::Error) -> String {
    let mut line = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !line.contains(&cause) {
            line.push_str(": ");
            line.push_str(&cause);
        }
    }
    line
}

/// Runs `write` on standard output, buffered, and flushes it. A reader that stops reading early
/// (`boxpose dump DATASET | head -1`) closes the pipe: that is not a failure, the output it
/// wanted was written.
pub(crate) fn to_stdout(
    write: impl FnOnce(&mut dyn Write) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let mut out = BufWriter::new(std::io::stdout().lock());
    match write(&mut out).and_then(|()| Ok(out.flush()?)) {
        Err(error)
            if error
                .downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == ErrorKind::BrokenPipe) =>
        {
            Ok(())
        }
        result => result,
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Schema { markdown: true, .. } => {
            to_stdout(|out| Ok(out.write_all(boxpose_data::schema::to_markdown().as_bytes())?))?
        }
        Command::Schema {
            recipes_markdown: true,
            ..
        } => to_stdout(|out| Ok(out.write_all(boxpose_data::recipe::to_markdown().as_bytes())?))?,
        Command::Schema { .. } => {
            let json = serde_json::to_string_pretty(&boxpose_data::schema::to_json())?;
            to_stdout(|out| Ok(writeln!(out, "{json}")?))?
        }
        Command::Inspect { dataset } => inspect::run(&dataset)?,
        Command::Dump { dataset } => dump::run(&dataset)?,
        Command::EvalGeometry(args) => eval_geometry::run(&args)?,
        Command::Settle(args) => settle::run(&args)?,
        Command::SettleDrops(args) => settle_drops::run(&args)?,
        Command::View(args) => view::run(&args)?,
        Command::Render(args) => render::run(&args)?,
        Command::Train(args) => train::run(&args)?,
        Command::TrainSegmenter(args) => train::run_segmenter(&args)?,
        Command::Predict(args) => predict::run(&args)?,
        Command::Eval(args) => eval::run(&args)?,
        Command::Search(args) => search::run(&args)?,
        Command::Improve(args) => improve::run(&args)?,
        Command::Export(args) => export::run(&args)?,
        Command::EvalResults(args) => eval_results::run(&args)?,
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_already_in_the_message_is_not_repeated() {
        let io = std::io::Error::from(ErrorKind::IsADirectory);
        let data = boxpose_data::DataError::Io {
            path: PathBuf::from("results/out"),
            source: io,
        };
        let cause = std::io::Error::from(ErrorKind::IsADirectory).to_string();
        let error = anyhow::Error::new(data).context("writing the table");
        assert_eq!(
            one_line(&error),
            format!("writing the table: results/out: {cause}")
        );
        let error = anyhow::Error::new(std::io::Error::other("disk full")).context("writing x");
        assert_eq!(one_line(&error), "writing x: disk full");
    }
}
