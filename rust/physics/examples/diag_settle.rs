//! Diagnostics: steps one scene of a dataset and prints contacts, constraint rows, islands and
//! solver iterations every 100 steps.
//!
//!     cargo run --release -p boxpose-physics --example diag_settle -- DATASET SCENE_ID [TOLERANCE [STEPS]]

use boxpose_data::Dataset;
use boxpose_physics::{MujocoOptions, RecipePhysics, SceneDescription, to_mjcf_with};
use mujoco_rs::prelude::*;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let dataset = Dataset::open(&args[1])?;
    let id: i64 = args[2].parse()?;
    let tolerance: f64 = args.get(3).map(|t| t.parse()).transpose()?.unwrap_or(1e-8);
    let scene = dataset
        .scenes()?
        .into_iter()
        .find(|s| s.scene_id == id)
        .ok_or("no such scene")?;
    let mut objs: Vec<_> = dataset
        .objects()?
        .into_iter()
        .filter(|o| o.scene_id == id)
        .collect();
    objs.sort_by_key(|o| o.object_id);
    let recipe = RecipePhysics::from_toml(&scene.recipe_toml)?;
    let desc = SceneDescription::from_objects(recipe.support, &objs);
    let options = MujocoOptions {
        tolerance,
        ..Default::default()
    };
    let model = MjModel::from_xml_string(&to_mjcf_with(&desc, &recipe.settle, &options))?;
    let mut data = MjData::new(&model);
    let (mut iters, mut t0) = (0i64, std::time::Instant::now());
    let steps: usize = args.get(4).map(|t| t.parse()).transpose()?.unwrap_or(2000);
    for step in 1..=steps {
        data.step();
        let d = data.ffi();
        iters += d.solver_niter.iter().map(|&n| n as i64).sum::<i64>();
        if step % 100 == 0 {
            let speeds: Vec<(f64, f64)> = data
                .qvel()
                .chunks(6)
                .map(|q| {
                    (
                        (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt(),
                        (q[3] * q[3] + q[4] * q[4] + q[5] * q[5]).sqrt(),
                    )
                })
                .collect();
            let (fastest, &(vmax, wmax)) = speeds
                .iter()
                .enumerate()
                .max_by(|a, b| {
                    (a.1.0 / 0.005 + a.1.1 / 0.05).total_cmp(&(b.1.0 / 0.005 + b.1.1 / 0.05))
                })
                .unwrap();
            let z = data.qpos()[7 * fastest + 2];
            println!(
                "step {step:>5}  ncon {:>3}  nefc {:>4}  nisland {:>2}  solver iters/step {:>5.1}  box {fastest} |v| {vmax:.4} |w| {wmax:.3} z {z:.3}  {:>5.0} µs/step",
                d.ncon,
                d.nefc,
                d.nisland,
                iters as f64 / 100.0,
                t0.elapsed().as_secs_f64() / 100.0 * 1e6
            );
            iters = 0;
            t0 = std::time::Instant::now();
        }
    }
    Ok(())
}
