//! Real-MuJoCo tests of the settler: single drops, stacks, reuse, supports and bad input.

mod common;

use std::f64::consts::PI;

use boxpose_physics::{
    BoxBody, CREEP_CURE, CreepCure, Face, MujocoOptions, PhysicsError, Pose, RecipePhysics,
    Rejection, SceneDescription, SettleParams, Settler, Support, SupportKind, down_face, resettle,
    settle,
};
use common::*;

const SIZE: [f64; 3] = [0.16, 0.12, 0.08];

fn params() -> SettleParams {
    SettleParams::default()
}

fn assert_at_rest(outcome: &boxpose_physics::SettleOutcome, what: &str) {
    let c = &outcome.certificate;
    assert!(outcome.settled, "{what}: not settled: {c:?}");
    assert!(
        outcome.stable,
        "{what}: not stable ({:?}): {c:?}\n{:?}",
        outcome.rejection, outcome.poses
    );
    assert!(
        c.max_linear_speed_mps < params().max_linear_speed_mps,
        "{what}: {c:?}"
    );
    assert!(
        c.max_angular_speed_radps < params().max_angular_speed_radps,
        "{what}: {c:?}"
    );
    assert!(
        c.min_signed_distance_m >= -params().max_penetration_m,
        "{what}: {c:?}"
    );
    assert!(c.settle_time_s <= params().max_time_s, "{what}: {c:?}");
}

#[test]
fn every_shipped_recipe_parses() {
    let root = std::path::PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../datasets/recipes"
    ));
    let mut count = 0;
    for entry in std::fs::read_dir(&root).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            RecipePhysics::from_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            count += 1;
        }
    }
    assert!(count >= 3, "recipes found: {count}");
    let tiny = RecipePhysics::from_file(&root.join("tiny.toml")).unwrap();
    assert_eq!(tiny.settle, SettleParams::default());
    assert_eq!(tiny.support.kind, SupportKind::Floor);
}

#[test]
fn box_resting_flat_stays_put() {
    let scene = floor_scene(vec![dropped_box(
        SIZE,
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0],
        0.0,
        0.7,
    )]);
    let out = settle(&scene, &params()).unwrap();
    assert_at_rest(&out, "resting box");
    let t = out.poses[0].translation;
    assert!((t[2] - SIZE[2] / 2.0).abs() < 5e-4, "centre height {t:?}");
    assert!(t[0].abs() < 1e-4 && t[1].abs() < 1e-4, "drifted to {t:?}");
    // A box starting at rest settles after one window.
    assert!(
        out.certificate.settle_time_s < params().window_s + 0.05,
        "{:?}",
        out.certificate
    );
}

/// Small drops, tilted up to 15° off a face: the box lands on that face.
#[test]
fn single_box_lands_on_the_face_nearest_down() {
    // One orientation per face down: identity (−z down), flipped (+z), ±90° about x and y.
    let bases = [
        axis_angle([1.0, 0.0, 0.0], 0.0),
        axis_angle([1.0, 0.0, 0.0], PI),
        axis_angle([1.0, 0.0, 0.0], PI / 2.0),
        axis_angle([1.0, 0.0, 0.0], -PI / 2.0),
        axis_angle([0.0, 1.0, 0.0], PI / 2.0),
        axis_angle([0.0, 1.0, 0.0], -PI / 2.0),
    ];
    let faces: Vec<(Face, [f64; 4])> = bases.iter().map(|&q| (down_face(q).0, q)).collect();
    assert_eq!(
        faces
            .iter()
            .map(|f| f.0)
            .collect::<std::collections::HashSet<_>>()
            .len(),
        6,
        "one base per face"
    );
    let faces: Vec<([f64; 4], Face)> = faces.into_iter().map(|(f, q)| (q, f)).collect();
    let mut rng = Rng(0x5eed);
    for (k, (base, face)) in faces.iter().enumerate() {
        for trial in 0..3 {
            let tilt_axis = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), 0.0];
            let tilt = rng.uniform(0.0, 15f64.to_radians());
            let yaw = rng.uniform(-PI, PI);
            let q = qmul(
                axis_angle(tilt_axis, tilt),
                qmul(axis_angle([0.0, 0.0, 1.0], yaw), *base),
            );
            let gap = rng.uniform(0.005, 0.03);
            assert_eq!(down_face(q).0, *face, "test setup: case {k}.{trial}");
            let scene = floor_scene(vec![dropped_box(SIZE, q, [0.0, 0.0], gap, 0.7)]);
            let out = settle(&scene, &params()).unwrap();
            let what = format!(
                "case {k}.{trial} (tilt {:.1}°, gap {gap:.3} m)",
                tilt.to_degrees()
            );
            assert_at_rest(&out, &what);
            let (landed, final_tilt) = down_face(out.poses[0].quat_wxyz);
            assert_eq!(landed, *face, "{what}");
            assert!(final_tilt < 1f64.to_radians(), "{what}: tilt {final_tilt}");
            let height = out.poses[0].translation[2];
            assert!(
                (height - SIZE[face.axis] / 2.0).abs() < 1e-3,
                "{what}: centre at z = {height}"
            );
        }
    }
}

/// Any orientation, drops up to 15 cm: the box ends statically stable, flat on some face.
#[test]
fn single_box_any_orientation_ends_on_a_face() {
    let mut rng = Rng(42);
    for trial in 0..12 {
        let size = [
            rng.uniform(0.06, 0.2),
            rng.uniform(0.05, 0.16),
            rng.uniform(0.04, 0.12),
        ];
        let gap = rng.uniform(0.02, 0.15);
        let scene = floor_scene(vec![dropped_box(
            size,
            rng.quat(),
            [0.0, 0.0],
            gap,
            rng.uniform(0.5, 0.9),
        )]);
        let out = settle(&scene, &params()).unwrap();
        let what = format!("trial {trial}");
        assert_at_rest(&out, &what);
        let (face, tilt) = down_face(out.poses[0].quat_wxyz);
        assert!(
            tilt < 1f64.to_radians(),
            "{what}: tilt {}°",
            tilt.to_degrees()
        );
        let height = out.poses[0].translation[2];
        assert!(
            (height - size[face.axis] / 2.0).abs() < 1e-3,
            "{what}: centre at z = {height}, face {face}"
        );
    }
}

#[test]
fn stack_of_three_stays_stacked() {
    let sizes = [[0.2, 0.16, 0.08], [0.16, 0.12, 0.06], [0.1, 0.08, 0.05]];
    let mut z = 0.0;
    let mut boxes = Vec::new();
    for (i, s) in sizes.iter().enumerate() {
        z += 0.005;
        let yaw = axis_angle([0.0, 0.0, 1.0], 0.2 * i as f64);
        let mut b = dropped_box(*s, yaw, [0.01 * i as f64, 0.0], 0.0, 0.7);
        b.initial.translation[2] = z + s[2] / 2.0;
        z += s[2];
        boxes.push(b);
    }
    let out = settle(&floor_scene(boxes), &params()).unwrap();
    assert_at_rest(&out, "stack");
    let mut top = 0.0;
    for (s, p) in sizes.iter().zip(&out.poses) {
        assert!(
            (p.translation[2] - (top + s[2] / 2.0)).abs() < 2e-3,
            "stack layer at {:?}",
            p.translation
        );
        assert!(down_face(p.quat_wxyz).1 < 1f64.to_radians());
        top += s[2];
    }
}

/// Boxes dropped on top of each other from scattered poses: stable, no deep penetration,
/// nothing below the floor.
#[test]
fn multi_box_drop_is_stable_without_penetration() {
    let mut rng = Rng(7);
    for (trial, n) in [(0, 5), (1, 8), (2, 12)] {
        // Four columns, layers 0.3 m apart: bounding spheres (radius ≤ 0.135 m) never overlap.
        let boxes: Vec<BoxBody> = (0..n)
            .map(|i| {
                let size = [
                    rng.uniform(0.06, 0.2),
                    rng.uniform(0.05, 0.16),
                    rng.uniform(0.04, 0.12),
                ];
                let (sx, sy) = (
                    if i % 2 == 0 { -1.0 } else { 1.0 },
                    if i % 4 < 2 { -1.0 } else { 1.0 },
                );
                let xy = [
                    sx * 0.14 + rng.uniform(-0.06, 0.06),
                    sy * 0.14 + rng.uniform(-0.06, 0.06),
                ];
                let mut b = dropped_box(size, rng.quat(), xy, 0.0, rng.uniform(0.5, 0.9));
                b.initial.translation[2] = 0.14 + 0.3 * (i / 4) as f64;
                b
            })
            .collect();
        // Boxes tumbling off a tall pile can roll far: a wide region keeps this test about contact.
        let scene = SceneDescription {
            support: Support {
                half_extent_m: [1.0, 1.0],
                ..Support::floor()
            },
            boxes,
        };
        let out = settle(&scene, &params()).unwrap();
        let what = format!("trial {trial}: {n} boxes");
        assert_at_rest(&out, &what);
        for (b, p) in scene.boxes.iter().zip(&out.poses) {
            assert!(
                lowest_z(b.size, p) > -params().max_penetration_m,
                "{what}: box below the floor at {p:?}"
            );
        }
    }
}

/// A settled 8-box pile, its highest box lifted and dropped back: the re-settle with the pile
/// asleep certifies the drop, leaves the boxes the drop never touched exactly where they rested,
/// and lands the dropped box where the all-awake reference does.
#[test]
fn a_box_dropped_onto_a_settled_pile_wakes_only_what_it_touches() {
    let mut rng = Rng(21);
    let boxes: Vec<BoxBody> = (0..8)
        .map(|i| {
            let size = [
                rng.uniform(0.06, 0.16),
                rng.uniform(0.05, 0.14),
                rng.uniform(0.04, 0.10),
            ];
            // two rows of four, well apart: a pile of separate little stacks
            let xy = [
                -0.3 + 0.2 * (i % 4) as f64,
                if i < 4 { -0.15 } else { 0.15 },
            ];
            dropped_box(size, rng.quat(), xy, 0.02, rng.uniform(0.5, 0.9))
        })
        .collect();
    let pile = SceneDescription {
        support: Support {
            half_extent_m: [0.5, 0.5],
            ..Support::floor()
        },
        boxes,
    };
    let settled = settle(&pile, &params()).unwrap();
    assert_at_rest(&settled, "the pile");
    let moved = 5;
    let mut drop = settled.poses[moved];
    drop.translation[2] += 0.1;
    drop.quat_wxyz = qmul(axis_angle([0.0, 0.0, 1.0], 0.5), drop.quat_wxyz);
    let asleep = resettle(&pile, &settled.poses, moved, drop, &params()).unwrap();
    assert_at_rest(&asleep, "re-settle, pile asleep");
    let mut start = settled.poses.clone();
    start[moved] = drop;
    let awake = Settler::new(&pile, &params())
        .unwrap()
        .settle_from(&start)
        .unwrap();
    assert_at_rest(&awake, "re-settle, pile awake");
    // boxes far from the drop slept through it: their poses are the stored ones, bit for bit
    let untouched = (0..8)
        .filter(|&i| i != moved && asleep.poses[i] == settled.poses[i])
        .count();
    assert!(
        untouched >= 6,
        "only {untouched} of 7 boxes slept through the drop"
    );
    // awake, the soft contacts move every box a little: bit-identical poses come from sleeping
    let awake_untouched = (0..8)
        .filter(|&i| i != moved && awake.poses[i] == settled.poses[i])
        .count();
    assert_eq!(awake_untouched, 0);
    let (a, b) = (asleep.poses[moved], awake.poses[moved]);
    assert_eq!(down_face(a.quat_wxyz).0, down_face(b.quat_wxyz).0);
    let gap = (0..3)
        .map(|k| (a.translation[k] - b.translation[k]).powi(2))
        .sum::<f64>();
    assert!(
        gap.sqrt() < 0.01,
        "dropped box {:.1} mm from the reference",
        gap.sqrt() * 1e3
    );
    let out_of_range = resettle(&pile, &settled.poses, 8, drop, &params()).unwrap_err();
    assert!(matches!(
        out_of_range,
        PhysicsError::NoSuchBox { index: 8, count: 8 }
    ));
}

#[test]
fn reuse_gives_identical_results() {
    let mut rng = Rng(99);
    let boxes: Vec<BoxBody> = (0..4)
        .map(|i| {
            let size = [
                rng.uniform(0.06, 0.2),
                rng.uniform(0.05, 0.16),
                rng.uniform(0.04, 0.12),
            ];
            let mut b = dropped_box(
                size,
                rng.quat(),
                [rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)],
                0.0,
                0.6,
            );
            b.initial.translation[2] = 0.15 + 0.25 * i as f64;
            b
        })
        .collect();
    let scene = floor_scene(boxes);
    let other: Vec<Pose> = scene
        .initial_poses()
        .iter()
        .map(|p| Pose {
            quat_wxyz: rng.quat(),
            translation: [p.translation[0] + 0.02, p.translation[1], p.translation[2]],
        })
        .collect();

    let mut settler = Settler::new(&scene, &params()).unwrap();
    let first = settler.settle().unwrap();
    let between = settler.settle_from(&other).unwrap();
    let again = settler.settle_from(&scene.initial_poses()).unwrap();
    let fresh = settle(&scene, &params()).unwrap();
    assert_ne!(first.poses, between.poses);
    for out in [&again, &fresh] {
        assert_eq!(out.poses, first.poses);
        assert_eq!(out.settled, first.settled);
        let (a, b) = (&out.certificate, &first.certificate);
        assert_eq!(
            (a.steps, a.settle_time_s, a.min_signed_distance_m),
            (b.steps, b.settle_time_s, b.min_signed_distance_m)
        );
        assert_eq!(
            (a.max_linear_speed_mps, a.max_angular_speed_radps),
            (b.max_linear_speed_mps, b.max_angular_speed_radps)
        );
    }
}

/// The creep cure ([`CREEP_CURE`]) switches the friction settings at its time and no earlier: a
/// box at rest before then settles exactly as without the cure; switched on from the start it is
/// exactly the stiffer settings compiled in; and a settler whose last settle switched it on
/// starts the next one with its own settings again.
#[test]
fn the_creep_cure_switches_at_its_time_and_is_undone_on_reuse() {
    let settle_with = |scene: &SceneDescription, options: MujocoOptions| {
        Settler::with_options(scene, &params(), &options)
            .unwrap()
            .settle()
            .unwrap()
    };
    let no_cure = MujocoOptions {
        creep_cure: None,
        ..MujocoOptions::default()
    };

    let quick = floor_scene(vec![dropped_box(
        SIZE,
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0],
        0.005,
        0.6,
    )]);
    let cured = settle_with(&quick, MujocoOptions::default());
    assert!(
        cured.certificate.settle_time_s < CREEP_CURE.after_s,
        "{:?}",
        cured.certificate
    );
    let plain = settle_with(&quick, no_cure);
    assert_eq!(
        (cured.poses, cured.certificate.steps),
        (plain.poses, plain.certificate.steps)
    );

    let mut rng = Rng(5);
    let pile = floor_scene(
        (0..4)
            .map(|i| {
                let mut b =
                    dropped_box(SIZE, rng.quat(), [rng.uniform(-0.05, 0.05), 0.0], 0.0, 0.6);
                b.initial.translation[2] = 0.15 + 0.25 * i as f64;
                b
            })
            .collect(),
    );
    let from_start = settle_with(
        &pile,
        MujocoOptions {
            creep_cure: Some(CreepCure {
                after_s: 0.0,
                ..CREEP_CURE
            }),
            ..MujocoOptions::default()
        },
    );
    let compiled_in = settle_with(
        &pile,
        MujocoOptions {
            impratio: CREEP_CURE.impratio,
            noslip_iterations: CREEP_CURE.noslip_iterations,
            ..no_cure
        },
    );
    assert_eq!(from_start.poses, compiled_in.poses);
    assert_eq!(from_start.certificate.steps, compiled_in.certificate.steps);

    let mut settler = Settler::new(&pile, &params()).unwrap();
    let first = settler.settle().unwrap();
    assert!(
        first.certificate.settle_time_s > CREEP_CURE.after_s,
        "{:?}",
        first.certificate
    );
    let again = settler.settle().unwrap();
    assert_eq!(
        (first.poses, first.certificate.steps),
        (again.poses, again.certificate.steps)
    );
}

#[test]
fn not_settled_by_max_time_is_reported() {
    let scene = floor_scene(vec![dropped_box(
        SIZE,
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0],
        0.5,
        0.7,
    )]);
    // 0.1 s is not enough to fall 0.5 m and rest for 0.05 s.
    let short = SettleParams {
        max_time_s: 0.1,
        window_s: 0.05,
        ..params()
    };
    let out = settle(&scene, &short).unwrap();
    assert!(!out.settled && !out.stable);
    assert_eq!(out.rejection, Some(Rejection::NotSettled));
    assert!((out.certificate.settle_time_s - 0.1).abs() < 1e-9);
    assert!(
        out.certificate.max_linear_speed_mps > 0.5,
        "{:?}",
        out.certificate
    );
}

#[test]
fn bin_walls_contain_boxes() {
    let support = Support {
        kind: SupportKind::Bin,
        half_extent_m: [0.12, 0.12],
        wall_height_m: 0.6,
    };
    let mut rng = Rng(3);
    let boxes: Vec<BoxBody> = (0..6)
        .map(|i| {
            let mut b = dropped_box(
                [0.1, 0.08, 0.06],
                rng.quat(),
                [rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05)],
                0.0,
                0.6,
            );
            b.initial.translation[2] = 0.1 + 0.1 * i as f64;
            b
        })
        .collect();
    let scene = SceneDescription { support, boxes };
    let out = settle(&scene, &params()).unwrap();
    assert_at_rest(&out, "bin");
    for p in &out.poses {
        let t = p.translation;
        assert!(
            t[0].abs() < 0.12 && t[1].abs() < 0.12,
            "box escaped the bin: {t:?}"
        );
    }
}

/// A box falling against a wall leans on it and stays inside.
#[test]
fn box_leaning_on_bin_wall_stays_inside() {
    let support = Support {
        kind: SupportKind::Bin,
        half_extent_m: [0.12, 0.12],
        wall_height_m: 0.3,
    };
    // Tall box, close to the +x wall, tipped towards it.
    let size = [0.05, 0.08, 0.16];
    let b = dropped_box(
        size,
        axis_angle([0.0, 1.0, 0.0], 0.5),
        [0.12 - 0.06, 0.0],
        0.01,
        0.7,
    );
    let out = settle(
        &SceneDescription {
            support,
            boxes: vec![b.clone()],
        },
        &params(),
    )
    .unwrap();
    assert_at_rest(&out, "leaning box");
    let r = boxpose_physics::rotation_matrix(out.poses[0].quat_wxyz);
    let reach_x: f64 = (0..3).map(|k| r[0][k].abs() * size[k] / 2.0).sum();
    let right = out.poses[0].translation[0] + reach_x;
    assert!(
        right < 0.12 + params().max_penetration_m,
        "box reaches x = {right} through the wall at 0.12: {:?}",
        out.poses[0]
    );
    // Without walls the same drop tips over further out.
    let free = settle(&floor_scene(vec![b]), &params()).unwrap();
    assert!(
        free.poses[0].translation[0] > out.poses[0].translation[0] + 0.01,
        "{:?} vs {:?}",
        free.poses[0],
        out.poses[0]
    );
}

#[test]
fn pallet_deck_holds_boxes_and_the_ground_does_not() {
    let support = Support {
        kind: SupportKind::Pallet,
        half_extent_m: [0.3, 0.2],
        wall_height_m: 0.0,
    };
    let top = boxpose_physics::PALLET_HEIGHT_M;
    let mut on_deck = dropped_box(
        SIZE,
        axis_angle([0.0, 0.0, 1.0], 0.3),
        [0.0, 0.0],
        0.03,
        0.7,
    );
    on_deck.initial.translation[2] += top;
    let out = settle(
        &SceneDescription {
            support,
            boxes: vec![on_deck.clone()],
        },
        &params(),
    )
    .unwrap();
    assert_at_rest(&out, "pallet");
    assert!(
        (out.poses[0].translation[2] - (top + SIZE[2] / 2.0)).abs() < 1e-3,
        "{:?}",
        out.poses[0]
    );

    // Dropped beyond the deck's edge: it lands on the ground, which is not the support region.
    let off_deck = dropped_box(SIZE, [1.0, 0.0, 0.0, 0.0], [0.6, 0.0], 0.03, 0.7);
    let out = settle(
        &SceneDescription {
            support,
            boxes: vec![on_deck, off_deck],
        },
        &params(),
    )
    .unwrap();
    assert!(out.settled && !out.stable, "{out:?}");
    assert_eq!(out.rejection, Some(Rejection::LeftSupport));
    assert!(
        (out.poses[1].translation[2] - SIZE[2] / 2.0).abs() < 1e-3,
        "{:?}",
        out.poses[1]
    );
}

#[test]
fn mjcf_names_every_parameter() {
    let scene = floor_scene(vec![dropped_box(
        SIZE,
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0],
        0.01,
        0.7,
    )]);
    let settler = Settler::new(&scene, &params()).unwrap();
    let mjcf = settler.mjcf();
    for needle in [
        r#"timestep="0.001""#,
        r#"cone="elliptic""#,
        r#"solref="0.01 1""#,
        r#"type="plane""#,
        "<pair",
        r#"size="0.08 0.06 0.04""#,
        "<freejoint",
    ] {
        assert!(mjcf.contains(needle), "{needle} missing from\n{mjcf}");
    }
}

#[test]
fn bad_input_is_a_clear_error() {
    let good = dropped_box(SIZE, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0], 0.01, 0.7);
    let with = |f: &dyn Fn(&mut BoxBody)| {
        let mut b = good.clone();
        f(&mut b);
        settle(&floor_scene(vec![good.clone(), b]), &params()).unwrap_err()
    };
    assert!(matches!(
        with(&|b| b.size[1] = 0.0),
        PhysicsError::BadSize { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.size[0] = -0.1),
        PhysicsError::BadSize { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.size[2] = f64::NAN),
        PhysicsError::BadSize { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.mass_kg = 0.0),
        PhysicsError::BadMass { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.friction = -1.0),
        PhysicsError::BadFriction { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.initial.translation[2] = f64::NAN),
        PhysicsError::NonFinitePose { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.initial.quat_wxyz[0] = f64::INFINITY),
        PhysicsError::NonFinitePose { index: 1, .. }
    ));
    assert!(matches!(
        with(&|b| b.initial.quat_wxyz = [1.0, 1.0, 0.0, 0.0]),
        PhysicsError::NonUnitQuaternion { index: 1, .. }
    ));
    assert!(matches!(
        settle(&floor_scene(vec![]), &params()).unwrap_err(),
        PhysicsError::NoBoxes
    ));

    let scene = floor_scene(vec![good.clone()]);
    let bad_params = SettleParams {
        time_step_s: 0.0,
        ..params()
    };
    assert!(matches!(
        settle(&scene, &bad_params).unwrap_err(),
        PhysicsError::BadParams(_)
    ));
    let bad_params = SettleParams {
        window_s: 10.0,
        ..params()
    };
    assert!(matches!(
        settle(&scene, &bad_params).unwrap_err(),
        PhysicsError::BadParams(_)
    ));
    let bin = SceneDescription {
        support: Support {
            kind: SupportKind::Bin,
            half_extent_m: [0.2, 0.2],
            wall_height_m: 0.0,
        },
        boxes: vec![good.clone()],
    };
    assert!(matches!(
        settle(&bin, &params()).unwrap_err(),
        PhysicsError::BadSupport(_)
    ));

    let mut settler = Settler::new(&scene, &params()).unwrap();
    assert!(matches!(
        settler.settle_from(&[]).unwrap_err(),
        PhysicsError::PoseCount {
            count: 0,
            expected: 1
        }
    ));
    let nan = Pose {
        quat_wxyz: [f64::NAN, 0.0, 0.0, 0.0],
        translation: [0.0; 3],
    };
    let err = settler.settle_from(&[nan]).unwrap_err();
    assert!(
        matches!(err, PhysicsError::NonFinitePose { index: 0, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("box 0"), "{err}");
    // The settler is still usable after rejected input.
    assert!(settler.settle().unwrap().stable);

    // Positive but below MuJoCo's minimum mass: MuJoCo's compiler refuses it, and says why.
    let err = with(&|b| b.mass_kg = 1e-20);
    let PhysicsError::Compile { message } = &err else {
        panic!("expected a compile error, got {err}")
    };
    assert!(message.to_lowercase().contains("mass"), "{message}");

    let err = RecipePhysics::from_toml("[support]\nkind = \"table\"\nhalf_extent_m = [0.2, 0.2]\n")
        .unwrap_err();
    assert!(matches!(err, PhysicsError::Recipe(_)), "{err}");
    let err = RecipePhysics::from_toml(
        "[support]\nkind = \"floor\"\nhalf_extent_m = [0.2, 0.2]\nwall_height_m = 0.0\n",
    )
    .unwrap_err();
    assert!(err.to_string().contains("settle"), "{err}");
    let err = RecipePhysics::from_toml("[support]\nkind = \"floor\"\nhalf_extent_m = [0.2, 0.2]\n")
        .unwrap_err();
    assert!(err.to_string().contains("wall_height_m"), "{err}");
}
