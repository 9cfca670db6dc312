//! What is simulated: the boxes (from `objects` rows), the support (from the recipe's
//! `[support]`) and how long and how strictly to settle (the recipe's `[settle]`).

use boxpose_data::{Object, Pose};
use serde::Deserialize;

use crate::error::{PhysicsError, Result};

/// Largest deviation from 1 tolerated in an input quaternion's norm (the dataset reader's
/// tolerance); quaternions within it are normalized before simulation.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

// The support geometry is the dataset contract's (boxpose_data::support), shared with the Drake
// and Blender stages through the generated schema.json.
pub use boxpose_data::recipe::MAX_SETTLE_STEPS;
pub use boxpose_data::support::{BIN_WALL_THICKNESS_M, PALLET_HEIGHT_M, SUPPORT_FRICTION};

/// The friction coefficient of a contact between two materials, Drake's rule (`CoulombFriction`
/// combination): 2 μ₁ μ₂ / (μ₁ + μ₂), 0 when both are 0.
pub fn combined_friction(a: f64, b: f64) -> f64 {
    if a + b > 0.0 {
        2.0 * a * b / (a + b)
    } else {
        0.0
    }
}

/// Standard gravity, along −z of the world frame.
pub const GRAVITY_MPS2: f64 = 9.81;

/// One box: geometry, inertia, friction and the pose it starts from.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxBody {
    /// Edge lengths (dx, dy, dz) in metres along the box frame's axes.
    pub size: [f64; 3],
    pub mass_kg: f64,
    /// Coulomb coefficient (the dataset's `friction`).
    pub friction: f64,
    /// `T_world_box` before the drop.
    pub initial: Pose,
    /// The box rests at `initial` in an already settled pile: it starts asleep and moves only
    /// once something touches it ([`crate::resettle`]).
    pub at_rest: bool,
}

impl BoxBody {
    /// A box from an `objects` row, starting from its `initial_world_box` pose.
    pub fn from_object(object: &Object) -> Self {
        Self {
            size: object.size,
            mass_kg: object.mass_kg,
            friction: object.friction,
            initial: object.initial_world_box,
            at_rest: false,
        }
    }

    /// Principal moments of inertia of a solid box of uniform density (kg m²).
    pub fn diag_inertia(&self) -> [f64; 3] {
        let [x, y, z] = self.size.map(|s| s * s);
        let k = self.mass_kg / 12.0;
        [k * (y + z), k * (x + z), k * (x + y)]
    }
}

/// The recipe's support kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SupportKind {
    Floor,
    Bin,
    Pallet,
}

impl SupportKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Floor => "floor",
            Self::Bin => "bin",
            Self::Pallet => "pallet",
        }
    }
}

/// The surface the boxes are dropped on, the geometry of [`boxpose_data::support`] (as in
/// python/drake_scenes/plant.py and python/blender_scripts/scene.py). World frame: z up, gravity along −z, the
/// ground's top surface at z = 0, the support region |x| ≤ half_extent_m[0],
/// |y| ≤ half_extent_m[1] centred on the origin.
///
/// - floor: the ground z = 0 (MuJoCo: an unbounded plane; Drake: a 0.2 m thick box reaching 1 m
///   beyond the region — boxes that far out are rejected either way).
/// - bin: the ground plus four walls of height `wall_height_m` whose inner faces are the region's
///   edges (thickness [`BIN_WALL_THICKNESS_M`]; the x walls overlap the corners).
/// - pallet: a deck exactly the size of the region, [`PALLET_HEIGHT_M`] high, on the ground; boxes
///   rest on its top at z = [`PALLET_HEIGHT_M`].
///
/// Every support surface has friction [`SUPPORT_FRICTION`].
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Support {
    pub kind: SupportKind,
    pub half_extent_m: [f64; 2],
    pub wall_height_m: f64,
}

impl Support {
    pub fn floor() -> Self {
        Self {
            kind: SupportKind::Floor,
            half_extent_m: [0.25, 0.25],
            wall_height_m: 0.0,
        }
    }

    /// Height of the surface boxes rest on: 0, or the pallet's deck.
    pub fn top_z(&self) -> f64 {
        if self.kind == SupportKind::Pallet {
            PALLET_HEIGHT_M
        } else {
            0.0
        }
    }

    /// Whether a box centre at `t` is over the support region and above its top surface (the
    /// Drake stage's "box left the support region" check).
    pub fn holds(&self, t: [f64; 3]) -> bool {
        let [hx, hy] = self.half_extent_m;
        t[0].abs() <= hx && t[1].abs() <= hy && t[2] >= self.top_z()
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(PhysicsError::BadSupport(m));
        if !self.half_extent_m.iter().all(|h| h.is_finite() && *h > 0.0) {
            return bad(format!(
                "half_extent_m {:?} must be finite and positive",
                self.half_extent_m
            ));
        }
        if !self.wall_height_m.is_finite() || self.wall_height_m < 0.0 {
            return bad(format!(
                "wall_height_m {} must be finite and non-negative",
                self.wall_height_m
            ));
        }
        if self.kind == SupportKind::Bin && self.wall_height_m <= 0.0 {
            return bad("a bin needs wall_height_m > 0".into());
        }
        Ok(())
    }
}

/// How a drop is simulated and when it counts as settled: the recipe's `[settle]` section.
///
/// Settled: every body's linear speed ‖v‖ ≤ `max_linear_speed_mps` and angular speed
/// ‖ω‖ ≤ `max_angular_speed_radps` at every step spanning the last `window_s` of simulated time,
/// before `max_time_s`. Stable: settled, no two bodies (support included) interpenetrating by
/// more than `max_penetration_m`, and every box centre still over the support region and above
/// its top. This is the Drake stage's test (python/drake_scenes/settle.py).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SettleParams {
    pub time_step_s: f64,
    pub max_time_s: f64,
    pub window_s: f64,
    pub max_linear_speed_mps: f64,
    pub max_angular_speed_radps: f64,
    pub max_penetration_m: f64,
}

impl Default for SettleParams {
    /// The values of every shipped recipe.
    fn default() -> Self {
        Self {
            time_step_s: 0.001,
            max_time_s: 4.0,
            window_s: 0.2,
            max_linear_speed_mps: 0.005,
            max_angular_speed_radps: 0.05,
            max_penetration_m: 0.002,
        }
    }
}

impl SettleParams {
    /// The Drake stage's rules (`python/drake_scenes/recipe.py`), which `tests/test_fuzz_inputs.py`
    /// holds this to: finite values, positive thresholds, 0 < time step < window < max time,
    /// and at most [`MAX_SETTLE_STEPS`] steps.
    pub fn validate(&self) -> Result<()> {
        let all = [
            ("time_step_s", self.time_step_s),
            ("max_time_s", self.max_time_s),
            ("window_s", self.window_s),
            ("max_linear_speed_mps", self.max_linear_speed_mps),
            ("max_angular_speed_radps", self.max_angular_speed_radps),
            ("max_penetration_m", self.max_penetration_m),
        ];
        for (name, v) in all {
            if !v.is_finite() || v <= 0.0 {
                return Err(PhysicsError::BadParams(format!(
                    "{name} = {v} must be finite and positive"
                )));
            }
        }
        if !(self.time_step_s < self.window_s && self.window_s < self.max_time_s) {
            return Err(PhysicsError::BadParams(format!(
                "need time_step_s < window_s < max_time_s, got {} < {} < {}",
                self.time_step_s, self.window_s, self.max_time_s
            )));
        }
        let steps = self.max_time_s / self.time_step_s;
        if steps > MAX_SETTLE_STEPS {
            return Err(PhysicsError::BadParams(format!(
                "max_time_s / time_step_s = {steps:.3e} steps is more than {MAX_SETTLE_STEPS:.0e}"
            )));
        }
        Ok(())
    }

    /// Consecutive at-rest steps that span the window: the first and last are `window_s` apart.
    pub fn window_steps(&self) -> usize {
        ((self.window_s / self.time_step_s).round() as usize).max(1) + 1
    }

    /// Steps until `max_time_s`.
    pub fn max_steps(&self) -> usize {
        (self.max_time_s / self.time_step_s).round() as usize
    }
}

/// The physics a recipe asks for: its `[support]` and `[settle]` sections (others are ignored).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct RecipePhysics {
    pub support: Support,
    pub settle: SettleParams,
}

impl RecipePhysics {
    /// Parses a recipe's TOML text (as in `datasets/recipes/*.toml` or a scene's `recipe_toml`),
    /// checked as every reader checks it ([`boxpose_data::recipe::check_sections`]): it refuses
    /// keys that are not recipe keys, and checks the two sections it reads.
    pub fn from_toml(text: &str) -> Result<Self> {
        let mut table: toml::Table =
            toml::from_str(text).map_err(|e| PhysicsError::Recipe(e.to_string()))?;
        boxpose_data::recipe::check_sections(&table, |section| {
            section == "support" || section == "settle"
        })
        .map_err(PhysicsError::Recipe)?;
        // `settle.engine` says which simulator settles the scene stage's drops, not how: this
        // crate is the "mujoco" one, and it settles any recipe's drops (the search's, the
        // benchmark's re-settles of Drake scenes) under the same rules.
        if let Some(toml::Value::Table(settle)) = table.get_mut("settle") {
            settle.remove("engine");
        }
        let recipe: Self = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| PhysicsError::Recipe(e.to_string()))?;
        recipe.support.validate()?;
        recipe.settle.validate()?;
        Ok(recipe)
    }

    /// The two sections of a recipe read and checked in full ([`boxpose_data::recipe::Recipe`]).
    pub fn from_recipe(recipe: &boxpose_data::recipe::Recipe) -> Result<Self> {
        let kind = match recipe.support.kind.as_str() {
            "floor" => SupportKind::Floor,
            "bin" => SupportKind::Bin,
            "pallet" => SupportKind::Pallet,
            other => {
                return Err(PhysicsError::Recipe(format!(
                    "unknown support kind {other:?}"
                )));
            }
        };
        let s = &recipe.settle;
        let physics = Self {
            support: Support {
                kind,
                half_extent_m: recipe.support.half_extent_m,
                wall_height_m: recipe.support.wall_height_m,
            },
            settle: SettleParams {
                time_step_s: s.time_step_s,
                max_time_s: s.max_time_s,
                window_s: s.window_s,
                max_linear_speed_mps: s.max_linear_speed_mps,
                max_angular_speed_radps: s.max_angular_speed_radps,
                max_penetration_m: s.max_penetration_m,
            },
        };
        physics.support.validate()?;
        physics.settle.validate()?;
        Ok(physics)
    }

    pub fn from_file(path: &std::path::Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| PhysicsError::Recipe(format!("{}: {e}", path.display())))?;
        Self::from_toml(&text).map_err(|e| {
            let problem = match e {
                PhysicsError::Recipe(problem) => problem,
                other => other.to_string(),
            };
            PhysicsError::Recipe(format!("{}: {problem}", path.display()))
        })
    }
}

/// One scene to simulate: the support and the boxes, each with its starting pose.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneDescription {
    pub support: Support,
    pub boxes: Vec<BoxBody>,
}

impl SceneDescription {
    /// The scene of some `objects` rows (one scene's, in object_id order), from their
    /// `initial_world_box` poses.
    pub fn from_objects<'a>(
        support: Support,
        objects: impl IntoIterator<Item = &'a Object>,
    ) -> Self {
        Self {
            support,
            boxes: objects.into_iter().map(BoxBody::from_object).collect(),
        }
    }

    /// The initial poses of every box.
    pub fn initial_poses(&self) -> Vec<Pose> {
        self.boxes.iter().map(|b| b.initial).collect()
    }

    /// Checks everything MuJoCo would silently accept or choke on: sizes, masses, friction, the
    /// support and the initial poses.
    pub fn validate(&self) -> Result<()> {
        if self.boxes.is_empty() {
            return Err(PhysicsError::NoBoxes);
        }
        self.support.validate()?;
        for (index, b) in self.boxes.iter().enumerate() {
            if !b.size.iter().all(|s| s.is_finite() && *s > 0.0) {
                return Err(PhysicsError::BadSize {
                    index,
                    size: b.size,
                });
            }
            if !b.mass_kg.is_finite() || b.mass_kg <= 0.0 {
                return Err(PhysicsError::BadMass {
                    index,
                    mass_kg: b.mass_kg,
                });
            }
            if !b.friction.is_finite() || b.friction < 0.0 {
                return Err(PhysicsError::BadFriction {
                    index,
                    friction: b.friction,
                });
            }
        }
        check_poses(&self.initial_poses(), self.boxes.len())?;
        Ok(())
    }
}

/// Validates poses and returns them with normalized quaternions.
pub(crate) fn check_poses(poses: &[Pose], expected: usize) -> Result<Vec<Pose>> {
    if poses.len() != expected {
        return Err(PhysicsError::PoseCount {
            count: poses.len(),
            expected,
        });
    }
    poses
        .iter()
        .enumerate()
        .map(|(index, p)| {
            if !p
                .quat_wxyz
                .iter()
                .chain(&p.translation)
                .all(|v| v.is_finite())
            {
                return Err(PhysicsError::NonFinitePose {
                    index,
                    quat_wxyz: p.quat_wxyz,
                    translation: p.translation,
                });
            }
            let norm = p.quat_wxyz.iter().map(|v| v * v).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                return Err(PhysicsError::NonUnitQuaternion {
                    index,
                    quat_wxyz: p.quat_wxyz,
                    norm,
                });
            }
            Ok(Pose {
                quat_wxyz: p.quat_wxyz.map(|v| v / norm),
                translation: p.translation,
            })
        })
        .collect()
}
