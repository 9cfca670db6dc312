//! The scene stage's MuJoCo engine, one drop at a time (`boxpose settle-drops`): the Drake stage
//! samples and projects a scene (python/drake_scenes) and hands its drop over as one JSON object;
//! [`settle_drop`] settles it under the recipe's `[support]` and `[settle]` and answers with the
//! settled poses and the certificate, as a JSON object.

use serde_json::{Value, json};

use crate::{BoxBody, Pose, RecipePhysics, SceneDescription, settle};

/// Settles the drop `line` holds: `{"recipe_toml": TEXT, "boxes": [{"size_m", "mass_kg",
/// "friction", "quat_wxyz", "translation_m"}, …]}`, each box dropped from its pose at rest.
/// Answers `{"settled", "stable", "rejection", "poses": [{"quat_wxyz", "translation_m"}, …],
/// "settle_time_s", "max_linear_speed_mps", "max_angular_speed_radps", "min_signed_distance_m",
/// "wall_time_s", "steps"}`; Err names the field that is wrong (`boxes[1]: "size_m" …`).
pub fn settle_drop(line: &str) -> Result<Value, String> {
    let drop: Value = serde_json::from_str(line).map_err(|e| format!("not a JSON object: {e}"))?;
    let recipe_toml = drop["recipe_toml"]
        .as_str()
        .ok_or("\"recipe_toml\" must be the recipe's TOML text")?;
    let recipe = RecipePhysics::from_toml(recipe_toml).map_err(|e| format!("recipe_toml: {e}"))?;
    let boxes = drop["boxes"]
        .as_array()
        .ok_or("\"boxes\" must be a list")?
        .iter()
        .enumerate()
        .map(|(i, b)| box_body(b).map_err(|e| format!("boxes[{i}]: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    let scene = SceneDescription {
        support: recipe.support,
        boxes,
    };
    let outcome = settle(&scene, &recipe.settle).map_err(|e| e.to_string())?;
    let c = &outcome.certificate;
    Ok(json!({
        "settled": outcome.settled,
        "stable": outcome.stable,
        "rejection": outcome.rejection.map(|r| r.as_str()),
        "poses": outcome.poses.iter().map(|p| json!({
            "quat_wxyz": p.quat_wxyz,
            "translation_m": p.translation,
        })).collect::<Vec<_>>(),
        "settle_time_s": c.settle_time_s,
        "max_linear_speed_mps": c.max_linear_speed_mps,
        "max_angular_speed_radps": c.max_angular_speed_radps,
        "min_signed_distance_m": c.min_signed_distance_m,
        "wall_time_s": c.wall_time_s,
        "steps": c.steps,
    }))
}

fn numbers<const N: usize>(value: &Value, key: &str) -> Result<[f64; N], String> {
    let list = value[key]
        .as_array()
        .filter(|l| l.len() == N)
        .ok_or_else(|| format!("\"{key}\" must be a list of {N} numbers"))?;
    let mut out = [0.0; N];
    for (slot, v) in out.iter_mut().zip(list) {
        *slot = v
            .as_f64()
            .ok_or_else(|| format!("\"{key}\" must be a list of {N} numbers, got {v}"))?;
    }
    Ok(out)
}

fn number(value: &Value, key: &str) -> Result<f64, String> {
    value[key]
        .as_f64()
        .ok_or_else(|| format!("\"{key}\" must be a number"))
}

fn box_body(value: &Value) -> Result<BoxBody, String> {
    Ok(BoxBody {
        size: numbers(value, "size_m")?,
        mass_kg: number(value, "mass_kg")?,
        friction: number(value, "friction")?,
        initial: Pose {
            quat_wxyz: numbers(value, "quat_wxyz")?,
            translation: numbers(value, "translation_m")?,
        },
        at_rest: false,
    })
}
