//! `boxpose render`: re-render frames of a dataset's scene in-process (embedded Blender).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use boxpose_data::arrow::array::{Array, AsArray};
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::{DataError, Dataset, Pose, schema, shard_file_name, write_shard};
use boxpose_render::{RenderRequest, Rendered, Renderer, scene_rows};

/// Re-render frames of one scene of a dataset with the embedded Blender.
///
/// Loads the scene once, renders each --frame (camera and lights drawn from the frame's render
/// seed, exactly as the dataset was made), optionally only a crop region, at other sample
/// counts, or with boxes moved. Writes DIR/scene-S-frame-F-rgb.png and -mask.png (16-bit,
/// object_id + 1), and DIR as a dataset of the rendered rows (scenes/, objects/, frames/,
/// instances/, one shard each) that `boxpose inspect` and pandas read.
///
/// --out must be a new folder (or one without dataset tables): a folder already holding tables
/// or a manifest.json — another dataset, or an earlier render — is refused rather than have its
/// rows replaced. Render several frames of a scene with one command (repeat --frame), or render
/// into one folder per command.
#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder holding the scene (its scenes/ and objects/ tables).
    dataset: PathBuf,
    /// scene_id of the scene to render.
    #[arg(long)]
    scene: i64,
    /// frame_id(s) to render (repeat the flag for several; the scene is loaded once). Each must
    /// be one of the scene's frames in the dataset; a dataset without a frames table (scenes not
    /// rendered yet) renders any id, drawing its camera from the frame's seed as the Blender
    /// stage does.
    #[arg(long = "frame", default_value = "0")]
    frames: Vec<i32>,
    /// Render only pixels x0 ≤ x < x1, y0 ≤ y < y1 of the frame (Cycles border render); the
    /// output frame is that region, its principal point shifted.
    #[arg(long, value_parser = parse_crop, value_name = "x0,y0,x1,y1")]
    crop: Option<[u32; 4]>,
    /// Render the whole frame smaller, this many pixels across (height and focal length scaled
    /// alike), as a search with segmenter crops renders the segmenter's frame (its
    /// `render_settings` record `scaled_from`). Not with --crop.
    #[arg(long, conflicts_with = "crop", value_parser = clap::value_parser!(u32).range(1..))]
    width: Option<u32>,
    /// Cycles samples per pixel, at least 1 (default: the recipe's).
    #[arg(long, value_parser = clap::value_parser!(i32).range(1..))]
    samples: Option<i32>,
    /// Denoise with OpenImageDenoise (true/false; default: the recipe's).
    #[arg(long)]
    denoise: Option<bool>,
    /// Also simulate the structured-light depth channel (default: the recipe's).
    #[arg(long)]
    sensor_depth: Option<bool>,
    /// Move a box for these renders: OBJECT_ID:qw,qx,qy,qz,x,y,z (T_world_box). Repeatable.
    #[arg(long = "pose", value_parser = parse_pose, value_name = "ID:qw,qx,qy,qz,x,y,z")]
    poses: Vec<(i32, Pose)>,
    /// Cycles threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Output folder: new, or holding no dataset tables and no manifest.json.
    #[arg(long)]
    out: PathBuf,
}

fn parse_crop(s: &str) -> Result<[u32; 4], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x0, y0, x1, y1] if x0 < x1 && y0 < y1 => Ok([x0, y0, x1, y1]),
        [_, _, _, _] => Err("need x0 < x1 and y0 < y1".into()),
        _ => Err("need four integers x0,y0,x1,y1".into()),
    }
}

fn parse_pose(s: &str) -> Result<(i32, Pose), String> {
    let (id, rest) = s
        .split_once(':')
        .ok_or("need OBJECT_ID:qw,qx,qy,qz,x,y,z")?;
    let id = id
        .trim()
        .parse::<i32>()
        .map_err(|e| format!("object id '{id}': {e}"))?;
    let v: Vec<f64> = rest
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, _>>()?;
    let [qw, qx, qy, qz, x, y, z] = v[..] else {
        return Err("need 7 numbers after the id: qw,qx,qy,qz,x,y,z".into());
    };
    let n = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
    if !(n > 0.0) || !v.iter().all(|x| x.is_finite()) {
        return Err("the quaternion must be finite and non-zero".into());
    }
    Ok((
        id,
        Pose {
            quat_wxyz: [qw / n, qx / n, qy / n, qz / n],
            translation: [x, y, z],
        },
    ))
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    // Writing part-00000-of-00001 shards into the input would replace or duplicate its shards.
    if let (Ok(input), Ok(output)) = (args.dataset.canonicalize(), args.out.canonicalize()) {
        anyhow::ensure!(
            input != output,
            "--out {} is the input dataset; its shards would be overwritten or duplicated: \
             choose another folder",
            args.out.display()
        );
    }
    // The rendered rows are written as the folder's only shards (`part-00000-of-00001`), which
    // would replace another dataset's rows or an earlier render's: no marker is its own.
    let _claim = boxpose_data::output_folder::claim(&args.out, "--out", "render", &[])?;
    let (scenes, objects) = scene_rows(&args.dataset, args.scene)
        .with_context(|| format!("reading scene {} of {}", args.scene, args.dataset.display()))?;
    check_frames(&args.dataset, args.scene, &args.frames)?;
    let start = Instant::now();
    let mut renderer = Renderer::new(args.threads).context("starting the embedded Blender")?;
    let started = start.elapsed().as_secs_f64();
    let load = Instant::now();
    renderer.load_scene(&scenes, &objects, args.scene)?;
    eprintln!(
        "scene {}: Blender started in {started:.2} s, scene built in {:.2} s",
        args.scene,
        load.elapsed().as_secs_f64()
    );
    let (mut frames, mut instances) = (Vec::new(), Vec::new());
    for &frame_id in &args.frames {
        let out = render_frame(&mut renderer, args, frame_id)?;
        frames.push(out.frames);
        instances.push(out.instances);
    }
    let name = shard_file_name(0, 1);
    // scene_rows returned them in the contract's schema
    write_shard(&args.out, &schema::SCENES, &name, &[scenes])?;
    write_shard(&args.out, &schema::OBJECTS, &name, &[objects])?;
    write_shard(&args.out, &schema::INSTANCES, &name, &instances)?;
    write_shard(&args.out, &schema::FRAMES, &name, &frames)?;
    println!("rows: {}", args.out.display());
    Ok(())
}

/// Renders frame `frame_id` of the loaded scene, checks its rows as a dataset shard's, writes its
/// RGB and mask PNGs into `--out` and prints a line about it.
fn render_frame(renderer: &mut Renderer, args: &Args, frame_id: i32) -> anyhow::Result<Rendered> {
    let request = RenderRequest {
        frame_id,
        samples: args.samples,
        denoise: args.denoise,
        crop: args.crop,
        sensor_depth: args.sensor_depth,
        poses: args.poses.clone(),
        crop_object: None,
        width: args.width,
    };
    let t = Instant::now();
    let out = renderer.render(&request)?;
    let seconds = t.elapsed().as_secs_f64();
    let f = &out.frames;
    // the renderer's rows pass the same validation as a dataset shard before anything is read
    let source = Path::new("<embedded Blender render>");
    let decoded = boxpose_data::decode_frames(source, f, &out.instances)?;
    let frame = decoded
        .first()
        .context("the renderer returned no frame row")?;
    let (width, height, samples, fx) = (
        frame.width,
        frame.height,
        frame.samples,
        frame.intrinsics.fx,
    );
    let stem = format!("scene-{:06}-frame-{frame_id:03}", args.scene);
    // created once the first render succeeded: a refused request leaves nothing behind
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    write_png(&args.out.join(format!("{stem}-rgb.png")), f, "rgb_png")?;
    write_png(
        &args.out.join(format!("{stem}-mask.png")),
        f,
        "instance_mask_png",
    )?;
    let seen = frame
        .instances
        .iter()
        .filter(|i| i.visible_pixels > 0)
        .count();
    println!(
        "{stem}: {width}×{height} px (fx {fx:.1}), {samples} samples, {seen}/{} boxes visible, {seconds:.2} s → {}",
        out.instances.num_rows(),
        args.out.join(format!("{stem}-rgb.png")).display()
    );
    Ok(out)
}

/// Checks that every requested frame is one of the scene's frames in the dataset: an unknown id
/// would silently draw a camera no frame of the dataset has. A dataset without a frames table
/// (its scenes not rendered yet) may render any id.
fn check_frames(dataset: &Path, scene: i64, requested: &[i32]) -> anyhow::Result<()> {
    let index = match Dataset::open(dataset)?.frame_index() {
        Err(DataError::MissingTable(_, table)) if table == schema::FRAMES.name => return Ok(()),
        index => index?,
    };
    let frames: BTreeSet<i32> = index
        .iter()
        .filter(|entry| entry.scene_id == scene)
        .map(|entry| entry.frame_id)
        .collect();
    let unknown: Vec<String> = requested
        .iter()
        .filter(|frame| !frames.contains(frame))
        .map(|frame| frame.to_string())
        .collect();
    if unknown.is_empty() {
        return Ok(());
    }
    let listed: Vec<String> = frames.iter().map(|frame| frame.to_string()).collect();
    let has = if listed.is_empty() {
        "has no frames".to_string()
    } else {
        format!("has frames {} only; give one of those", listed.join(", "))
    };
    bail!(
        "--frame {}: scene {scene} of {} {has}",
        unknown.join(", "),
        dataset.display()
    )
}

fn write_png(path: &Path, batch: &RecordBatch, column: &str) -> anyhow::Result<()> {
    let array = batch
        .column_by_name(column)
        .with_context(|| format!("the render has no {column} column"))?
        .as_binary::<i32>();
    if array.is_null(0) {
        bail!("{column} is null");
    }
    std::fs::write(path, array.value(0)).with_context(|| format!("writing {}", path.display()))
}
