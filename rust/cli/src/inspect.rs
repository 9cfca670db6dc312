use std::path::Path;

use boxpose_data::schema::{FRAMES, INSTANCES, OBJECTS, SCENES, Table};
use boxpose_data::{Dataset, Visibility};
use indicatif::{ProgressBar, ProgressStyle};

pub fn run(path: &Path) -> anyhow::Result<()> {
    let dataset = Dataset::open(path)?;
    // Decoding the rows checks their keys: no scene or object twice, no object of no scene.
    let scenes = dataset.scenes()?.len();
    let objects = dataset.objects()?.len();
    ensure_complete(&dataset, &SCENES)?;
    ensure_complete(&dataset, &OBJECTS)?;
    println!("{}: {scenes} scenes, {objects} objects", path.display());
    if dataset.shards(&FRAMES).is_err() {
        println!("no rendered frames yet");
        return Ok(());
    }
    ensure_complete(&dataset, &FRAMES)?;
    ensure_complete(&dataset, &INSTANCES)?;
    let frames = dataset.count(&FRAMES)?;
    let bar = ProgressBar::new(frames as u64).with_style(ProgressStyle::with_template(
        "decoding frames {bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}]",
    )?);
    let (mut instances, mut corners, mut visible) = (0, 0, 0);
    for frame in dataset.frames()? {
        let frame = frame?;
        instances += frame.instances.len();
        for instance in &frame.instances {
            corners += 8;
            visible += instance
                .visibility
                .iter()
                .filter(|&&v| v == Visibility::Visible)
                .count();
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let declared = dataset.count(&INSTANCES)?;
    anyhow::ensure!(
        instances == declared,
        "{}: {} instance rows belong to no frame",
        path.join("instances").display(),
        declared - instances
    );
    println!(
        "{frames} frames, {instances} instances, {visible}/{corners} corners visible — all shards valid"
    );
    Ok(())
}

/// A valid dataset has every shard of N: one missing is a generation that did not finish.
fn ensure_complete(dataset: &Dataset, table: &'static Table) -> anyhow::Result<()> {
    let (missing, count) = dataset.missing_shards(table)?;
    anyhow::ensure!(
        missing.is_empty(),
        "{} is missing ({} of {count} shards missing): the job that writes them did not \
         finish; resume it (e.g. `make scenes` with the same arguments)",
        dataset
            .root()
            .join(table.name)
            .join(boxpose_data::shard_file_name(missing[0], count))
            .display(),
        missing.len()
    );
    Ok(())
}

/// Warns on stderr, per table, when a dataset lacks some of its `part-i-of-N` shards (an
/// unfinished `make scenes`): commands that work on what is there (`export`, `eval*`) say that
/// their output covers part of the dataset instead of looking complete.
pub fn warn_if_incomplete(dataset: &Dataset) {
    for table in [&SCENES, &OBJECTS, &FRAMES, &INSTANCES] {
        if let Ok((missing, count)) = dataset.missing_shards(table)
            && !missing.is_empty()
        {
            eprintln!(
                "warning: {}: {} of {count} shards missing (an unfinished generation?); this output covers only the rest — `boxpose inspect` says what is missing",
                dataset.root().join(table.name).display(),
                missing.len()
            );
        }
    }
}
