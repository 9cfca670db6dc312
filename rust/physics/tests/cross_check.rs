//! The cross-check: the same initial states settled by BOTH engines. Drake
//! (`python -m drake_scenes.bench_settle`, the tiny recipe) samples, projects and settles
//! single-box and multi-box scenes into a temp dataset; MuJoCo settles the same initial poses.
//! Both must end statically stable and every single box must rest on the same face.
//!
//! Needs the project's venv with Drake (`make setup`), as every MuJoCo test does for libmujoco.

mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::Command;

use boxpose_data::{Dataset, Object};
use boxpose_physics::{RecipePhysics, SceneDescription, Settler, down_face};

fn repo_root() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

#[test]
fn drake_and_mujoco_agree_on_the_same_drops() {
    let root = repo_root();
    let python = root.join(".venv/bin/python");
    assert!(
        python.exists(),
        "{} missing: run `make setup` (the cross-check runs the Drake stage)",
        python.display()
    );
    let recipe_path = root.join("datasets/recipes/tiny.toml");
    let out = tempfile::tempdir().unwrap();
    let output = Command::new(&python)
        .current_dir(&root)
        .args(["-m", "drake_scenes.bench_settle", "--recipe"])
        .arg(&recipe_path)
        .args(["--boxes", "1", "3", "--scenes", "4", "--out"])
        .arg(out.path())
        .output()
        .expect("running the Drake stage");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "drake_scenes.bench_settle failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let drake: BTreeMap<i64, serde_json::Value> = stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .map(|v| (v["scene_id"].as_i64().unwrap(), v))
        .collect();

    let recipe = RecipePhysics::from_file(&recipe_path).unwrap();
    let dataset = Dataset::open(out.path()).unwrap();
    let mut objects: BTreeMap<i64, Vec<Object>> = BTreeMap::new();
    for o in dataset.objects().unwrap() {
        objects.entry(o.scene_id).or_default().push(o);
    }
    let (mut single, mut multi) = (0, 0);
    let mut report = Vec::new();
    for scene in dataset.scenes().unwrap() {
        let mut objs = objects.remove(&scene.scene_id).unwrap();
        objs.sort_by_key(|o| o.object_id);
        assert_eq!(
            drake[&scene.scene_id]["stable"].as_bool(),
            Some(scene.stable)
        );
        assert!(
            scene.stable,
            "Drake did not settle scene {}: {}",
            scene.scene_id, drake[&scene.scene_id]
        );

        let description = SceneDescription::from_objects(recipe.support, &objs);
        let outcome = Settler::new(&description, &recipe.settle)
            .unwrap()
            .settle()
            .unwrap();
        let c = &outcome.certificate;
        assert!(
            outcome.stable,
            "MuJoCo did not settle scene {} ({:?}): {c:?}",
            scene.scene_id, outcome.rejection
        );
        for (o, p) in objs.iter().zip(&outcome.poses) {
            let (drake_face, drake_tilt) = down_face(o.world_box.quat_wxyz);
            let (mujoco_face, mujoco_tilt) = down_face(p.quat_wxyz);
            let d = (0..3)
                .map(|k| (o.world_box.translation[k] - p.translation[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            report.push(format!(
                "scene {} box {}: drake {drake_face} ({:.1}°), mujoco {mujoco_face} ({:.1}°), centres {:.1} mm apart, mujoco {:.1} ms",
                scene.scene_id,
                o.object_id,
                drake_tilt.to_degrees(),
                mujoco_tilt.to_degrees(),
                d * 1e3,
                c.wall_time_s * 1e3
            ));
            if objs.len() == 1 {
                assert_eq!(
                    mujoco_face,
                    drake_face,
                    "scene {}: single box rests on different faces\n{}",
                    scene.scene_id,
                    report.join("\n")
                );
                assert!(mujoco_tilt < 1f64.to_radians() && drake_tilt < 1f64.to_radians());
                // Same face, same resting height.
                assert!(
                    (o.world_box.translation[2] - p.translation[2]).abs() < 2e-3,
                    "{}",
                    report.join("\n")
                );
            }
        }
        if objs.len() == 1 {
            single += 1
        } else {
            multi += 1
        }
    }
    println!("{}", report.join("\n"));
    assert!(
        single >= 2 && multi >= 2,
        "too few scenes projected: {single} single-box, {multi} multi-box"
    );
}
