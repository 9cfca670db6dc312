//! A seeded benchmark set the crate generates itself: boxes of many shapes seen as 8 noisy corner
//! peaks, some replaced by outliers placed uniformly or adversarially, and the failure criterion
//! and failure-prediction measure (AUROC) the fits are judged by.
//!
//! Used by `tests/benchmark.rs` (targets as assertions, on a small sample) and
//! `examples/fit_benchmark.rs` (the tables of `docs/benchmarks.md`).

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::BoxModel;
use crate::box_model::CORNER_COUNT;

/// A small, fast, seeded generator (SplitMix64), so that the set is the same on every machine
/// without a dependency.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn range(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.unit()
    }

    /// Uniform in 0..n.
    pub fn index(&mut self, n: usize) -> usize {
        (self.unit() * n as f64) as usize % n
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u = 1.0 - self.unit();
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// Box shapes of the set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// Three equal sides, 0.1–0.5 m (24 symmetries).
    Cube,
    /// Two equal sides 0.1–0.5 m and a third differing from them by 30–100 %.
    Square,
    /// Sides 0.2–0.5 m and a thickness of 4–8 cm.
    Plate,
    /// Three independent sides, 0.1–0.5 m.
    Generic,
}

impl Shape {
    pub const ALL: [Shape; 4] = [Shape::Cube, Shape::Square, Shape::Plate, Shape::Generic];

    pub fn name(self) -> &'static str {
        match self {
            Shape::Cube => "cube",
            Shape::Square => "square",
            Shape::Plate => "plate",
            Shape::Generic => "generic",
        }
    }

    fn sample(self, rng: &mut SplitMix64) -> Vector3<f64> {
        let mut size = match self {
            Shape::Cube => Vector3::repeat(rng.range(0.1, 0.5)),
            Shape::Square => {
                let a = rng.range(0.1, 0.5);
                let factor = if rng.unit() < 0.5 {
                    rng.range(1.3, 2.0)
                } else {
                    1.0 / rng.range(1.3, 2.0)
                };
                Vector3::new(a, a, a * factor)
            }
            // Sides that should differ are kept 15 % apart: a nearly square face is symmetric
            // within the noise, and MSSD (exact symmetries only) would count its quarter turn,
            // whose corners lie on the true ones, as a failure.
            Shape::Plate => loop {
                let (a, b) = (rng.range(0.2, 0.5), rng.range(0.2, 0.5));
                if distinct_sides(a, b) {
                    break Vector3::new(a, b, rng.range(0.04, 0.08));
                }
            },
            Shape::Generic => loop {
                let v = Vector3::from_fn(|_, _| rng.range(0.1, 0.5));
                if distinct_sides(v.x, v.y) && distinct_sides(v.y, v.z) && distinct_sides(v.x, v.z)
                {
                    break v;
                }
            },
        };
        // Which axis is the odd one out is part of the sample.
        let shift = rng.index(3);
        size = Vector3::from_fn(|i, _| size[(i + shift) % 3]);
        size
    }
}

fn distinct_sides(a: f64, b: f64) -> bool {
    (a - b).abs() >= 0.15 * a.max(b)
}

/// Where the outlier peaks go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outliers {
    /// Uniform in the cube of half-width half the diameter around the box centre (as the issue's
    /// measurement), replacing uniformly chosen corners.
    Uniform,
    /// Within 5–25 % of the shortest side of another true corner (a duplicate NMS peak).
    NearCorner,
    /// Uniform on the box's surface (a peak on a face).
    OnFace,
    /// A mirrored corner: the corner farthest from the camera (a hidden one) is replaced by its
    /// reflection through the plane of the face that best faces the camera (a depth flip, a
    /// corner of the mirror box); the other replaced corners, chosen uniformly, get uniform
    /// outliers.
    Mirrored,
}

impl Outliers {
    pub const ALL: [Outliers; 4] = [
        Outliers::Uniform,
        Outliers::NearCorner,
        Outliers::OnFace,
        Outliers::Mirrored,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Outliers::Uniform => "uniform",
            Outliers::NearCorner => "near_corner",
            Outliers::OnFace => "on_face",
            Outliers::Mirrored => "mirrored",
        }
    }
}

/// One generated box and its peaks.
#[derive(Debug, Clone)]
pub struct Case {
    pub model: BoxModel,
    pub truth: Isometry3<f64>,
    /// 8 peaks in a random order.
    pub points: Vec<Point3<f64>>,
    /// Random scores (outliers as likely as inliers to rank high).
    pub scores: Vec<f64>,
    /// Per peak: whether it is an outlier.
    pub is_outlier: Vec<bool>,
    /// Per peak: the true corner it stands for (or replaces, for an outlier).
    pub corner_of: Vec<usize>,
    /// Whether the inlier corners all lie in one plane (4 inliers on a face or a diagonal
    /// section), where a mirror image fits them as well.
    pub coplanar_inliers: bool,
}

/// A depth image rendered by ray casting: what the mirror check of [`crate::depth`] reads.
#[derive(Debug, Clone)]
pub struct DepthImage {
    pub width: usize,
    pub height: usize,
    /// fx, fy, cx, cy.
    pub intrinsics: [f64; 4],
    pub depth_m: Vec<f32>,
}

impl DepthImage {
    pub fn view(&self) -> crate::depth::DepthView<'_> {
        crate::depth::DepthView {
            width: self.width,
            height: self.height,
            intrinsics: self.intrinsics,
            depth_m: &self.depth_m,
        }
    }
}

/// The depth image of `model` at `pose` seen by a 160 × 120 camera with a focal length of 125 px
/// (the field of view of the recipes' 640 × 480 cameras at a quarter of their resolution), in
/// front of a wall perpendicular to the optical axis at `background_z` (a bin's floor).
pub fn render_depth(model: &BoxModel, pose: &Isometry3<f64>, background_z: f64) -> DepthImage {
    let (width, height) = (160, 120);
    let intrinsics = [125.0, 125.0, 79.5, 59.5];
    let inverse = pose.inverse();
    let origin = inverse * Point3::origin();
    let half = model.size() * 0.5;
    let depth_m = (0..width * height)
        .map(|i| {
            let (u, v) = ((i % width) as f64, (i / width) as f64);
            // a ray with unit z in the camera frame: its parameter at a hit is the hit's depth
            let ray = Vector3::new(
                (u - intrinsics[2]) / intrinsics[0],
                (v - intrinsics[3]) / intrinsics[1],
                1.0,
            );
            let direction = inverse.rotation * ray;
            let (mut near, mut far) = (0.0f64, f64::INFINITY);
            for a in 0..3 {
                let t1 = (-half[a] - origin[a]) / direction[a];
                let t2 = (half[a] - origin[a]) / direction[a];
                near = near.max(t1.min(t2));
                far = far.min(t1.max(t2));
            }
            (if near <= far { near } else { background_z }) as f32
        })
        .collect();
    DepthImage {
        width,
        height,
        intrinsics,
        depth_m,
    }
}

impl Case {
    /// The true box's depth image ([`render_depth`]) over a background one diameter behind its
    /// centre.
    pub fn depth_image(&self) -> DepthImage {
        render_depth(
            &self.model,
            &self.truth,
            self.truth.translation.z + self.model.diameter(),
        )
    }
}

/// `count` cases from `seed`: shape, `outliers` of the 8 peaks placed as `kind`, Gaussian noise of
/// `noise_m` per coordinate on the inliers, poses uniform in rotation at 0.8–2 m.
pub fn generate(
    seed: u64,
    count: usize,
    shape: Shape,
    outliers: usize,
    kind: Outliers,
    noise_m: f64,
) -> Vec<Case> {
    let mut rng = SplitMix64::new(seed);
    (0..count)
        .map(|_| case(&mut rng, shape, outliers.min(CORNER_COUNT), kind, noise_m))
        .collect()
}

fn case(rng: &mut SplitMix64, shape: Shape, k: usize, kind: Outliers, noise: f64) -> Case {
    let model = BoxModel::new(shape.sample(rng)).expect("positive sides");
    let quaternion =
        nalgebra::Quaternion::new(rng.normal(), rng.normal(), rng.normal(), rng.normal());
    let truth = Isometry3::from_parts(
        Translation3::new(
            rng.range(-0.3, 0.3),
            rng.range(-0.3, 0.3),
            rng.range(0.8, 2.0),
        ),
        UnitQuaternion::from_quaternion(quaternion),
    );
    let corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth * c).collect();
    let centre = truth.translation.vector;
    let half = model.size() * 0.5;

    let replaced: Vec<usize> = match kind {
        Outliers::Mirrored if k > 0 => {
            let farthest = (0..CORNER_COUNT)
                .max_by(|&a, &b| {
                    corners[a]
                        .coords
                        .norm()
                        .total_cmp(&corners[b].coords.norm())
                })
                .expect("8 corners");
            let mut pool: Vec<usize> = (0..CORNER_COUNT).filter(|&c| c != farthest).collect();
            std::iter::once(farthest)
                .chain((1..k).map(|_| pool.remove(rng.index(pool.len()))))
                .collect()
        }
        _ => {
            let mut pool: Vec<usize> = (0..CORNER_COUNT).collect();
            (0..k).map(|_| pool.remove(rng.index(pool.len()))).collect()
        }
    };
    // The face that best faces the camera: outward normal most opposed to the view ray.
    let (front_axis, front_sign) = (0..3)
        .flat_map(|axis| [(axis, -1.0), (axis, 1.0)])
        .min_by(|a, b| {
            let facing = |(axis, sign): (usize, f64)| {
                (truth.rotation * Vector3::ith(axis, sign)).dot(&centre.normalize())
            };
            facing(*a).total_cmp(&facing(*b))
        })
        .expect("six faces");

    let mut points = Vec::with_capacity(CORNER_COUNT);
    let mut is_outlier = Vec::with_capacity(CORNER_COUNT);
    for (i, corner) in corners.iter().enumerate() {
        if !replaced.contains(&i) {
            let jitter = Vector3::from_fn(|_, _| rng.normal() * noise);
            points.push(corner + jitter);
            is_outlier.push(false);
            continue;
        }
        let mirrored = kind == Outliers::Mirrored && i == replaced[0];
        let kind = if kind == Outliers::Mirrored && !mirrored {
            Outliers::Uniform
        } else {
            kind
        };
        let point = match kind {
            Outliers::Uniform => Point3::from(
                centre + Vector3::from_fn(|_, _| rng.range(-1.0, 1.0)) * 0.5 * model.diameter(),
            ),
            Outliers::NearCorner => {
                let other = (i + 1 + rng.index(CORNER_COUNT - 1)) % CORNER_COUNT;
                let direction = Vector3::from_fn(|_, _| rng.normal()).normalize();
                corners[other] + direction * rng.range(0.05, 0.25) * model.size().min()
            }
            Outliers::OnFace => {
                let areas = [
                    model.size().y * model.size().z,
                    model.size().x * model.size().z,
                    model.size().x * model.size().y,
                ];
                let mut pick = rng.unit() * (areas[0] + areas[1] + areas[2]);
                let mut axis = 0;
                while axis < 2 && pick >= areas[axis] {
                    pick -= areas[axis];
                    axis += 1;
                }
                let local = Vector3::from_fn(|a, _| {
                    if a == axis {
                        if rng.unit() < 0.5 { -half[a] } else { half[a] }
                    } else {
                        rng.range(-half[a], half[a])
                    }
                });
                truth * Point3::from(local)
            }
            Outliers::Mirrored => {
                let mut local = model.corners()[i].coords;
                let plane = front_sign * half[front_axis];
                // A corner on the front face itself is reflected through the back face instead.
                let plane = if (local[front_axis] - plane).abs() < 1e-12 {
                    -plane
                } else {
                    plane
                };
                local[front_axis] = 2.0 * plane - local[front_axis];
                truth * Point3::from(local) + Vector3::from_fn(|_, _| rng.normal() * noise)
            }
        };
        points.push(point);
        is_outlier.push(true);
    }
    let inlier_corners: Vec<Point3<f64>> = (0..CORNER_COUNT)
        .filter(|i| !replaced.contains(i))
        .map(|i| model.corners()[i])
        .collect();
    let coplanar_inliers = inlier_corners.len() <= 3
        || (inlier_corners.len() == 4 && {
            let [a, b, c, d] = [
                inlier_corners[0],
                inlier_corners[1],
                inlier_corners[2],
                inlier_corners[3],
            ];
            (b - a).cross(&(c - a)).dot(&(d - a)).abs() < 1e-12
        });

    // A random order, so that no fit can use the corner order.
    let mut order: Vec<usize> = (0..CORNER_COUNT).collect();
    for i in (1..CORNER_COUNT).rev() {
        order.swap(i, rng.index(i + 1));
    }
    let scores = (0..CORNER_COUNT).map(|_| rng.range(0.2, 1.0)).collect();
    Case {
        model,
        truth,
        points: order.iter().map(|&i| points[i]).collect(),
        scores,
        is_outlier: order.iter().map(|&i| is_outlier[i]).collect(),
        corner_of: order,
        coplanar_inliers,
    }
}

/// The noise floor: the pose fitted by least squares ([`crate::align::kabsch`]) to the inliers
/// with their true corners, which no fit from unlabelled peaks can beat on average. `None` with
/// fewer than 3 inliers.
pub fn oracle_pose(case: &Case) -> Option<Isometry3<f64>> {
    let corners = case.model.corners();
    let (sources, targets): (Vec<_>, Vec<_>) = (0..case.points.len())
        .filter(|&i| !case.is_outlier[i])
        .map(|i| (corners[case.corner_of[i]], case.points[i]))
        .unzip();
    crate::align::kabsch(&sources, &targets).ok()
}

/// A fit is wrong when its MSSD exceeds this fraction of the box's diameter.
pub const WRONG_FRACTION_OF_DIAMETER: f64 = 0.1;
