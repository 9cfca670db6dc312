//! What a scene recipe (`datasets/recipes/*.toml`) may hold, written once: every key, the support
//! kinds, and the bound on a settle's length. Three readers apply it: the Drake stage
//! (`python/drake_scenes/recipe.py`), the Blender stage (`python/blender_scripts/recipe.py`) and MuJoCo
//! (`boxpose-physics`'s `RecipePhysics`). The Python readers load it from
//! `python/boxpose_io/schema.json` (its `"recipe"` object, generated from [`to_json`]); the
//! schema's drift test fails when that file disagrees with this module, and
//! `tests/test_fuzz_inputs.py` checks that the Drake and Rust readers accept and refuse the same
//! supports and settle parameters.

/// Every key a recipe may hold, dotted by section; a reader refuses any other key.
pub const RECIPE_KEYS: &[&str] = &[
    // the recipe itself
    "name",
    "description",
    "seed",
    "num_scenes",
    // Drake: what is dropped, where, and when it counts as settled
    "boxes.count",
    "boxes.size_min_m",
    "boxes.size_max_m",
    "boxes.density_kg_m3",
    "boxes.friction",
    "support.kind",
    "support.half_extent_m",
    "support.wall_height_m",
    "drop.height_m",
    "drop.min_separation_m",
    "drop.max_solve_attempts",
    "settle.time_step_s",
    "settle.max_time_s",
    "settle.window_s",
    "settle.max_linear_speed_mps",
    "settle.max_angular_speed_radps",
    "settle.max_penetration_m",
    // both: the boxes' surfaces
    "materials.roughness",
    "materials.tape_probability",
    "materials.label_probability",
    // Blender: cameras, lights, render settings
    "camera.frames_per_scene",
    "camera.width",
    "camera.height",
    "camera.hfov_deg",
    "camera.distance_m",
    "camera.elevation_deg",
    "camera.azimuth_deg",
    "camera.look_at_jitter_m",
    "camera.look_at_object",
    "lighting.sun_strength",
    "lighting.sun_elevation_deg",
    "lighting.sun_azimuth_deg",
    "lighting.area_lights",
    "lighting.area_power_w",
    "lighting.world_strength",
    "lighting.world_color_jitter",
    "render.samples",
    "render.denoise",
    "render.sensor_depth",
    "render.max_bounces",
    "render.view_transform",
    "render.exposure",
];

/// The values of `support.kind` (and of the `scenes.support` column): see [`crate::support`].
pub const SUPPORT_KINDS: [&str; 3] = ["floor", "bin", "pallet"];

/// Most simulation steps a settle may take (`settle.max_time_s / settle.time_step_s`): a
/// resource bound, so that a recipe cannot ask for a simulation of years (hours at most).
pub const MAX_SETTLE_STEPS: f64 = 1e7;

/// The dotted keys of a parsed recipe that are not recipe keys, sorted (a table that is not a
/// section counts as one unknown key).
pub fn unknown_keys(recipe: &toml::Table) -> Vec<String> {
    fn walk(table: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (key, value) in table {
            let dotted = format!("{prefix}{key}");
            let section = format!("{dotted}.");
            match value {
                toml::Value::Table(inner)
                    if RECIPE_KEYS.iter().any(|k| k.starts_with(&section)) =>
                {
                    walk(inner, &section, out)
                }
                _ if !RECIPE_KEYS.contains(&dotted.as_str()) => out.push(dotted),
                _ => {}
            }
        }
    }
    let mut out = Vec::new();
    walk(recipe, "", &mut out);
    out.sort();
    out
}

/// The facts as the `"recipe"` object of `schema.json`.
pub fn to_json() -> serde_json::Value {
    serde_json::json!({
        "keys": RECIPE_KEYS,
        "support_kinds": SUPPORT_KINDS,
        "max_settle_steps": MAX_SETTLE_STEPS,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_are_found_at_every_level() {
        let recipe: toml::Table = toml::from_str(
            "name = 'x'\ncolour = 1\n[settle]\nmax_tiem_s = 2.0\ntime_step_s = 0.001\n[extra]\na = 1\n",
        )
        .unwrap();
        assert_eq!(
            unknown_keys(&recipe),
            ["colour", "extra", "settle.max_tiem_s"]
        );
    }
}
