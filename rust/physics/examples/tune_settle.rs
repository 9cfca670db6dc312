//! Tuning harness: settles every scene of a dataset (e.g. from `python -m drake_scenes.bench_settle`)
//! under several MuJoCo option sets and prints time, stability and agreement with the stored poses.
//!
//!     cargo run --release -p boxpose-physics --example tune_settle -- DATASET [REPEAT]

use std::collections::BTreeMap;

use boxpose_data::{Dataset, Object};
use boxpose_physics::{Cone, MujocoOptions, RecipePhysics, SceneDescription, Settler, Solver, down_face};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args.next().ok_or("usage: tune_settle DATASET [REPEAT]")?;
    let repeat: usize = args.next().map(|r| r.parse()).transpose()?.unwrap_or(3);
    let dataset = Dataset::open(&dir)?;
    let scenes = dataset.scenes()?;
    let mut objects: BTreeMap<i64, Vec<Object>> = BTreeMap::new();
    for o in dataset.objects()? {
        objects.entry(o.scene_id).or_default().push(o);
    }
    let d = MujocoOptions::default();
    let fast = MujocoOptions { tolerance: 1e-6, ..d };
    let variants: Vec<(&str, MujocoOptions)> = vec![
        ("tol 1e-6", fast),
        ("tol 1e-6 sleep 1e-4", MujocoOptions { sleep_tolerance: Some(1e-4), ..fast }),
        ("tol 1e-6 sleep 1e-3", MujocoOptions { sleep_tolerance: Some(1e-3), ..fast }),
        ("tol 1e-6 solref .01", MujocoOptions { solref: [0.01, 1.0], ..fast }),
        ("tol 1e-6 solref .01 sleep 1e-3", MujocoOptions { solref: [0.01, 1.0], sleep_tolerance: Some(1e-3), ..fast }),
    ];
    let _ = Solver::Newton;
    for (name, options) in &variants {
        let mut by_n: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
        let (mut stable, mut faces, mut boxes, mut sim, mut step_us) = (0, 0, 0, 0.0, BTreeMap::<usize, Vec<f64>>::new());
        for scene in &scenes {
            let mut objs = objects[&scene.scene_id].clone();
            objs.sort_by_key(|o| o.object_id);
            let recipe = RecipePhysics::from_toml(&scene.recipe_toml)?;
            let desc = SceneDescription::from_objects(recipe.support, &objs);
            let mut settler = Settler::with_options(&desc, &recipe.settle, options)?;
            let mut walls = Vec::new();
            let mut last = None;
            for _ in 0..repeat {
                let out = settler.settle()?;
                walls.push(out.certificate.wall_time_s);
                last = Some(out);
            }
            let out = last.unwrap();
            walls.sort_by(f64::total_cmp);
            by_n.entry(objs.len()).or_default().push(walls[walls.len() / 2]);
            step_us.entry(objs.len()).or_default().push(walls[0] / out.certificate.steps as f64 * 1e6);
            stable += usize::from(out.stable);
            sim += out.certificate.settle_time_s;
            for (o, p) in objs.iter().zip(&out.poses) {
                faces += usize::from(down_face(o.world_box.quat_wxyz).0 == down_face(p.quat_wxyz).0);
                boxes += 1;
            }
        }
        let times: Vec<String> = by_n
            .iter()
            .map(|(n, w)| {
                let us = &step_us[n];
                format!("{n} boxes {:.1} ms ({:.0} µs/step)", w.iter().sum::<f64>() / w.len() as f64 * 1e3, us.iter().sum::<f64>() / us.len() as f64)
            })
            .collect();
        println!(
            "{name:<22} {}  stable {stable}/{}  faces {faces}/{boxes}  mean sim {:.2} s",
            times.join(", "),
            scenes.len(),
            sim / scenes.len() as f64
        );
    }
    Ok(())
}
