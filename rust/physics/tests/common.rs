//! Helpers shared by the physics tests.
#![allow(dead_code)]

use boxpose_physics::{BoxBody, Pose, SceneDescription, Support};

/// Unit quaternion (w, x, y, z) of a rotation by `angle` about `axis`.
pub fn axis_angle(axis: [f64; 3], angle: f64) -> [f64; 4] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let (s, c) = (angle / 2.0).sin_cos();
    [c, s * axis[0] / n, s * axis[1] / n, s * axis[2] / n]
}

/// Hamilton product a ⊗ b (apply b, then a).
pub fn qmul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

/// Lowest z of the box's corners at `pose`.
pub fn lowest_z(size: [f64; 3], pose: &Pose) -> f64 {
    let r = boxpose_physics::rotation_matrix(pose.quat_wxyz);
    let half = size.map(|s| s / 2.0);
    pose.translation[2] - (0..3).map(|k| r[2][k].abs() * half[k]).sum::<f64>()
}

/// A box of uniform density 150 kg/m³ whose lowest corner is `gap` above z = 0.
pub fn dropped_box(
    size: [f64; 3],
    quat: [f64; 4],
    xy: [f64; 2],
    gap: f64,
    friction: f64,
) -> BoxBody {
    let mut pose = Pose {
        quat_wxyz: quat,
        translation: [xy[0], xy[1], 0.0],
    };
    pose.translation[2] = gap - lowest_z(size, &pose);
    BoxBody {
        size,
        mass_kg: 150.0 * size.iter().product::<f64>(),
        friction,
        initial: pose,
        at_rest: false,
    }
}

pub fn floor_scene(boxes: Vec<BoxBody>) -> SceneDescription {
    SceneDescription {
        support: Support::floor(),
        boxes,
    }
}

/// Small deterministic generator (xorshift) so tests need no rand dependency.
pub struct Rng(pub u64);

impl Rng {
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        lo + (hi - lo) * ((self.0 >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Uniformly random rotation (Shoemake).
    pub fn quat(&mut self) -> [f64; 4] {
        let (u1, u2, u3) = (
            self.uniform(0.0, 1.0),
            self.uniform(0.0, 1.0),
            self.uniform(0.0, 1.0),
        );
        let tau = std::f64::consts::TAU;
        let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
        [
            a * (tau * u2).sin(),
            a * (tau * u2).cos(),
            b * (tau * u3).sin(),
            b * (tau * u3).cos(),
        ]
    }
}
