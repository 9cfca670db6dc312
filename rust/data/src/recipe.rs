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
    "materials.tape_along",
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

/// The values of `materials.tape_along`: which side of a box's top (+z) face its tape strip and
/// its label's long (u) axis follow. `"long"`: the longer side (x when dx ≥ dy), as on a regular
/// slotted carton, so the texture tells the two sides of a nearly square top apart and a keypoint
/// network can learn the quarter turn. `"random"`: either side at random (the default, and what
/// every dataset written before the key existed holds). Both draw the same random numbers, so only
/// those two choices differ. The Blender stage applies it (`blender_scripts.sampling`).
pub const TAPE_ALONG: [&str; 2] = ["long", "random"];

/// `materials.tape_along` when a recipe does not give it: the datasets (and the networks trained
/// on them) that predate the key must render as they did.
pub const TAPE_ALONG_DEFAULT: &str = "random";

/// A recipe's `materials.tape_along` (one of [`TAPE_ALONG`], [`TAPE_ALONG_DEFAULT`] when absent),
/// or the message that refuses it; the Python readers apply the same rule
/// (`drake_scenes.recipe.read_tape_along`).
pub fn tape_along(recipe: &toml::Table) -> Result<&'static str, String> {
    let Some(value) = recipe.get("materials").and_then(|m| m.get("tape_along")) else {
        return Ok(TAPE_ALONG_DEFAULT);
    };
    value
        .as_str()
        .and_then(|v| TAPE_ALONG.iter().find(|&&accepted| accepted == v).copied())
        .ok_or_else(|| {
            // as JSON: the TOML writer is not compiled in, and a string, number, boolean or
            // list reads the same either way
            let written = serde_json::to_string(value).unwrap_or_else(|_| format!("{value:?}"));
            format!(
                "key 'materials.tape_along' must be \"long\" or \"random\", got {written} \
                 (\"long\" ties the tape and the label to the top face's longer side, for new \
                 recipes; \"random\", the default, draws them as the existing datasets do)"
            )
        })
}

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
        "tape_along": TAPE_ALONG,
        "tape_along_default": TAPE_ALONG_DEFAULT,
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

    #[test]
    fn tape_along_defaults_to_random_and_refuses_other_values_naming_the_key() {
        let read = |text: &str| tape_along(&toml::from_str(text).unwrap());
        assert_eq!(read("[materials]\nroughness = [0.5, 0.9]\n"), Ok("random"));
        assert_eq!(read("[materials]\ntape_along = 'long'\n"), Ok("long"));
        assert_eq!(read("[materials]\ntape_along = 'random'\n"), Ok("random"));
        for bad in ["\"Long\"", "\"short\"", "1", "true", "[\"long\"]"] {
            let problem = read(&format!("[materials]\ntape_along = {bad}\n")).unwrap_err();
            assert!(
                problem.contains("materials.tape_along")
                    && problem.contains("\"long\" or \"random\"")
                    && problem.contains(&format!("got {bad}")),
                "{problem}"
            );
        }
    }
}
