//! The support geometries, written once: what the `scenes.support` values "floor", "bin" and
//! "pallet" mean. Every stage builds its support from these constants: the Drake scene stage
//! (`python/drake_scenes/plant.py`), the Blender stage (`python/blender_scripts/scene.py`, `synthetic.py`) and
//! MuJoCo (`boxpose-physics`). The Python stages read them from `python/boxpose_io/schema.json`
//! (its `"support"` object, generated from [`to_json`] by `boxpose schema`); the schema's drift
//! test fails when that file disagrees with this module.
//!
//! World frame: z up, the ground's top surface at z = 0, the support region the recipe's
//! rectangle |x| ≤ `half_extent_m[0]`, |y| ≤ `half_extent_m[1]` centred on the origin.
//!
//! - floor: the ground; boxes rest on it at z = 0.
//! - bin: the ground plus four walls of the recipe's `wall_height_m`, [`BIN_WALL_THICKNESS_M`]
//!   thick, standing on the ground with their inner faces on the region's edges (the walls
//!   along y, at ±x, reach over the corners).
//! - pallet: a slab of exactly the region's size, [`PALLET_HEIGHT_M`] high, standing on the
//!   ground; boxes rest on its top at z = [`PALLET_HEIGHT_M`].
//!
//! Every support surface has the Coulomb friction [`SUPPORT_FRICTION`].

/// Height of the pallet deck's top above the ground, in metres (a EUR pallet, 144 mm).
pub const PALLET_HEIGHT_M: f64 = 0.144;

/// Thickness of a bin's walls, in metres, outside the support region.
pub const BIN_WALL_THICKNESS_M: f64 = 0.02;

/// Coulomb friction coefficient (static and dynamic) of every support surface: ground, bin walls
/// and pallet. The boxes' own friction is their `objects.friction`; the simulators combine the
/// two.
pub const SUPPORT_FRICTION: f64 = 0.6;

/// The constants as the `"support"` object of `schema.json`.
pub fn to_json() -> serde_json::Value {
    serde_json::json!({
        "pallet_height_m": PALLET_HEIGHT_M,
        "bin_wall_thickness_m": BIN_WALL_THICKNESS_M,
        "friction": SUPPORT_FRICTION,
    })
}

/// The support geometries as a section of the column reference in `docs/dataset.md`.
pub fn to_markdown() -> String {
    format!(
        "### Supports\n\n\
         What the `scenes.support` values mean. World frame: z up, the ground's top at z = 0, the \
         support region the recipe's rectangle |x| ≤ `half_extent_m[0]`, |y| ≤ `half_extent_m[1]` \
         centred on the origin.\n\n\
         | support | geometry |\n|---|---|\n\
         | `floor` | The ground; boxes rest on it at z = 0. |\n\
         | `bin` | The ground and four walls of the recipe's `wall_height_m`, {BIN_WALL_THICKNESS_M} m \
         thick, whose inner faces are the region's edges (the walls at ±x reach over the corners). |\n\
         | `pallet` | A slab of exactly the region's size, {PALLET_HEIGHT_M} m high, on the ground; \
         boxes rest on its top at z = {PALLET_HEIGHT_M} m. |\n\n\
         Every support surface has Coulomb friction {SUPPORT_FRICTION}.\n"
    )
}
