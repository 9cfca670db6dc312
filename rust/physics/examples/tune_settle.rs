//! Tuning harness: settles every scene of a dataset (e.g. from `python -m drake_scenes.bench_settle`)
//! under several MuJoCo option sets and prints time, stability and agreement with the stored
//! poses. Variants are interleaved over ROUNDS rounds and each scene's fastest settle is kept, so
//! other load on the machine disturbs the comparison as little as possible.
//!
//!     cargo run --release -p boxpose-physics --example tune_settle -- DATASET [ROUNDS]

use std::collections::BTreeMap;

use boxpose_data::{Dataset, Object};
use boxpose_physics::{
    CREEP_CURE, Cone, CreepCure, Integrator, MujocoOptions, RecipePhysics, SceneDescription,
    SettleOutcome, Settler, down_face,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args.next().ok_or("usage: tune_settle DATASET [ROUNDS]")?;
    let rounds: usize = args.next().map(|r| r.parse()).transpose()?.unwrap_or(5);
    let dataset = Dataset::open(&dir)?;
    let scenes = dataset.scenes()?;
    let mut objects: BTreeMap<i64, Vec<Object>> = BTreeMap::new();
    for o in dataset.objects()? {
        objects.entry(o.scene_id).or_default().push(o);
    }
    let d = MujocoOptions::default();
    let variants: Vec<(&str, MujocoOptions)> = vec![
        ("default", d),
        (
            "no creep cure",
            MujocoOptions {
                creep_cure: None,
                ..d
            },
        ),
        (
            "cure after 0.5 s",
            MujocoOptions {
                creep_cure: Some(CreepCure {
                    after_s: 0.5,
                    ..CREEP_CURE
                }),
                ..d
            },
        ),
        (
            "cure after 1.5 s",
            MujocoOptions {
                creep_cure: Some(CreepCure {
                    after_s: 1.5,
                    ..CREEP_CURE
                }),
                ..d
            },
        ),
        (
            "solref 0.01",
            MujocoOptions {
                solref: [0.01, 1.0],
                ..d
            },
        ),
        (
            "solref 0.004",
            MujocoOptions {
                solref: [0.004, 1.0],
                ..d
            },
        ),
        (
            "impratio 100",
            MujocoOptions {
                impratio: 100.0,
                ..d
            },
        ),
        (
            "solref .004 imp 100",
            MujocoOptions {
                solref: [0.004, 1.0],
                impratio: 100.0,
                ..d
            },
        ),
        (
            "solref .01 imp 100",
            MujocoOptions {
                solref: [0.01, 1.0],
                impratio: 100.0,
                ..d
            },
        ),
        (
            "noslip 10",
            MujocoOptions {
                noslip_iterations: 10,
                ..d
            },
        ),
        (
            "Euler",
            MujocoOptions {
                integrator: Integrator::Euler,
                ..d
            },
        ),
        (
            "Euler imp 100",
            MujocoOptions {
                integrator: Integrator::Euler,
                impratio: 100.0,
                ..d
            },
        ),
        (
            "Euler noslip 10",
            MujocoOptions {
                integrator: Integrator::Euler,
                noslip_iterations: 10,
                ..d
            },
        ),
        (
            "imp 100 noslip 10",
            MujocoOptions {
                impratio: 100.0,
                noslip_iterations: 10,
                ..d
            },
        ),
        (
            "pyramidal",
            MujocoOptions {
                cone: Cone::Pyramidal,
                impratio: 1.0,
                ..d
            },
        ),
        (
            "sleep 1e-3",
            MujocoOptions {
                sleep_tolerance: Some(1e-3),
                ..d
            },
        ),
    ];
    // One settler per (variant, scene), built up front.
    let mut settlers = Vec::new();
    for (_, options) in &variants {
        let mut row = Vec::new();
        for scene in &scenes {
            let mut objs = objects[&scene.scene_id].clone();
            objs.sort_by_key(|o| o.object_id);
            let recipe = RecipePhysics::from_toml(&scene.recipe_toml)?;
            let desc = SceneDescription::from_objects(recipe.support, &objs);
            row.push((Settler::with_options(&desc, &recipe.settle, options)?, objs));
        }
        settlers.push(row);
    }
    let mut best = vec![vec![f64::INFINITY; scenes.len()]; variants.len()];
    let mut outcomes: Vec<Vec<Option<SettleOutcome>>> =
        vec![vec![None; scenes.len()]; variants.len()];
    for _ in 0..rounds {
        for (v, row) in settlers.iter_mut().enumerate() {
            for (k, (settler, _)) in row.iter_mut().enumerate() {
                let out = settler.settle()?;
                best[v][k] = best[v][k].min(out.certificate.wall_time_s);
                outcomes[v][k] = Some(out);
            }
        }
    }
    for (v, (name, _)) in variants.iter().enumerate() {
        let mut by_n: BTreeMap<usize, Vec<(f64, f64)>> = BTreeMap::new();
        let (mut stable, mut faces, mut boxes, mut sim) = (0, 0, 0, 0.0);
        // of the piles Drake certified, those MuJoCo certifies too
        let (mut certified, mut both) = (0, 0);
        for (k, (_, objs)) in settlers[v].iter().enumerate() {
            let out = outcomes[v][k].as_ref().unwrap();
            let c = &out.certificate;
            by_n.entry(objs.len())
                .or_default()
                .push((best[v][k], best[v][k] / c.steps as f64));
            stable += usize::from(out.stable);
            certified += usize::from(scenes[k].stable);
            both += usize::from(scenes[k].stable && out.stable);
            sim += c.settle_time_s;
            for (o, p) in objs.iter().zip(&out.poses) {
                faces +=
                    usize::from(down_face(o.world_box.quat_wxyz).0 == down_face(p.quat_wxyz).0);
                boxes += 1;
            }
        }
        let times: Vec<String> = by_n
            .iter()
            .map(|(n, w)| {
                let m = w.len() as f64;
                let (ms, us) = (
                    w.iter().map(|x| x.0).sum::<f64>() / m * 1e3,
                    w.iter().map(|x| x.1).sum::<f64>() / m * 1e6,
                );
                format!("{n} boxes {ms:6.1} ms ({us:3.0} µs/step)")
            })
            .collect();
        println!(
            "{name:<14} {}  stable {stable}/{} (Drake-certified {both}/{certified})  same face as stored {faces}/{boxes}  mean sim {:.2} s",
            times.join(", "),
            scenes.len(),
            sim / scenes.len() as f64
        );
    }
    Ok(())
}
