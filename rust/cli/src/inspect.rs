use std::path::Path;

use boxpose_data::schema::{FRAMES, INSTANCES, OBJECTS, SCENES};
use boxpose_data::{Dataset, Visibility};
use indicatif::{ProgressBar, ProgressStyle};

pub fn run(path: &Path) -> anyhow::Result<()> {
    let dataset = Dataset::open(path)?;
    let scenes = dataset.count(&SCENES)?;
    let objects = dataset.count(&OBJECTS)?;
    println!("{}: {scenes} scenes, {objects} objects", path.display());
    if dataset.shards(&FRAMES).is_err() {
        println!("no rendered frames yet");
        return Ok(());
    }
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
