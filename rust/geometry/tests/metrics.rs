use boxpose_geometry::metrics::*;
use boxpose_geometry::{BoxModel, GeometryError};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn generic() -> BoxModel {
    BoxModel::new(Vector3::new(0.3, 0.2, 0.1)).unwrap()
}

fn truth() -> Isometry3<f64> {
    Isometry3::new(Vector3::new(0.1, -0.2, 1.4), Vector3::new(0.3, 1.2, -0.5))
}

fn turned(pose: &Isometry3<f64>, axis: Vector3<f64>, degrees: f64) -> Isometry3<f64> {
    let turn = UnitQuaternion::from_scaled_axis(axis.normalize() * degrees.to_radians());
    Isometry3::from_parts(pose.translation, pose.rotation * turn)
}

#[test]
fn symmetric_poses_have_zero_error() {
    for model in [
        generic(),
        BoxModel::new(Vector3::new(0.2, 0.2, 0.1)).unwrap(),
        BoxModel::unit(),
    ] {
        let truth_corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth() * c).collect();
        for symmetry in model.symmetries() {
            let estimate = Isometry3::from_parts(
                truth().translation,
                truth().rotation * UnitQuaternion::from_rotation_matrix(&symmetry.rotation),
            );
            assert!(paper_error(&model, &estimate, &truth_corners).unwrap() < 1e-24);
            assert!(add_s(&model, &estimate, &truth()).unwrap() < 1e-12);
            assert!(add_s_corners(&model, &estimate, &truth()).unwrap() < 1e-12);
            assert!(mssd(&model, &estimate, &truth()).unwrap() < 1e-12);
            assert!(rotation_error_deg(&model, &estimate, &truth()).unwrap() < 1e-5);
        }
    }
}

#[test]
fn a_shift_shows_up_as_its_length() {
    let model = generic();
    let shift = Vector3::new(0.01, -0.02, 0.005);
    let estimate = Isometry3::from_parts(
        Translation3::from(truth().translation.vector + shift),
        truth().rotation,
    );
    let truth_corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth() * c).collect();
    // Each corner moves by `shift`, less than half an edge, so its nearest true corner is its own.
    assert!(
        (paper_error(&model, &estimate, &truth_corners).unwrap() - shift.norm_squared()).abs()
            < 1e-15
    );
    assert!((add_s_corners(&model, &estimate, &truth()).unwrap() - shift.norm()).abs() < 1e-12);
    // Nearest-point matching over the surface can only shorten the shift.
    let surface = add_s(&model, &estimate, &truth()).unwrap();
    assert!(surface > 0.0 && surface <= shift.norm() + 1e-12);
    assert!((surface - brute_force_adi(&model, &estimate, &model, &truth())).abs() < 1e-12);
    assert!((mssd(&model, &estimate, &truth()).unwrap() - shift.norm()).abs() < 1e-12);
    assert!((translation_error(&estimate, &truth()).unwrap() - shift.norm()).abs() < 1e-12);
    assert!(rotation_error_deg(&model, &estimate, &truth()).unwrap() < 1e-6);
}

/// bop_toolkit's `adi` written out: every truth-placed surface point to the nearest
/// estimate-placed one, by a scan over all of them.
fn brute_force_adi(
    estimated_box: &BoxModel,
    estimate: &Isometry3<f64>,
    true_box: &BoxModel,
    truth: &Isometry3<f64>,
) -> f64 {
    let placed: Vec<Point3<f64>> = surface_points(estimated_box)
        .iter()
        .map(|y| estimate * y)
        .collect();
    let truth_points = surface_points(true_box);
    truth_points
        .iter()
        .map(|x| {
            let target = truth * x;
            placed
                .iter()
                .map(|y| (y - target).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .sum::<f64>()
        / truth_points.len() as f64
}

/// Grid step along each side: side / ⌈side / (diameter/50)⌉.
fn steps(model: &BoxModel) -> Vector3<f64> {
    let spacing = model.diameter() / 50.0;
    model.size().map(|side| side / (side / spacing).ceil())
}

#[test]
fn surface_sample_covers_the_faces_uniformly() {
    for (model, count) in [(generic(), 4118), (BoxModel::unit(), 5046)] {
        let points = surface_points(&model);
        assert_eq!(points.len(), count);
        let half = model.size() * 0.5;
        let step = steps(&model);
        assert!(step.iter().all(|&s| s <= model.diameter() / 50.0 + 1e-15));
        for p in &points {
            // On exactly one face, strictly inside the others by half a step.
            let on_face = (0..3).filter(|&k| p[k].abs() == half[k]).count();
            assert_eq!(on_face, 1, "{p}");
            assert!((0..3).all(|k| p[k].abs() == half[k] || p[k].abs() <= half[k] - step[k] / 2.0 + 1e-15));
        }
    }
}

#[test]
fn add_s_of_a_small_shift_along_a_face_normal_is_the_shift() {
    // Shifting along z by s < δ_z/2 moves every surface point by s onto a point with no nearer
    // neighbour: the z faces keep their in-face grid, the side faces' nearest row is their own.
    let model = generic();
    let s = 0.4 * steps(&model).z;
    let along_z = truth().rotation * Vector3::z() * s;
    let estimate = Isometry3::from_parts(
        Translation3::from(truth().translation.vector + along_z),
        truth().rotation,
    );
    assert!((add_s(&model, &estimate, &truth()).unwrap() - s).abs() < 1e-12);
}

#[test]
fn add_s_of_a_half_turn_is_zero() {
    // 180° about each axis of a box with three different sides maps the surface sample onto itself.
    for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
        let estimate = turned(&truth(), axis, 180.0);
        assert!(add_s(&generic(), &estimate, &truth()).unwrap() < 1e-12);
    }
    // A quarter turn about z is not a symmetry of the generic box.
    let quarter = turned(&truth(), Vector3::z(), 90.0);
    assert!(add_s(&generic(), &quarter, &truth()).unwrap() > 0.01);
}

/// The structured nearest-point search equals a brute-force `adi` over the same points, for
/// random poses near and far from the truth, and between boxes of different sizes.
#[test]
fn add_s_matches_brute_force_adi() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let models = [
        generic(),
        BoxModel::unit(),
        BoxModel::new(Vector3::new(0.2, 0.2, 0.05)).unwrap(),
    ];
    for round in 0..9 {
        let model = models[round % 3];
        let scale = if round < 3 {
            0.02
        } else if round < 6 {
            0.2
        } else {
            1.0
        };
        let estimate = Isometry3::new(
            truth().translation.vector
                + Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)) * scale * 0.3,
            Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)) * scale * 3.0,
        ) * Isometry3::rotation(truth().rotation.scaled_axis());
        let fast = add_s(&model, &estimate, &truth()).unwrap();
        let slow = brute_force_adi(&model, &estimate, &model, &truth());
        assert!((fast - slow).abs() < 1e-12, "{fast} vs {slow}");
    }
    // A fitted box of the wrong size against the true one.
    let fitted = BoxModel::new(Vector3::new(0.28, 0.23, 0.09)).unwrap();
    let estimate = turned(&truth(), Vector3::new(0.2, -1.0, 0.4), 4.0);
    let fast = add_s_between(&fitted, &estimate, &generic(), &truth()).unwrap();
    let slow = brute_force_adi(&fitted, &estimate, &generic(), &truth());
    assert!((fast - slow).abs() < 1e-12, "{fast} vs {slow}");
    assert!(add_s_between(&fitted, &truth(), &generic(), &truth()).unwrap() > 0.001);
}

#[test]
fn add_s_speed() {
    let model = generic();
    let estimate = turned(&truth(), Vector3::new(1.0, 2.0, -1.0), 7.0);
    let calls = 2000;
    let start = std::time::Instant::now();
    let mut total = 0.0;
    for _ in 0..calls {
        total += add_s(&model, &estimate, &truth()).unwrap();
    }
    let per_call_us = start.elapsed().as_secs_f64() * 1e6 / calls as f64;
    eprintln!(
        "add_s: {per_call_us:.1} µs per call (4118 points), mean {}",
        total / calls as f64
    );
}

#[test]
fn rotation_error_respects_only_true_symmetries() {
    let square = BoxModel::new(Vector3::new(0.2, 0.2, 0.1)).unwrap();
    let quarter = turned(&truth(), Vector3::z(), 90.0);
    assert!((rotation_error_deg(&generic(), &quarter, &truth()).unwrap() - 90.0).abs() < 1e-9);
    assert!(rotation_error_deg(&square, &quarter, &truth()).unwrap() < 1e-6);
    let small = turned(&truth(), Vector3::new(1.0, 2.0, -1.0), 7.0);
    assert!((rotation_error_deg(&generic(), &small, &truth()).unwrap() - 7.0).abs() < 1e-9);
    // MSSD of a turn about z by θ: the corner farthest from the axis moves by 2·r·sin(θ/2).
    let radius = (0.15f64.powi(2) + 0.1f64.powi(2)).sqrt();
    let expected = 2.0 * radius * (7.0f64.to_radians() / 2.0).sin();
    let about_z = turned(&truth(), Vector3::z(), 7.0);
    assert!((mssd(&generic(), &about_z, &truth()).unwrap() - expected).abs() < 1e-12);
}

#[test]
fn iou_of_known_configurations() {
    let cube = BoxModel::unit();
    let at = |x: f64| Isometry3::translation(x, 0.0, 0.0);
    assert!((iou_3d(&cube, &truth(), &cube, &truth()).unwrap() - 1.0).abs() < 1e-12);
    // Half overlap: intersection 1/2, union 3/2.
    assert!((iou_3d(&cube, &at(0.0), &cube, &at(0.5)).unwrap() - 1.0 / 3.0).abs() < 1e-12);
    assert_eq!(iou_3d(&cube, &at(0.0), &cube, &at(1.5)).unwrap(), 0.0);
    // Touching faces: no volume in common.
    assert!(iou_3d(&cube, &at(0.0), &cube, &at(1.0)).unwrap().abs() < 1e-12);
    // Nested boxes: the small one's volume over the big one's.
    let small = BoxModel::new(Vector3::new(0.5, 0.4, 0.2)).unwrap();
    assert!(
        (iou_3d(
            &cube,
            &at(0.0),
            &small,
            &turned(&at(0.1), Vector3::x(), 30.0)
        )
        .unwrap()
            - 0.04)
            .abs()
            < 1e-12
    );
    // A unit square and the same square turned 45° overlap in a regular octagon of area
    // 2(√2 − 1); as prisms of height 1, IoU = a / (2 − a).
    let octagon = 2.0 * (2f64.sqrt() - 1.0);
    let iou = iou_3d(
        &cube,
        &at(0.0),
        &cube,
        &turned(&at(0.0), Vector3::z(), 45.0),
    )
    .unwrap();
    assert!((iou - octagon / (2.0 - octagon)).abs() < 1e-12);
}

/// The exact IoU agrees with a fixed-seed Monte Carlo estimate on random pairs of boxes, and is
/// symmetric in its arguments.
#[test]
fn iou_matches_monte_carlo() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..12 {
        let mut random_box =
            || BoxModel::new(Vector3::from_fn(|_, _| rng.random_range(0.2..1.0))).unwrap();
        let (a, b) = (random_box(), random_box());
        let mut random_pose = || {
            let axis = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            Isometry3::new(
                Vector3::from_fn(|_, _| rng.random_range(-0.3..0.3)),
                axis * 2.0,
            )
        };
        let (pose_a, pose_b) = (random_pose(), random_pose());
        let exact = iou_3d(&a, &pose_a, &b, &pose_b).unwrap();
        assert!((exact - iou_3d(&b, &pose_b, &a, &pose_a).unwrap()).abs() < 1e-12);

        // Sample A uniformly; the fraction inside B estimates vol(A ∩ B) / vol(A).
        let samples = 40_000;
        let inside_b = |p: &Point3<f64>| {
            let local = pose_b.inverse() * p;
            (0..3).all(|i| local[i].abs() <= 0.5 * b.size()[i])
        };
        let hits = (0..samples)
            .filter(|_| {
                let local = Point3::from(Vector3::from_fn(|i, _| {
                    rng.random_range(-0.5..0.5) * a.size()[i]
                }));
                inside_b(&(pose_a * local))
            })
            .count();
        // Compare the fraction of A inside B, recovered from the exact IoU, with the hit rate,
        // whose binomial standard error is at most 0.0025: allow four of them.
        let exact_fraction = exact * (a.volume() + b.volume()) / (1.0 + exact) / a.volume();
        let hit_rate = hits as f64 / samples as f64;
        assert!(
            (exact_fraction - hit_rate).abs() < 0.01,
            "{exact_fraction} vs {hit_rate}"
        );
    }
}

#[test]
fn bad_inputs_are_errors() {
    let model = generic();
    let mut broken = truth();
    broken.translation.vector.x = f64::NAN;
    assert!(matches!(
        add_s(&model, &broken, &truth()),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        mssd(&model, &truth(), &broken),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        rotation_error_deg(&model, &broken, &truth()),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        translation_error(&broken, &truth()),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        iou_3d(&model, &broken, &model, &truth()),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        paper_error(&model, &truth(), &[]),
        Err(GeometryError::TooFewPoints { .. })
    ));
    assert!(matches!(
        paper_error(&model, &truth(), &[Point3::new(f64::INFINITY, 0.0, 0.0)]),
        Err(GeometryError::NonFinite { .. })
    ));
}

/// A random box (sides 4–60 cm) and a random pose, from proptest's inputs.
fn box_and_pose(
    sides: [f64; 3],
    axis: [f64; 3],
    angle: f64,
    at: [f64; 3],
) -> (BoxModel, Isometry3<f64>) {
    let model = BoxModel::new(Vector3::from(sides)).unwrap();
    let axis = Vector3::from(axis);
    let rotation = if axis.norm() < 1e-6 {
        UnitQuaternion::identity()
    } else {
        UnitQuaternion::from_scaled_axis(axis.normalize() * angle)
    };
    (
        model,
        Isometry3::from_parts(Translation3::from(Vector3::from(at)), rotation),
    )
}

mod cube_mssd_properties {
    use super::*;
    use proptest::prelude::*;

    fn side() -> impl Strategy<Value = f64> {
        0.04..0.6f64
    }

    fn unit() -> impl Strategy<Value = f64> {
        -1.0..1.0f64
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Symmetric in its two poses, non-negative, never above the exact-symmetry MSSD, and
        /// equal to it for a cube (whose own group is the cube's).
        #[test]
        fn symmetric_non_negative_and_at_most_mssd(
            sides in [side(), side(), side()],
            a in [unit(), unit(), unit()], angle_a in 0.0..std::f64::consts::PI,
            b in [unit(), unit(), unit()], angle_b in 0.0..std::f64::consts::PI,
            shift in [unit(), unit(), unit()],
        ) {
            let (model, truth) = box_and_pose(sides, a, angle_a, [0.0, 0.0, 1.0]);
            let (_, estimate) = box_and_pose(sides, b, angle_b, [0.1 * shift[0], 0.1 * shift[1], 1.0 + 0.1 * shift[2]]);
            let e = cube_mssd(&model, &estimate, &model, &truth).unwrap();
            let reverse = cube_mssd(&model, &truth, &model, &estimate).unwrap();
            prop_assert!(e >= 0.0);
            prop_assert!((e - reverse).abs() < 1e-12, "{e} vs {reverse}");
            prop_assert!(e <= mssd(&model, &estimate, &truth).unwrap() + 1e-12);
            let cube = BoxModel::new(Vector3::repeat(sides[0])).unwrap();
            let exact = mssd(&cube, &estimate, &truth).unwrap();
            let modulo = cube_mssd(&cube, &estimate, &cube, &truth).unwrap();
            prop_assert!((exact - modulo).abs() < 1e-12, "{exact} vs {modulo}");
        }

        /// Zero for every relabelling of the same corners (each of the cube's rotations applied
        /// to a cube, the box's own symmetries to any box), and positive for another corner set.
        #[test]
        fn zero_exactly_for_the_same_corner_set(
            sides in [side(), side(), side()],
            a in [unit(), unit(), unit()], angle in 0.0..std::f64::consts::PI,
            shift in [unit(), unit(), unit()],
        ) {
            let (model, truth) = box_and_pose(sides, a, angle, [0.0, 0.0, 1.0]);
            for symmetry in model.symmetries() {
                let same = Isometry3::from_parts(
                    truth.translation,
                    truth.rotation * UnitQuaternion::from_rotation_matrix(&symmetry.rotation),
                );
                prop_assert!(cube_mssd(&model, &same, &model, &truth).unwrap() < 1e-12);
            }
            let moved = Isometry3::from_parts(
                Translation3::from(truth.translation.vector + Vector3::from(shift) * 0.01),
                truth.rotation,
            );
            let displacement = (Vector3::from(shift) * 0.01).norm();
            let e = cube_mssd(&model, &moved, &model, &truth).unwrap();
            // A shift smaller than half the shortest side keeps each corner nearest its own.
            prop_assert!((e - displacement).abs() < 1e-12, "{e} vs {displacement}");
        }

        /// A quarter turn about the normal of an a × b face moves every corner by |a − b|/√2 (the
        /// face's corners rotate onto the other side's corners), where the exact MSSD counts the
        /// turn as a wrong orientation.
        #[test]
        fn a_quarter_turn_costs_the_corners_real_displacement(
            sides in [side(), side(), side()],
            a in [unit(), unit(), unit()], angle in 0.0..std::f64::consts::PI,
            axis in 0usize..3,
        ) {
            let (model, truth) = box_and_pose(sides, a, angle, [0.0, 0.0, 1.0]);
            let estimate = turned(&truth, Vector3::ith(axis, 1.0), 90.0);
            let (a_side, b_side) = (sides[(axis + 1) % 3], sides[(axis + 2) % 3]);
            let expected = (a_side - b_side).abs() / std::f64::consts::SQRT_2;
            let e = cube_mssd(&model, &estimate, &model, &truth).unwrap();
            prop_assert!((e - expected).abs() < 1e-9, "{e} vs {expected}");
        }
    }
}

#[test]
fn a_quarter_turn_of_a_nearly_square_box_is_graded_not_a_cliff() {
    // 30 × 29 × 10 cm: MSSD calls a quarter turn about z as wrong as a pose half a diagonal away;
    // the cube-group error sees the centimetre the corners actually moved.
    let model = BoxModel::new(Vector3::new(0.30, 0.29, 0.10)).unwrap();
    let estimate = turned(&truth(), Vector3::z(), 90.0);
    let exact = mssd(&model, &estimate, &truth()).unwrap();
    let modulo = cube_mssd(&model, &estimate, &model, &truth()).unwrap();
    assert!(exact > 0.1 * model.diameter(), "{exact}");
    assert!((modulo - 0.01 / 2f64.sqrt()).abs() < 1e-12, "{modulo}");
}

#[test]
fn a_wrong_size_counts_in_the_cube_group_error() {
    // The fitted box 2 cm longer along x, centred on the truth: its +x corners are 1 cm out.
    let fitted = BoxModel::new(Vector3::new(0.32, 0.2, 0.1)).unwrap();
    let e = cube_mssd(&fitted, &truth(), &generic(), &truth()).unwrap();
    assert!((e - 0.01).abs() < 1e-12, "{e}");
}

#[test]
fn average_recall_is_the_mean_recall_over_bop_thresholds() {
    assert_eq!(average_recall(&[]), 0.0);
    assert_eq!(average_recall(&[0.0, 0.01]), 1.0);
    assert_eq!(average_recall(&[f64::INFINITY]), 0.0);
    // 0.12 < θ for θ ≥ 0.15 (8 of 10 thresholds); 0.3 for θ ≥ 0.35 (4 of 10): (0.8 + 0.4) / 2
    assert!((average_recall(&[0.12, 0.3]) - 0.6).abs() < 1e-12);
}
