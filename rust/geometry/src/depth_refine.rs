//! Refining a fitted box's pose against the depth image.
//!
//! The corner peaks place a box to within a voxel (a few millimetres), which leaves a few degrees
//! of rotation on a small box: the paper's predicate flags such near misses. The depth image
//! holds hundreds of measured points on the box's visible faces. [`refine_with_depth`] moves the
//! pose to lay the box's camera-facing faces on them: Gauss–Newton on the pose (a twist in the
//! camera frame, point-to-plane residuals to the nearest face, Cauchy weights), from the fit's
//! pose, using only the pixels of the box's own mask (ground truth or the segmenter's) inside its
//! projection whose points lie within a gate of its surface, so the support and neighbouring
//! boxes do not pull it. It refines, it does not
//! search: a result that moves the box by more than [`MAX_ROTATION_DEG`] or a fraction of its
//! shortest side is discarded, and too few points leave the pose as it was.
//!
//! The search belongs to the fit: when its peaks allow several poses, [`choose_with_depth`] keeps
//! the one the depth image supports ([`DepthSupport`]).

use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};

use crate::BoxModel;
use crate::depth::{self, DepthView};

/// Gauss–Newton steps at most.
const ITERATIONS: usize = 15;
/// Depth pixels sampled at most (on a regular grid over the box's projection).
const MAX_SAMPLES: usize = 2000;
/// Points within this many metres of the box's surface (at the current pose) take part.
const GATE_M: f64 = 0.01;
/// The Cauchy weight's scale, metres: residuals well above it count little.
const CAUCHY_SCALE_M: f64 = 0.003;
/// Points whose nearest surface point lies within this of a face's border take no part: the
/// support's surface continues a face's bottom edge in the same plane (its points would pull the
/// face outwards), and the pixels at an edge mix two surfaces.
const EDGE_MARGIN_M: f64 = 0.005;
/// Fewer points than this on the box's visible faces leave the pose unrefined.
const MIN_POINTS: usize = 50;
/// A refinement that turns the box by more than this is discarded.
pub const MAX_ROTATION_DEG: f64 = 10.0;
/// A refinement that moves the box's centre by more than this fraction of its shortest side is
/// discarded.
const MAX_SHIFT_OF_SHORTEST_SIDE: f64 = 0.5;

/// A pose refined against the depth image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthRefinement {
    pub pose: Isometry3<f64>,
    /// Depth points on the box's visible faces at the last step.
    pub points: usize,
    /// Their root-mean-square distance to the faces, metres.
    pub rms_m: f64,
}

/// `pose` of the box `model` refined against `view` (see the module) on the pixels `belongs`
/// marks as the box's (row-major pixel index: its mask), or None when the depth image does not
/// hold enough of the box or the refinement would move it too far.
pub fn refine_with_depth(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    view: &DepthView,
    belongs: impl Fn(usize) -> bool,
) -> Option<DepthRefinement> {
    let observed = observed_points(model, pose, view, belongs)?;
    let half = model.size() * 0.5;
    let mut refined = *pose;
    let mut last = (0, f64::INFINITY);
    for _ in 0..ITERATIONS {
        let (step, used, rms) = gauss_newton_step(&half, &refined, &observed)?;
        last = (used, rms);
        // the rotation turns the box about its own centre: damping then holds the centre along
        // any direction the faces do not constrain where the corner fit put it
        let centre = refined.translation.vector;
        let rotation = Vector3::from(step.fixed_rows::<3>(0));
        let shift = Vector3::from(step.fixed_rows::<3>(3));
        refined =
            Isometry3::translation(centre.x + shift.x, centre.y + shift.y, centre.z + shift.z)
                * Isometry3::rotation(rotation)
                * Isometry3::translation(-centre.x, -centre.y, -centre.z)
                * refined;
        if step.norm() < 1e-7 {
            break;
        }
    }
    let (points, rms_m) = last;
    let turned = (refined.rotation * pose.rotation.inverse())
        .angle()
        .to_degrees();
    let shifted = (refined.translation.vector - pose.translation.vector).norm();
    let shortest = model.size().min();
    (points >= MIN_POINTS
        && turned <= MAX_ROTATION_DEG
        && shifted <= MAX_SHIFT_OF_SHORTEST_SIDE * shortest)
        .then_some(DepthRefinement {
            pose: refined,
            points,
            rms_m,
        })
}

/// The pixel rectangle (u0, v0, u1, v1, inclusive) of the box's projection at `pose` (its
/// corners' bounding rectangle, clipped to the image); None when a corner is behind the camera.
fn projection_rect(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    view: &DepthView,
) -> Option<[usize; 4]> {
    let [fx, fy, cx, cy] = view.intrinsics;
    let (mut u0, mut v0, mut u1, mut v1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for corner in model.corners() {
        let p = pose * corner;
        if p.z <= 0.0 {
            return None;
        }
        let (u, v) = (fx * p.x / p.z + cx, fy * p.y / p.z + cy);
        (u0, v0, u1, v1) = (u0.min(u), v0.min(v), u1.max(u), v1.max(v));
    }
    let clip = |x: f64, len: usize| x.clamp(0.0, len as f64 - 1.0).round() as usize;
    Some([
        clip(u0, view.width),
        clip(v0, view.height),
        clip(u1, view.width),
        clip(v1, view.height),
    ])
}

/// The camera-frame points of the depth pixels inside the box's projection at `pose` that
/// `belongs` marks as the box's, sampled on a grid of at most [`MAX_SAMPLES`] pixels.
fn observed_points(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    view: &DepthView,
    belongs: impl Fn(usize) -> bool,
) -> Option<Vec<Point3<f64>>> {
    Some(points_in_rect(
        projection_rect(model, pose, view)?,
        view,
        belongs,
    ))
}

/// The camera-frame points of the depth pixels of `rect` that `belongs` marks, on a grid of at
/// most [`MAX_SAMPLES`] pixels of the rectangle.
fn points_in_rect(
    [u0, v0, u1, v1]: [usize; 4],
    view: &DepthView,
    belongs: impl Fn(usize) -> bool,
) -> Vec<Point3<f64>> {
    let [fx, fy, cx, cy] = view.intrinsics;
    let area = ((u1 - u0 + 1) * (v1 - v0 + 1)) as f64;
    let stride = ((area / MAX_SAMPLES as f64).sqrt().ceil() as usize).max(1);
    let mut points = Vec::new();
    for v in (v0..=v1).step_by(stride) {
        for u in (u0..=u1).step_by(stride) {
            let pixel = v * view.width + u;
            let Some(&z) = view.depth_m.get(pixel).filter(|_| belongs(pixel)) else {
                continue;
            };
            let z = z as f64;
            if z.is_finite() && z > 0.0 {
                points.push(Point3::new(
                    (u as f64 - cx) * z / fx,
                    (v as f64 - cy) * z / fy,
                    z,
                ));
            }
        }
    }
    points
}

/// A mask point within this many metres of a candidate's surface is explained by it.
const EXPLAINED_WITHIN_M: f64 = 0.01;
/// A candidate's visible face sample this far in front of the observed surface is impossible.
const IN_FRONT_TOLERANCE_M: f64 = 0.01;
/// The lead in [`DepthSupport::score`] a candidate needs over the fit's own pose to replace it.
const DECISIVE_LEAD: f64 = 0.1;

/// How well a candidate pose accounts for the depth image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthSupport {
    /// Share of the box's mask points within [`EXPLAINED_WITHIN_M`] of the candidate's surface.
    pub explained: f64,
    /// Share of the candidate's camera-facing face samples that lie in front of everything the
    /// camera saw there ([`depth::check_against_depth`]): where the candidate would be, the
    /// camera saw through.
    pub impossible: f64,
}

impl DepthSupport {
    /// explained − 3 · impossible: a sample the camera saw through cannot be explained away by
    /// an occluder, while a mask point can be missed by a pose that is nearly right.
    pub fn score(&self) -> f64 {
        self.explained - 3.0 * self.impossible
    }
}

/// The distance from `q` (box frame) to the surface of the box of half-extents `half`.
fn surface_distance(half: &Vector3<f64>, q: &Point3<f64>) -> f64 {
    let beyond = q.coords.abs() - half;
    if beyond.max() < 0.0 {
        -beyond.max()
    } else {
        beyond.map(|x| x.max(0.0)).norm()
    }
}

/// How well each of `candidates` (poses of `model`) accounts for the depth image `view` on the
/// pixels `belongs` marks as the box's (its mask) — [`DepthSupport`] — or None when the mask
/// holds fewer than [`MIN_POINTS`] depth points inside the candidates' projections.
pub fn depth_support(
    model: &BoxModel,
    candidates: &[Isometry3<f64>],
    view: &DepthView,
    belongs: impl Fn(usize) -> bool,
) -> Option<Vec<DepthSupport>> {
    let rect = candidates
        .iter()
        .filter_map(|pose| projection_rect(model, pose, view))
        .reduce(|a, b| {
            [
                a[0].min(b[0]),
                a[1].min(b[1]),
                a[2].max(b[2]),
                a[3].max(b[3]),
            ]
        })?;
    let observed = points_in_rect(rect, view, belongs);
    if observed.len() < MIN_POINTS {
        return None;
    }
    let half = model.size() * 0.5;
    Some(
        candidates
            .iter()
            .map(|pose| {
                let inverse = pose.inverse();
                let explained = observed
                    .iter()
                    .filter(|p| surface_distance(&half, &(inverse * *p)) <= EXPLAINED_WITHIN_M)
                    .count();
                let check = depth::check_against_depth(model, pose, view, IN_FRONT_TOLERANCE_M);
                DepthSupport {
                    explained: explained as f64 / observed.len() as f64,
                    impossible: check.in_front as f64 / check.samples.max(1) as f64,
                }
            })
            .collect(),
    )
}

/// Of `candidates` (the fit's own pose first, then the other poses its peaks allow), the one the
/// depth image supports ([`depth_support`]): another candidate replaces the fit's pose only when
/// its score leads by [`DECISIVE_LEAD`]. The index of the chosen candidate; 0 when the mask
/// holds too few depth points to judge.
pub fn choose_with_depth(
    model: &BoxModel,
    candidates: &[Isometry3<f64>],
    view: &DepthView,
    belongs: impl Fn(usize) -> bool,
) -> usize {
    let Some(support) = depth_support(model, candidates, view, belongs) else {
        return 0;
    };
    let scores: Vec<f64> = support.iter().map(DepthSupport::score).collect();
    let best = (0..scores.len())
        .max_by(|&a, &b| scores[a].total_cmp(&scores[b]).then(b.cmp(&a)))
        .unwrap_or(0);
    if best != 0 && scores[best] - scores[0] >= DECISIVE_LEAD {
        best
    } else {
        0
    }
}

/// The face of the box of half-extents `half` nearest to `q` (box frame), as the point of that
/// face's plane below `q` and the face's outward normal; None when that point is not inside the
/// face by [`EDGE_MARGIN_M`] (a point beyond an edge or a corner, or near one).
fn nearest_face(half: &Vector3<f64>, q: &Point3<f64>) -> Option<(Point3<f64>, Vector3<f64>)> {
    // outside the box the face is the one whose plane the point is beyond; inside, the nearest
    let axis = (0..3)
        .min_by(|&a, &b| (half[a] - q[a].abs()).total_cmp(&(half[b] - q[b].abs())))
        .unwrap_or(2);
    let inside_face = (0..3).filter(|&k| k != axis).all(|k| {
        let margin = EDGE_MARGIN_M.min(0.25 * half[k]);
        q[k].abs() <= half[k] - margin
    });
    if !inside_face {
        return None;
    }
    let sign = if q[axis] >= 0.0 { 1.0 } else { -1.0 };
    let mut on_face = *q;
    on_face[axis] = sign * half[axis];
    let mut normal = Vector3::zeros();
    normal[axis] = sign;
    Some((on_face, normal))
}

/// One damped Gauss–Newton step (rotation ω about the box's centre, then translation v of the
/// centre, camera axes) of the weighted
/// point-to-plane residuals of the points within [`GATE_M`] of a camera-facing part of the
/// surface; with how many points took part and their RMS residual. None with too few points.
fn gauss_newton_step(
    half: &Vector3<f64>,
    pose: &Isometry3<f64>,
    observed: &[Point3<f64>],
) -> Option<(Vector6<f64>, usize, f64)> {
    let inverse = pose.inverse();
    let centre = Point3::from(pose.translation.vector);
    let (mut normal_matrix, mut gradient) = (Matrix6::zeros(), Vector6::zeros());
    let (mut used, mut squares) = (0usize, 0.0);
    for p in observed {
        let Some((on_surface, normal)) = nearest_face(half, &(inverse * p)) else {
            continue;
        };
        let (s, n) = (pose * on_surface, pose.rotation * normal);
        // a face turned away from the camera is not what the depth image sees
        if n.dot(&s.coords) >= 0.0 {
            continue;
        }
        let residual = n.dot(&(p - s));
        if residual.abs() > GATE_M {
            continue;
        }
        let weight = 1.0 / (1.0 + (residual / CAUCHY_SCALE_M).powi(2));
        // d residual / d (ω, v) for s moved to s + ω × (s − centre) + v
        let arm = (s - centre).cross(&n);
        let jacobian = Vector6::from_iterator(arm.iter().chain(n.iter()).copied());
        normal_matrix += weight * jacobian * jacobian.transpose();
        gradient += weight * residual * jacobian;
        used += 1;
        squares += residual * residual;
    }
    if used < MIN_POINTS {
        return None;
    }
    // Damping keeps directions the visible faces do not constrain (a single face's in-plane
    // shift and spin) where the corner fit put them.
    let damping = 1e-3 * normal_matrix.trace() / 6.0 + 1e-12;
    let step = (normal_matrix + Matrix6::identity() * damping)
        .cholesky()?
        .solve(&gradient);
    Some((step, used, (squares / used as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    const SIZE: [f64; 3] = [0.3, 0.2, 0.1];
    const INTRINSICS: [f64; 4] = [500.0, 500.0, 160.0, 120.0];
    const WIDTH: usize = 320;
    const HEIGHT: usize = 240;

    /// What a ray that misses the box meets.
    #[derive(Clone, Copy)]
    enum Background {
        /// A wall facing the camera at this depth.
        Wall(f32),
        /// A floor in the plane of the box's bottom face (the box rests on it).
        Floor,
    }

    /// Planar depth of the box at `pose` as a pinhole camera sees it: each pixel's ray against the
    /// box (slab test), else against the background.
    fn render(model: &BoxModel, pose: &Isometry3<f64>, background: Background) -> Vec<f32> {
        render_boxes(&[(model, *pose)], background).0
    }

    /// Planar depth of several boxes, and per pixel the index + 1 of the box seen there (0: the
    /// background); a floor lies in the plane of the first box's bottom face.
    fn render_boxes(
        boxes: &[(&BoxModel, Isometry3<f64>)],
        background: Background,
    ) -> (Vec<f32>, Vec<u8>) {
        let [fx, fy, cx, cy] = INTRINSICS;
        let (mut depth, mut labels) = (vec![0.0f32; WIDTH * HEIGHT], vec![0u8; WIDTH * HEIGHT]);
        for v in 0..HEIGHT {
            for u in 0..WIDTH {
                // the ray's z-component is 1, so a distance along it is a planar depth
                let ray = Vector3::new((u as f64 - cx) / fx, (v as f64 - cy) / fy, 1.0);
                let behind = match background {
                    Background::Wall(wall_m) => wall_m as f64,
                    Background::Floor => {
                        let (model, pose) = boxes[0];
                        let inverse = pose.inverse();
                        let (origin, direction) =
                            (inverse * Point3::origin(), inverse.rotation * ray);
                        let floor = (-model.size()[2] * 0.5 - origin[2]) / direction[2];
                        if floor > 0.0 { floor } else { f64::INFINITY }
                    }
                };
                let mut nearest = (behind, 0u8);
                for (k, (model, pose)) in boxes.iter().enumerate() {
                    if let Some(hit) = ray_hit(model, pose, &ray)
                        && hit < nearest.0
                    {
                        nearest = (hit, k as u8 + 1);
                    }
                }
                let pixel = v * WIDTH + u;
                depth[pixel] = if nearest.0.is_finite() {
                    nearest.0 as f32
                } else {
                    0.0
                };
                labels[pixel] = nearest.1;
            }
        }
        (depth, labels)
    }

    /// Where the camera ray `ray` (from the origin) enters the box at `pose`, if it does.
    fn ray_hit(model: &BoxModel, pose: &Isometry3<f64>, ray: &Vector3<f64>) -> Option<f64> {
        let half = model.size() * 0.5;
        let inverse = pose.inverse();
        let (origin, direction) = (inverse * Point3::origin(), inverse.rotation * ray);
        let (mut near, mut far) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            let (a, b) = (
                (-half[k] - origin[k]) / direction[k],
                (half[k] - origin[k]) / direction[k],
            );
            near = near.max(a.min(b));
            far = far.min(a.max(b));
        }
        (near <= far).then_some(near)
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.02, -0.01, 0.9),
            UnitQuaternion::from_euler_angles(0.7, -0.4, 0.3),
        )
    }

    fn view(depth: &[f32]) -> DepthView<'_> {
        DepthView {
            width: WIDTH,
            height: HEIGHT,
            intrinsics: INTRINSICS,
            depth_m: depth,
        }
    }

    fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        (a.rotation * b.rotation.inverse()).angle().to_degrees()
    }

    #[test]
    fn a_few_degrees_and_millimetres_off_are_brought_back_to_the_depth() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let depth = render(&model, &truth(), Background::Wall(2.0));
        // turned about its own centre, and shifted
        let off = Isometry3::from_parts(
            Translation3::from(truth().translation.vector + Vector3::new(0.004, -0.003, 0.005)),
            UnitQuaternion::new(Vector3::new(0.05, -0.04, 0.06)) * truth().rotation,
        );
        assert!(rotation_error_deg(&off, &truth()) > 4.0);
        let refined = refine_with_depth(&model, &off, &view(&depth), |_| true).expect("refined");
        assert!(
            rotation_error_deg(&refined.pose, &truth()) < 0.3,
            "{refined:?}"
        );
        let shift = (refined.pose.translation.vector - truth().translation.vector).norm();
        assert!(shift < 0.002, "{shift}");
        assert!(
            refined.points >= MIN_POINTS && refined.rms_m < 0.002,
            "{refined:?}"
        );
    }

    #[test]
    fn the_true_pose_stays_where_it_is() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let depth = render(&model, &truth(), Background::Wall(2.0));
        let refined =
            refine_with_depth(&model, &truth(), &view(&depth), |_| true).expect("refined");
        assert!(rotation_error_deg(&refined.pose, &truth()) < 0.1);
        assert!((refined.pose.translation.vector - truth().translation.vector).norm() < 5e-4);
    }

    #[test]
    fn no_box_in_the_depth_image_leaves_the_pose_unrefined() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let empty = vec![0.0f32; WIDTH * HEIGHT];
        assert!(refine_with_depth(&model, &truth(), &view(&empty), |_| true).is_none());
        // a box far from where the depth image has one: no point within the gate
        let elsewhere = Isometry3::translation(0.0, 0.0, 0.5) * truth();
        let depth = render(&model, &truth(), Background::Wall(2.0));
        assert!(refine_with_depth(&model, &elsewhere, &view(&depth), |_| true).is_none());
    }

    /// The box resting on a floor (the plane of its bottom face), the camera `elevation_deg`
    /// above the horizon at `distance_m`, looking at the box's centre.
    fn on_floor_view(elevation_deg: f64, azimuth_deg: f64, distance_m: f64) -> Isometry3<f64> {
        let (e, a) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
        let eye = Point3::new(
            distance_m * e.cos() * a.cos(),
            distance_m * e.cos() * a.sin(),
            distance_m * e.sin(),
        );
        // world z up; camera z forward, y down
        let forward = (Point3::origin() - eye).normalize();
        let right = forward.cross(&Vector3::z()).normalize();
        let down = forward.cross(&right);
        let rotation = nalgebra::Rotation3::from_basis_unchecked(&[right, down, forward]);
        // T_camera_world
        let world_camera = Isometry3::from_parts(
            Translation3::from(eye.coords),
            UnitQuaternion::from_rotation_matrix(&rotation),
        );
        world_camera.inverse()
    }

    #[test]
    fn on_a_floor_the_faces_fix_what_they_can_and_hold_the_rest() {
        // a flat box seen from 57° above: from azimuth 30° three faces show, from 80° the top and
        // one long side only, which leave the centre free along their common edge
        let model = BoxModel::new(Vector3::new(0.195, 0.089, 0.049)).unwrap();
        for (azimuth_deg, worst_shift_m) in [(30.0, 1e-5), (80.0, 0.0016)] {
            let truth = on_floor_view(57.0, azimuth_deg, 0.75);
            let depth = render(&model, &truth, Background::Floor);
            for shift in [Vector3::x(), Vector3::y(), Vector3::z()] {
                let off = Isometry3::from_parts(
                    Translation3::from(truth.translation.vector + 0.0015 * shift),
                    UnitQuaternion::new(Vector3::new(0.01, -0.01, 0.015)) * truth.rotation,
                );
                let refined =
                    refine_with_depth(&model, &off, &view(&depth), |_| true).expect("refined");
                let moved = (refined.pose.translation.vector - truth.translation.vector).norm();
                assert!(
                    rotation_error_deg(&refined.pose, &truth) < 0.01,
                    "{refined:?}"
                );
                assert!(moved <= worst_shift_m, "azimuth {azimuth_deg}: {moved}");
            }
        }
    }

    #[test]
    fn the_box_s_own_mask_keeps_a_leaning_neighbour_from_pulling_it() {
        // a box on a floor, a second one leaning against its side (turned 12°, its bottom edge
        // 6 mm up): with every pixel of the projection the neighbour's faces within the gate
        // pull the box 7–8 mm away; with the box's own mask they take no part
        let model = BoxModel::new(Vector3::new(0.16, 0.12, 0.08)).unwrap();
        let truth = on_floor_view(55.0, 35.0, 0.7);
        let leaning = truth
            * Isometry3::from_parts(
                Translation3::new(0.16, 0.0, 0.006),
                UnitQuaternion::from_euler_angles(0.0, -0.21, 0.0),
            );
        let (depth, labels) =
            render_boxes(&[(&model, truth), (&model, leaning)], Background::Floor);
        assert!(labels.contains(&2), "the neighbour is in view");
        for shift in [Vector3::x(), Vector3::y(), Vector3::z()] {
            let off = Isometry3::from_parts(
                Translation3::from(truth.translation.vector + truth.rotation * (0.004 * shift)),
                UnitQuaternion::new(Vector3::new(0.02, -0.03, 0.02)) * truth.rotation,
            );
            let moved = |belongs: &dyn Fn(usize) -> bool| {
                let refined =
                    refine_with_depth(&model, &off, &view(&depth), belongs).expect("refined");
                (refined.pose.translation.vector - truth.translation.vector).norm()
            };
            let own = moved(&|pixel| labels[pixel] == 1);
            assert!(own < 1e-4, "own mask, shifted along {shift:?}: {own}");
            let every = moved(&|_| true);
            assert!(
                every > 0.005,
                "every pixel, shifted along {shift:?}: {every}"
            );
        }
    }

    /// The truth turned a quarter about its shortest axis (the 0.3 × 0.2 face turned in its
    /// plane): its faces leave part of the mask unexplained and stand where the camera saw past
    /// the box.
    fn quarter_turned(pose: &Isometry3<f64>) -> Isometry3<f64> {
        pose * Isometry3::rotation(Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2))
    }

    #[test]
    fn the_pose_the_depth_image_supports_replaces_one_it_does_not() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let (depth, labels) = render_boxes(&[(&model, truth())], Background::Wall(2.0));
        let mask = |pixel: usize| labels[pixel] == 1;
        let wrong = quarter_turned(&truth());
        let support = depth_support(&model, &[wrong, truth()], &view(&depth), mask).unwrap();
        assert!(
            support[1].explained > 0.95 && support[1].impossible < 0.02,
            "{support:?}"
        );
        assert!(support[1].score() - support[0].score() > 0.3, "{support:?}");
        assert_eq!(
            choose_with_depth(&model, &[wrong, truth()], &view(&depth), mask),
            1
        );
        assert_eq!(
            choose_with_depth(&model, &[truth(), wrong], &view(&depth), mask),
            0
        );
    }

    #[test]
    fn a_candidate_no_better_supported_keeps_the_fit_s_own_pose() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let (depth, labels) = render_boxes(&[(&model, truth())], Background::Wall(2.0));
        // a millimetre along the optical axis changes nothing the score can see
        let beside = Isometry3::translation(0.0, 0.0, 0.001) * truth();
        assert_eq!(
            choose_with_depth(&model, &[truth(), beside], &view(&depth), |pixel| {
                labels[pixel] == 1
            }),
            0
        );
    }

    #[test]
    fn a_mask_with_too_few_depth_points_keeps_the_fit_s_own_pose() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let depth = render(&model, &truth(), Background::Wall(2.0));
        let wrong = quarter_turned(&truth());
        let candidates = [wrong, truth()];
        assert!(depth_support(&model, &candidates, &view(&depth), |_| false).is_none());
        assert_eq!(
            choose_with_depth(&model, &candidates, &view(&depth), |_| false),
            0
        );
    }

    #[test]
    fn a_pose_standing_where_the_camera_saw_through_is_impossible() {
        let model = BoxModel::new(Vector3::from(SIZE)).unwrap();
        let depth = render(&model, &truth(), Background::Wall(2.0));
        // 5 cm nearer the camera: every visible face sample is in front of the observed box
        let nearer = Isometry3::translation(0.0, 0.0, -0.05) * truth();
        let support = depth_support(&model, &[nearer], &view(&depth), |_| true).unwrap();
        assert!(support[0].impossible > 0.9, "{support:?}");
        assert!(support[0].score() < -2.0, "{support:?}");
    }

    #[test]
    fn the_distance_to_the_surface_is_zero_on_it_and_grows_off_it() {
        let half = Vector3::new(0.15, 0.1, 0.05);
        assert!((surface_distance(&half, &Point3::origin()) - 0.05).abs() < 1e-12);
        assert!(surface_distance(&half, &Point3::new(0.0, 0.0, 0.05)).abs() < 1e-12);
        assert!((surface_distance(&half, &Point3::new(0.0, 0.0, 0.08)) - 0.03).abs() < 1e-12);
        let corner = surface_distance(&half, &Point3::new(0.18, 0.14, 0.05));
        assert!((corner - 0.05).abs() < 1e-12, "{corner}");
    }
}
