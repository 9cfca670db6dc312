//! What the depth image says about a fitted box: the mirror disambiguation of fits whose inliers
//! lie in one plane.
//!
//! Four inlier peaks in one plane (a face of the box) fit the box and its mirror image through
//! that plane alike, so the peaks cannot choose. The depth image can: a camera sees the surface
//! nearest to it, so a pose whose visible faces lie *in front of* the observed surface is
//! impossible (there would be box where the camera saw through to something farther), and the
//! right pose's visible faces lie *on* the observed surface where nothing occludes them. Each
//! pose's visible faces are sampled on a grid, projected into the image and compared with the
//! observed depth there ([`check_against_depth`]); [`resolve_mirror`] keeps the pose that agrees.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::{BoxModel, adaptive};

/// A depth image and the pinhole camera that took it (OpenCV axes: x right, y down, z forward,
/// the frame of the fitted poses).
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    pub width: usize,
    pub height: usize,
    /// fx, fy, cx, cy in pixels (top-left pixel centre at (0, 0)).
    pub intrinsics: [f64; 4],
    /// height × width, row-major, metres along the optical axis; 0 or non-finite where there is
    /// no measurement (pixels beyond its length count as such).
    pub depth_m: &'a [f32],
}

impl DepthView<'_> {
    /// The observed depths in the 3 × 3 pixels around where a camera-frame point projects (the
    /// rounding to a pixel and the mixed pixels at a face's edge make one pixel too strict), as
    /// (the nearest surface, the observed depth closest to `p.z`); None where none has a depth.
    fn observed_around(&self, p: &Point3<f64>) -> Option<(f64, f64)> {
        if p.z <= 0.0 {
            return None;
        }
        let [fx, fy, cx, cy] = self.intrinsics;
        let (u, v) = ((fx * p.x / p.z + cx).round(), (fy * p.y / p.z + cy).round());
        if !(u.is_finite() && v.is_finite()) {
            return None;
        }
        let mut found: Option<(f64, f64)> = None;
        for dv in -1..=1 {
            for du in -1..=1 {
                let (uu, vv) = (u as i64 + du, v as i64 + dv);
                if uu < 0 || vv < 0 || uu as usize >= self.width || vv as usize >= self.height {
                    continue;
                }
                let Some(&z) = self.depth_m.get(vv as usize * self.width + uu as usize) else {
                    continue;
                };
                let z = z as f64;
                if !(z.is_finite() && z > 0.0) {
                    continue;
                }
                found = Some(match found {
                    None => (z, z),
                    Some((nearest, closest)) => (
                        nearest.min(z),
                        if (z - p.z).abs() < (closest - p.z).abs() {
                            z
                        } else {
                            closest
                        },
                    ),
                });
            }
        }
        found
    }
}

/// How one pose's visible faces compare with the depth image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DepthCheck {
    /// Surface samples that project onto a pixel with a depth.
    pub samples: usize,
    /// Samples within the tolerance of the observed depth.
    pub agree: usize,
    /// Samples in front of every observed surface around them by more than the tolerance:
    /// impossible.
    pub in_front: usize,
}

impl DepthCheck {
    /// (agree − 3 · in front) / samples, in [−3, 1]: an impossible sample outweighs an agreeing
    /// one, because agreement can also be lost to an occluder while a sample in front cannot be
    /// explained away. −∞ without samples.
    pub fn score(&self) -> f64 {
        if self.samples == 0 {
            return f64::NEG_INFINITY;
        }
        (self.agree as f64 - 3.0 * self.in_front as f64) / self.samples as f64
    }
}

/// Samples per face edge: a 6 × 6 grid of face-interior points per visible face.
const FACE_GRID: usize = 6;

/// Compares the faces of `model` at `pose` that face the camera with the observed depth:
/// `tolerance_m` is how far a sample may lie from the observed surface and still agree.
pub fn check_against_depth(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    view: &DepthView,
    tolerance_m: f64,
) -> DepthCheck {
    let half = model.size() * 0.5;
    let mut check = DepthCheck::default();
    for axis in 0..3 {
        for sign in [-1.0, 1.0] {
            let normal = pose.rotation * Vector3::ith(axis, sign);
            let face_centre = pose * Point3::from(Vector3::ith(axis, sign * half[axis]));
            // A face is seen from the camera (at the origin) when its outward normal points back.
            if normal.dot(&face_centre.coords) >= 0.0 {
                continue;
            }
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..FACE_GRID {
                for j in 0..FACE_GRID {
                    // cell centres, so the grid keeps off the edges, where the depth image mixes
                    // this box with what is behind it
                    let s = (i as f64 + 0.5) / FACE_GRID as f64 * 2.0 - 1.0;
                    let t = (j as f64 + 0.5) / FACE_GRID as f64 * 2.0 - 1.0;
                    let mut local = Vector3::ith(axis, sign * half[axis]);
                    local[a] = s * half[a];
                    local[b] = t * half[b];
                    let p = pose * Point3::from(local);
                    let Some((nearest, closest)) = view.observed_around(&p) else {
                        continue;
                    };
                    check.samples += 1;
                    if p.z < nearest - tolerance_m {
                        check.in_front += 1;
                    } else if (p.z - closest).abs() <= tolerance_m {
                        check.agree += 1;
                    }
                }
            }
        }
    }
    check
}

/// The box at `pose` reflected through the best plane of `plane_points`, as a proper pose of the
/// same box (the reflection of a box is the same box, turned).
pub fn mirrored_pose(pose: &Isometry3<f64>, plane_points: &[Point3<f64>]) -> Isometry3<f64> {
    let (centroid, scatter) = adaptive::scatter(plane_points);
    let eigen = scatter.symmetric_eigen();
    let normal = eigen
        .eigenvectors
        .column(eigen.eigenvalues.imin())
        .into_owned();
    let reflection = Matrix3::identity() - 2.0 * normal * normal.transpose();
    // H·R has determinant −1; flipping the box's x axis (which maps the box onto itself as a set)
    // makes it a rotation again.
    let rotation = reflection
        * pose.rotation.to_rotation_matrix().matrix()
        * Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0));
    let centre = reflection * (pose.translation.vector - centroid) + centroid;
    Isometry3::from_parts(
        Translation3::from(centre),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation)),
    )
}

/// What [`resolve_mirror`] decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MirrorResolution {
    /// The pose the depth image supports (the given one when it cannot tell).
    pub pose: Isometry3<f64>,
    /// The mirror image was taken instead of the given pose.
    pub switched: bool,
    /// The depth image does not separate the two either (no samples, or scores within 0.1).
    pub still_ambiguous: bool,
}

/// The score gap under which the depth image is taken to leave a mirror tie undecided.
const DECISIVE_SCORE_GAP: f64 = 0.1;

/// Of a fit and its mirror image through the plane of its inliers, the one whose visible faces
/// agree with the depth image ([`check_against_depth`], [`DepthCheck::score`]).
pub fn resolve_mirror(
    model: &BoxModel,
    pose: &Isometry3<f64>,
    inlier_points: &[Point3<f64>],
    view: &DepthView,
    tolerance_m: f64,
) -> MirrorResolution {
    let mirror = mirrored_pose(pose, inlier_points);
    let given = check_against_depth(model, pose, view, tolerance_m).score();
    let other = check_against_depth(model, &mirror, view, tolerance_m).score();
    let decided =
        |a: f64, b: f64| a.is_finite() && (b == f64::NEG_INFINITY || a - b >= DECISIVE_SCORE_GAP);
    if decided(other, given) {
        MirrorResolution {
            pose: mirror,
            switched: true,
            still_ambiguous: false,
        }
    } else {
        MirrorResolution {
            pose: *pose,
            switched: false,
            still_ambiguous: !decided(given, other),
        }
    }
}

/// The depth tolerance for a fit whose inlier peaks have per-coordinate noise `noise_scale_m`:
/// a centimetre (the depth image's own error at the edges of faces) plus three peak sigmas.
pub fn depth_tolerance(noise_scale_m: f64) -> f64 {
    0.01 + 3.0 * noise_scale_m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::benchmark::render_depth;

    fn scene() -> (BoxModel, Isometry3<f64>) {
        let model = BoxModel::new(Vector3::new(0.3, 0.2, 0.12)).unwrap();
        let pose = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 1.2),
            UnitQuaternion::from_euler_angles(0.5, -0.4, 0.3),
        );
        (model, pose)
    }

    #[test]
    fn the_true_pose_agrees_with_its_own_depth_image() {
        let (model, pose) = scene();
        let image = render_depth(&model, &pose, 2.5);
        let view = image.view();
        let check = check_against_depth(&model, &pose, &view, 0.01);
        assert!(check.samples >= 60, "{check:?}");
        assert_eq!(check.in_front, 0, "{check:?}");
        assert!(
            check.agree as f64 >= 0.95 * check.samples as f64,
            "{check:?}"
        );
    }

    #[test]
    fn the_mirror_through_any_face_is_rejected_and_the_truth_kept() {
        let (model, pose) = scene();
        let image = render_depth(&model, &pose, 2.5);
        let view = image.view();
        let corners: Vec<Point3<f64>> = model.corners().iter().map(|c| pose * c).collect();
        for axis in 0..3 {
            for sign in [-1.0, 1.0] {
                let face: Vec<Point3<f64>> = model
                    .corners()
                    .iter()
                    .zip(&corners)
                    .filter(|(c, _)| c[axis] * sign > 0.0)
                    .map(|(_, p)| *p)
                    .collect();
                let mirror = mirrored_pose(&pose, &face);
                // the mirror keeps the face's four corners where they are
                let moved: Vec<Point3<f64>> = model.corners().iter().map(|c| mirror * c).collect();
                for p in &face {
                    let nearest = moved
                        .iter()
                        .map(|q| (p - q).norm())
                        .fold(f64::INFINITY, f64::min);
                    assert!(nearest < 1e-9, "face corner moved by {nearest}");
                }
                let from_truth = resolve_mirror(&model, &pose, &face, &view, 0.01);
                assert!(
                    !from_truth.switched && !from_truth.still_ambiguous,
                    "axis {axis} {sign}: {from_truth:?}"
                );
                let from_mirror = resolve_mirror(&model, &mirror, &face, &view, 0.01);
                assert!(from_mirror.switched, "axis {axis} {sign}: {from_mirror:?}");
                assert!(
                    from_mirror
                        .pose
                        .translation
                        .vector
                        .metric_distance(&pose.translation.vector)
                        < 1e-9
                );
            }
        }
    }

    #[test]
    fn without_depth_the_tie_stays() {
        let (model, pose) = scene();
        let depth = vec![0.0f32; 160 * 120];
        let view = DepthView {
            width: 160,
            height: 120,
            intrinsics: [125.0, 125.0, 79.5, 59.5],
            depth_m: &depth,
        };
        let face: Vec<Point3<f64>> = model.corners()[..4].iter().map(|c| pose * c).collect();
        let r = resolve_mirror(&model, &pose, &face, &view, 0.01);
        assert!(!r.switched && r.still_ambiguous);
    }
}
