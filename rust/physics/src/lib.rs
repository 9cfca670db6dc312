//! MuJoCo drop-and-settle for boxpose scenes.
//!
//! One description, many consumers: a [`SceneDescription`] is built from the dataset's `objects`
//! rows and the recipe's `[support]` ([`RecipePhysics`]), rendered as MJCF ([`to_mjcf`]) and
//! settled with MuJoCo ([`settle`], or a reusable [`Settler`] for many drops of one scene). The
//! stability test is the Drake stage's: every body's ‖v‖ and ‖ω‖ under the recipe's thresholds
//! over the whole window.
//!
//! World frame (as in drake_scenes): z up, gravity −9.81 m/s² along z, the ground's top surface
//! at z = 0 (see [`Support`]). Poses are `T_world_box` as in the dataset contract: unit quaternion (w, x, y, z)
//! and the box centre.

mod agreement;
mod drops;
mod error;
mod mjcf;
mod scene;
mod settle;

pub use agreement::{Agreement, settle_and_compare};
pub use boxpose_data::Pose;
pub use drops::settle_drop;
pub use error::{PhysicsError, Result};
pub use mjcf::{
    CONTACT_SOLIMP, CONTACT_SOLREF, CREEP_CURE, Cone, CreepCure, IMPRATIO, Integrator,
    MujocoOptions, RESETTLE_SLEEP_TOLERANCE, Solver, to_mjcf, to_mjcf_with,
};
pub use scene::{
    BIN_WALL_THICKNESS_M, BoxBody, GRAVITY_MPS2, PALLET_HEIGHT_M, QUATERNION_NORM_TOLERANCE,
    RecipePhysics, SUPPORT_FRICTION, SceneDescription, SettleParams, Support, SupportKind,
    combined_friction,
};
pub use settle::{
    Certificate, DISTANCE_HORIZON_M, Rejection, SettleOutcome, Settler, resettle, settle,
};

/// The MuJoCo version this crate binds and links (the `mujoco` wheel's library).
pub const MUJOCO_VERSION: &str = "3.17.0";

/// A face of a box: the one whose outward normal is +axis (`positive`) or −axis of the box frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Face {
    /// 0 = x, 1 = y, 2 = z.
    pub axis: usize,
    pub positive: bool,
}

impl std::fmt::Display for Face {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}{}",
            if self.positive { '+' } else { '-' },
            ['x', 'y', 'z'][self.axis]
        )
    }
}

/// Rotation matrix (row-major) of a unit quaternion (w, x, y, z), by nalgebra.
pub fn rotation_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    let r = nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(w, x, y, z))
        .to_rotation_matrix();
    std::array::from_fn(|row| std::array::from_fn(|col| r[(row, col)]))
}

/// The face of a box with orientation `quat_wxyz` whose outward normal points most nearly down
/// (world −z), and the angle between that normal and −z in radians (0 when resting flat).
pub fn down_face(quat_wxyz: [f64; 4]) -> (Face, f64) {
    let r = rotation_matrix(quat_wxyz);
    // World z-component of each box axis.
    let up = r[2];
    let axis = (0..3)
        .max_by(|&a, &b| up[a].abs().total_cmp(&up[b].abs()))
        .unwrap_or(2);
    let tilt = up[axis].abs().clamp(0.0, 1.0).acos();
    (
        Face {
            axis,
            positive: up[axis] < 0.0,
        },
        tilt,
    )
}
