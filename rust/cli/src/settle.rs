//! `boxpose settle`: re-settle every scene of a dataset with MuJoCo, from the stored initial
//! poses, and compare with the stored (Drake) settled poses.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use boxpose_data::{Dataset, Object, Scene};
use boxpose_physics::{RecipePhysics, settle_and_compare};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

/// Command-line options of `boxpose settle`.
#[derive(clap::Args)]
#[command(
    about = "Re-settle every scene of a dataset with MuJoCo and compare with the stored (Drake) poses",
    long_about = "Re-settle every scene of a dataset with MuJoCo and compare with the stored (Drake) poses.\n\n\
        Each scene is rebuilt from its `objects` rows (size, mass, friction, initial_world_box pose) and its \
        recipe's [support] and [settle] sections, dropped from the initial poses and stepped until every box is \
        at rest over the recipe's window (the Drake stage's test). Per scene it prints MuJoCo's verdict and \
        certificate, whether each box rests on the same face as in the stored settled pose (world_box), the \
        distance between the two settled box centres, and the wall time.",
    after_help = "Examples:\n  \
        boxpose settle datasets/generated/tiny\n  \
        boxpose settle build/bench_settle --bench --repeat 5 --json > mujoco.jsonl"
)]
pub struct Args {
    /// Dataset folder with scenes/ and objects/ shards (e.g. from `python -m drake_scenes`).
    pub dataset: PathBuf,
    /// Recipe for the support and [settle] parameters: a TOML path or a name in datasets/recipes/.
    /// Default: each scene's own `recipe_toml`.
    #[arg(long, value_name = "R")]
    pub recipe: Option<String>,
    /// Benchmark: settle each scene --repeat times reusing the compiled model, report the median.
    #[arg(long)]
    pub bench: bool,
    /// Settles per scene with --bench.
    #[arg(long, default_value_t = 5, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// One JSON object per scene on stdout (and no summary), for scripts.
    #[arg(long)]
    pub json: bool,
    /// Only the first K scenes.
    #[arg(long, value_name = "K")]
    pub limit: Option<usize>,
}

/// Per-scene comparison of MuJoCo's settle with the stored one.
struct Row {
    boxes: usize,
    stable: bool,
    drake_stable: bool,
    faces_agree: usize,
    max_position_diff_m: f64,
    wall_s: f64,
}

fn load_recipe(recipe: &str) -> anyhow::Result<RecipePhysics> {
    let path = Path::new(recipe);
    let path = if path.exists() {
        path.to_path_buf()
    } else {
        Path::new("datasets/recipes").join(format!("{recipe}.toml"))
    };
    anyhow::ensure!(
        path.is_file(),
        "--recipe {recipe}: neither a TOML file nor a recipe name ({} does not exist)",
        path.display()
    );
    Ok(RecipePhysics::from_file(&path)?)
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let dataset = Dataset::open(&args.dataset)?;
    let mut scenes = dataset.scenes()?;
    scenes.sort_by_key(|s| s.scene_id);
    if let Some(k) = args.limit {
        scenes.truncate(k);
    }
    let mut objects: BTreeMap<i64, Vec<Object>> = BTreeMap::new();
    for o in dataset.objects()? {
        objects.entry(o.scene_id).or_default().push(o);
    }
    let fixed = args.recipe.as_deref().map(load_recipe).transpose()?;

    let bar = ProgressBar::new(scenes.len() as u64).with_style(ProgressStyle::with_template(
        "settling {bar:30} {pos}/{len} scenes [{elapsed_precise}<{eta_precise}] {msg}",
    )?);
    let mut rows = Vec::new();
    let mut failures = 0usize;
    for scene in &scenes {
        let result = settle_scene(
            scene,
            objects.get(&scene.scene_id).map_or(&[][..], Vec::as_slice),
            fixed.as_ref(),
            args,
        );
        match result {
            Ok((row, line)) => {
                bar.suspend(|| println!("{line}"));
                rows.push(row);
            }
            Err(e) => {
                failures += 1;
                bar.suspend(|| {
                    if args.json {
                        println!(
                            "{}",
                            json!({"scene_id": scene.scene_id, "error": format!("{e:#}")})
                        );
                    } else {
                        println!("scene {:>5}  error: {e:#}", scene.scene_id);
                    }
                });
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    if !args.json {
        print_summary(&rows, args.bench);
    }
    anyhow::ensure!(
        failures == 0,
        "{failures} of {} scenes could not be settled",
        scenes.len()
    );
    Ok(())
}

fn settle_scene(
    scene: &Scene,
    objects: &[Object],
    fixed: Option<&RecipePhysics>,
    args: &Args,
) -> anyhow::Result<(Row, String)> {
    let recipe = match fixed {
        Some(r) => *r,
        None => RecipePhysics::from_toml(&scene.recipe_toml).context("the scene's recipe_toml")?,
    };
    let repeats = if args.bench { args.repeat } else { 1 };
    let a = settle_and_compare(objects, scene.num_objects as usize, &recipe, repeats)?;
    let (outcome, n, wall_s) = (&a.outcome, objects.len(), a.median_wall_s());
    let c = &outcome.certificate;
    let line = if args.json {
        json!({
            "scene_id": scene.scene_id,
            "boxes": n,
            "mujoco_settle_s": wall_s,
            "mujoco_compile_s": a.compile_s,
            "repeats": a.walls_s.len(),
            "settled": outcome.settled,
            "stable": outcome.stable,
            "rejection": outcome.rejection.map(|r| r.as_str()),
            "settle_time_s": c.settle_time_s,
            "max_linear_speed_mps": c.max_linear_speed_mps,
            "max_angular_speed_radps": c.max_angular_speed_radps,
            "min_signed_distance_m": c.min_signed_distance_m,
            "drake_stable": scene.stable,
            "drake_settle_time_s": scene.settle_time_s,
            "faces_agree": a.faces_agree,
            "same_face": a.faces_agree == n,
            "max_position_diff_m": a.max_position_diff_m,
            "mean_position_diff_m": a.mean_position_diff_m,
        })
        .to_string()
    } else {
        format!(
            "scene {:>5}  {n:>2} boxes  mujoco {:<6} drake {:<6}  faces {}/{n}  Δpos max {:>6.1} mm mean {:>6.1} mm  settle {:.2} s sim  {:>7.2} ms wall{}",
            scene.scene_id,
            verdict(outcome.stable, outcome.rejection.map(|r| r.as_str())),
            verdict(scene.stable, None),
            a.faces_agree,
            a.max_position_diff_m * 1e3,
            a.mean_position_diff_m * 1e3,
            c.settle_time_s,
            wall_s * 1e3,
            if args.bench {
                format!(" (median of {})", a.walls_s.len())
            } else {
                String::new()
            },
        )
    };
    Ok((
        Row {
            boxes: n,
            stable: outcome.stable,
            drake_stable: scene.stable,
            faces_agree: a.faces_agree,
            max_position_diff_m: a.max_position_diff_m,
            wall_s,
        },
        line,
    ))
}

fn verdict(stable: bool, why: Option<&str>) -> String {
    match (stable, why) {
        (true, _) => "stable".into(),
        (false, Some(w)) => format!("({w})"),
        (false, None) => "unstable".into(),
    }
}

fn print_summary(rows: &[Row], bench: bool) {
    if rows.is_empty() {
        println!("no scenes settled");
        return;
    }
    let n = rows.len();
    let both = rows.iter().filter(|r| r.stable && r.drake_stable).count();
    let singles: Vec<&Row> = rows.iter().filter(|r| r.boxes == 1).collect();
    let single_same = singles.iter().filter(|r| r.faces_agree == 1).count();
    let (faces, boxes) = rows
        .iter()
        .fold((0, 0), |(f, b), r| (f + r.faces_agree, b + r.boxes));
    let mut diffs: Vec<f64> = rows.iter().map(|r| r.max_position_diff_m).collect();
    diffs.sort_by(f64::total_cmp);
    println!();
    println!("{n} scenes: {both} stable in both MuJoCo and the stored settle");
    if !singles.is_empty() {
        println!(
            "single-box scenes resting on the same face: {single_same}/{}",
            singles.len()
        );
    }
    println!("boxes resting on the same face: {faces}/{boxes}");
    println!(
        "per-scene largest centre distance: median {:.1} mm, max {:.1} mm",
        diffs[n / 2] * 1e3,
        diffs[n - 1] * 1e3
    );
    let mut by_count: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for r in rows {
        by_count.entry(r.boxes).or_default().push(r.wall_s);
    }
    println!(
        "MuJoCo wall time per settle{}:",
        if bench {
            " (median of the repeats)"
        } else {
            ""
        }
    );
    for (boxes, mut walls) in by_count {
        walls.sort_by(f64::total_cmp);
        let mean = walls.iter().sum::<f64>() / walls.len() as f64;
        println!(
            "  {boxes:>3} boxes: median {:.2} ms, mean {:.2} ms over {} scenes",
            walls[walls.len() / 2] * 1e3,
            mean * 1e3,
            walls.len()
        );
    }
}
