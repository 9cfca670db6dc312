//! Re-settle benchmark (docs/benchmarks.md, "Settling"): the search loop's case of one disturbed
//! box. For every scene of a dataset the box that rests highest is moved 3 cm sideways, turned
//! 30° about the vertical, lifted until its lowest corner is 5 cm above every other box, and
//! dropped back onto the stored settled pile (the `world_box` poses). Two ways, interleaved over
//! ROUNDS rounds, each scene's fastest kept:
//!
//! - asleep: [`resettle`], the pile starts asleep and a box wakes when something touches it;
//! - awake: the same start with every box awake ([`Settler::settle_from`]), the reference.
//!
//!     cargo run --release -p boxpose-physics --example resettle -- DATASET [ROUNDS]

use std::collections::BTreeMap;

use boxpose_data::{Dataset, Object};
use boxpose_physics::{
    BoxBody, Pose, RecipePhysics, SceneDescription, SettleOutcome, Settler, down_face, resettle,
    rotation_matrix,
};

/// The disturbance: sideways, a turn about the world's z axis, and a drop from this far above
/// the pile.
const SHIFT_M: [f64; 2] = [0.03, 0.0];
const TURN_RAD: f64 = std::f64::consts::PI / 6.0;
const GAP_M: f64 = 0.05;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args.next().ok_or("usage: resettle DATASET [ROUNDS]")?;
    let rounds: usize = args.next().map(|r| r.parse()).transpose()?.unwrap_or(5);
    let dataset = Dataset::open(&dir)?;
    let mut scenes = dataset.scenes()?;
    scenes.sort_by_key(|s| s.scene_id);
    let mut objects: BTreeMap<i64, Vec<Object>> = BTreeMap::new();
    for o in dataset.objects()? {
        objects.entry(o.scene_id).or_default().push(o);
    }
    println!(
        "scene boxes | asleep ms  stable | awake ms  stable | speed-up | dropped box: same face, Δ centre"
    );
    let mut speedups = Vec::new();
    for scene in scenes.iter().filter(|s| s.stable) {
        let mut rows = objects.remove(&scene.scene_id).unwrap_or_default();
        rows.sort_by_key(|o| o.object_id);
        let recipe = RecipePhysics::from_toml(&scene.recipe_toml)?;
        let pile = SceneDescription::from_objects(recipe.support, &rows);
        let settled: Vec<Pose> = rows.iter().map(|o| o.world_box).collect();
        let moved = (0..settled.len())
            .max_by(|&a, &b| settled[a].translation[2].total_cmp(&settled[b].translation[2]))
            .ok_or("a scene without boxes")?;
        let top = (0..settled.len())
            .filter(|&i| i != moved)
            .map(|i| z_extent(&pile.boxes[i], &settled[i]).1)
            .fold(0.0, f64::max);
        let drop = disturbed(&pile.boxes[moved], settled[moved], top + GAP_M);
        let mut start = settled.clone();
        start[moved] = drop;
        let mut awake = Settler::new(&pile, &recipe.settle)?;
        let (mut best_asleep, mut best_awake): (Option<SettleOutcome>, Option<SettleOutcome>) =
            (None, None);
        for _ in 0..rounds {
            let a = resettle(&pile, &settled, moved, drop, &recipe.settle)?;
            let b = awake.settle_from(&start)?;
            keep_fastest(&mut best_asleep, a);
            keep_fastest(&mut best_awake, b);
        }
        let (a, b) = (best_asleep.unwrap(), best_awake.unwrap());
        let (ta, tb) = (a.certificate.wall_time_s, b.certificate.wall_time_s);
        speedups.push(tb / ta);
        let same_face =
            down_face(a.poses[moved].quat_wxyz).0 == down_face(b.poses[moved].quat_wxyz).0;
        let delta = (0..3)
            .map(|k| (a.poses[moved].translation[k] - b.poses[moved].translation[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        println!(
            "{:>5} {:>5} | {:>9.1}  {:<6} | {:>8.1}  {:<6} | {:>7.1}× | {}, {:.1} mm",
            scene.scene_id,
            rows.len(),
            ta * 1e3,
            verdict(&a),
            tb * 1e3,
            verdict(&b),
            tb / ta,
            if same_face { "yes" } else { "no" },
            delta * 1e3
        );
    }
    speedups.sort_by(f64::total_cmp);
    if !speedups.is_empty() {
        println!(
            "{} scenes: speed-up asleep over awake, median {:.1}×",
            speedups.len(),
            speedups[speedups.len() / 2]
        );
    }
    Ok(())
}

/// `pose` shifted and turned about the world's z axis (through the box's centre), then raised
/// so that its lowest corner is at `lowest_z`.
fn disturbed(body: &BoxBody, pose: Pose, lowest_z: f64) -> Pose {
    let (s, c) = (TURN_RAD / 2.0).sin_cos();
    let [w, x, y, z] = pose.quat_wxyz;
    // (cos, 0, 0, sin) ⊗ q
    let quat_wxyz = [c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w];
    let [px, py, pz] = pose.translation;
    let turned = Pose {
        quat_wxyz,
        translation: [px + SHIFT_M[0], py + SHIFT_M[1], pz],
    };
    let below = pz - z_extent(body, &turned).0;
    Pose {
        translation: [
            turned.translation[0],
            turned.translation[1],
            lowest_z + below,
        ],
        ..turned
    }
}

/// Lowest and highest z of the box's corners at `pose`.
fn z_extent(body: &BoxBody, pose: &Pose) -> (f64, f64) {
    let r = rotation_matrix(pose.quat_wxyz);
    let reach: f64 = (0..3).map(|k| r[2][k].abs() * body.size[k] / 2.0).sum();
    (pose.translation[2] - reach, pose.translation[2] + reach)
}

fn keep_fastest(best: &mut Option<SettleOutcome>, outcome: SettleOutcome) {
    if best
        .as_ref()
        .is_none_or(|b| outcome.certificate.wall_time_s < b.certificate.wall_time_s)
    {
        *best = Some(outcome);
    }
}

fn verdict(outcome: &SettleOutcome) -> &'static str {
    outcome.rejection.map_or("stable", |r| r.as_str())
}
