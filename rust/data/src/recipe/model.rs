//! The typed recipe: every key of [`RECIPE_REFERENCE`] as a field, read once and checked against
//! the reference — its types, bounds and choices, and the rules between keys that the bounds
//! cannot say — so that a Rust reader uses fields instead of walking TOML, and every Rust reader
//! refuses the same recipes with the same message. The Python stages check the same reference
//! (`boxpose_io.recipe`, from schema.json).

use serde::{Deserialize, Serialize};

use super::{
    Accepted, Bound, MAX_SETTLE_STEPS, RECIPE_REFERENCE, RecipeKey, ValueType, WhenAbsent,
    unknown_keys,
};

/// A whole recipe (`datasets/recipes/*.toml`, a scene's `recipe_toml`), checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    pub seed: i64,
    pub num_scenes: i64,
    pub boxes: Boxes,
    pub support: Support,
    pub drop: Drop,
    pub settle: Settle,
    pub materials: Materials,
    pub camera: Camera,
    pub lighting: Lighting,
    pub render: Render,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Boxes {
    pub count: [i64; 2],
    pub size_min_m: [f64; 3],
    pub size_max_m: [f64; 3],
    pub density_kg_m3: [f64; 2],
    pub friction: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Support {
    /// One of [`super::SUPPORT_KINDS`].
    pub kind: String,
    pub half_extent_m: [f64; 2],
    pub wall_height_m: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drop {
    pub height_m: [f64; 2],
    pub min_separation_m: f64,
    pub max_solve_attempts: i64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settle {
    pub time_step_s: f64,
    pub max_time_s: f64,
    pub window_s: f64,
    pub max_linear_speed_mps: f64,
    pub max_angular_speed_radps: f64,
    pub max_penetration_m: f64,
    /// One of [`super::SETTLE_ENGINES`].
    #[serde(default = "defaults::settle_engine")]
    pub engine: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Materials {
    pub roughness: [f64; 2],
    pub tape_probability: f64,
    pub label_probability: f64,
    /// One of [`super::TAPE_ALONG`].
    #[serde(default = "defaults::tape_along")]
    pub tape_along: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub frames_per_scene: i64,
    pub width: i64,
    pub height: i64,
    pub hfov_deg: [f64; 2],
    pub distance_m: [f64; 2],
    pub elevation_deg: [f64; 2],
    pub azimuth_deg: [f64; 2],
    pub look_at_jitter_m: f64,
    /// One of [`super::CAMERA_REGIONS`].
    #[serde(default = "defaults::camera_region")]
    pub region: String,
    #[serde(default = "defaults::region_margin")]
    pub region_margin: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at_object: Option<i64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lighting {
    pub sun_strength: [f64; 2],
    #[serde(default = "defaults::sun_elevation_deg")]
    pub sun_elevation_deg: [f64; 2],
    #[serde(default = "defaults::sun_azimuth_deg")]
    pub sun_azimuth_deg: [f64; 2],
    pub area_lights: [i64; 2],
    pub area_power_w: [f64; 2],
    pub world_strength: [f64; 2],
    pub world_color_jitter: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Render {
    pub samples: i64,
    pub denoise: bool,
    pub sensor_depth: bool,
    #[serde(default = "defaults::max_bounces")]
    pub max_bounces: i64,
    #[serde(default = "defaults::view_transform")]
    pub view_transform: String,
    #[serde(default = "defaults::exposure")]
    pub exposure: f64,
}

/// The reference's `WhenAbsent::Value`s, as serde needs them (a test checks they agree).
mod defaults {
    pub fn settle_engine() -> String {
        super::super::SETTLE_ENGINE_DEFAULT.into()
    }
    pub fn tape_along() -> String {
        super::super::TAPE_ALONG_DEFAULT.into()
    }
    pub fn camera_region() -> String {
        super::super::CAMERA_REGION_DEFAULT.into()
    }
    pub fn region_margin() -> f64 {
        1.75
    }
    pub fn sun_elevation_deg() -> [f64; 2] {
        [30.0, 80.0]
    }
    pub fn sun_azimuth_deg() -> [f64; 2] {
        [0.0, 360.0]
    }
    pub fn max_bounces() -> i64 {
        4
    }
    pub fn view_transform() -> String {
        "AgX".into()
    }
    pub fn exposure() -> f64 {
        -1.0
    }
}

impl Recipe {
    /// Parses and checks a recipe's TOML text; the error is the problem, for the caller to
    /// prefix with where the text came from.
    pub fn from_toml(text: &str) -> Result<Self, String> {
        let table: toml::Table = toml::from_str(text).map_err(|e| format!("invalid TOML ({e})"))?;
        Self::from_table(table)
    }

    /// [`Recipe::from_toml`] of a parsed table.
    pub fn from_table(table: toml::Table) -> Result<Self, String> {
        check(&table)?;
        toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| e.message().to_string())
    }
}

/// Whether `table` is a recipe every reader accepts: no unknown key, every required key, each
/// value of its type and within the reference's bounds, and the rules between keys. The first
/// problem found, naming its key.
pub fn check(table: &toml::Table) -> Result<(), String> {
    check_sections(table, |_| true)
}

/// [`check`] for a reader of some sections only (`""` is the top level): it refuses unknown keys
/// anywhere, but checks only the keys of the sections `reads` and the rules among them, as the
/// Python stages do (`boxpose_io.recipe.read`).
pub fn check_sections(table: &toml::Table, reads: impl Fn(&str) -> bool) -> Result<(), String> {
    let unknown = unknown_keys(table);
    if !unknown.is_empty() {
        return Err(format!(
            "unknown key{} {} (misspelt? docs/recipes.md lists every recipe key with its type, \
             range and default, as does `boxpose schema` under \"recipe\")",
            if unknown.len() > 1 { "s" } else { "" },
            unknown
                .iter()
                .map(|k| format!("'{k}'"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    for key in RECIPE_REFERENCE.iter().filter(|k| reads(section_of(k.key))) {
        match lookup(table, key.key) {
            None if key.when_absent == WhenAbsent::Required => {
                return Err(format!("missing key '{}'", key.key));
            }
            None => {}
            Some(value) => check_value(key, value)?,
        }
    }
    check_rules(&|key| lookup(table, key).filter(|_| reads(section_of(key))))
}

/// `"camera"` for `camera.width`, `""` for a top-level key.
fn section_of(dotted: &str) -> &str {
    dotted.split_once('.').map_or("", |(section, _)| section)
}

fn lookup<'a>(table: &'a toml::Table, dotted: &str) -> Option<&'a toml::Value> {
    match dotted.split_once('.') {
        Some((section, key)) => table.get(section)?.as_table()?.get(key),
        None => table.get(dotted),
    }
}

/// A number of a recipe: TOML writes `0` for `0.0` happily, so an integer is a float too.
fn number(value: &toml::Value, integer: bool) -> Option<f64> {
    match value {
        toml::Value::Integer(i) => Some(*i as f64),
        toml::Value::Float(f) if !integer => Some(*f),
        _ => None,
    }
}

fn check_value(key: &RecipeKey, value: &toml::Value) -> Result<(), String> {
    let written = serde_json::to_string(value).unwrap_or_else(|_| format!("{value:?}"));
    let wrong_type = || {
        format!(
            "key '{}' must be {}, got {written}",
            key.key,
            key.value_type.name()
        )
    };
    let numbers: Vec<f64> = match key.value_type {
        ValueType::String => {
            // a choice says its choices whatever was written instead (a number, a list, …)
            return match (key.accepted, value.as_str()) {
                (Accepted::OneOf(choices), text) if !text.is_some_and(|t| choices.contains(&t)) => {
                    let names: Vec<String> = choices.iter().map(|c| format!("\"{c}\"")).collect();
                    Err(format!(
                        "key '{}' must be {}, got {written}",
                        key.key,
                        names.join(" or ")
                    ))
                }
                (_, None) => Err(wrong_type()),
                _ => Ok(()),
            };
        }
        ValueType::Boolean => return value.as_bool().map(|_| ()).ok_or_else(wrong_type),
        ValueType::Integer => vec![number(value, true).ok_or_else(wrong_type)?],
        ValueType::Float => vec![number(value, false).ok_or_else(wrong_type)?],
        list => {
            let (length, integer) = match list {
                ValueType::IntegerRange => (2, true),
                ValueType::FloatXyz => (3, false),
                _ => (2, false),
            };
            let items = value.as_array().ok_or_else(wrong_type)?;
            let numbers: Option<Vec<f64>> = items.iter().map(|v| number(v, integer)).collect();
            match numbers {
                Some(numbers) if numbers.len() == length => numbers,
                _ => return Err(wrong_type()),
            }
        }
    };
    if numbers.iter().any(|v| !v.is_finite()) {
        return Err(format!("key '{}' must be finite, got {written}", key.key));
    }
    let is_range = matches!(
        key.value_type,
        ValueType::IntegerRange | ValueType::FloatRange
    );
    if is_range && numbers[0] > numbers[1] {
        return Err(format!(
            "key '{}' is a range [min, max] with min above max: {written}",
            key.key
        ));
    }
    if let Accepted::Within { min, max, .. } = key.accepted {
        let inside = |v: f64| {
            let above = match min {
                Bound::Unbounded => true,
                Bound::Inclusive(lo) => v >= lo,
                Bound::Exclusive(lo) => v > lo,
            };
            let below = match max {
                Bound::Unbounded => true,
                Bound::Inclusive(hi) => v <= hi,
                Bound::Exclusive(hi) => v < hi,
            };
            above && below
        };
        if !numbers.iter().all(|&v| inside(v)) {
            return Err(format!(
                "key '{}' must be {}, got {written}",
                key.key,
                key.accepted.to_markdown(key.value_type)
            ));
        }
    }
    Ok(())
}

/// The rules between keys (the reference's `and` texts) among the keys `value` gives; the values
/// are already checked one by one.
fn check_rules<'a>(value: &dyn Fn(&str) -> Option<&'a toml::Value>) -> Result<(), String> {
    let float = |key: &str| value(key).and_then(|v| number(v, false));
    let list = |key: &str| -> Vec<f64> {
        value(key)
            .and_then(|v| v.as_array())
            .map(|a| a.iter().filter_map(|v| number(v, false)).collect())
            .unwrap_or_default()
    };
    let (size_min, size_max) = (list("boxes.size_min_m"), list("boxes.size_max_m"));
    if size_min.iter().zip(&size_max).any(|(lo, hi)| lo > hi) {
        return Err("boxes.size_min_m must be ≤ boxes.size_max_m on every axis".into());
    }
    let kind = value("support.kind").and_then(|v| v.as_str());
    if kind == Some("bin") && float("support.wall_height_m").is_some_and(|h| h <= 0.0) {
        return Err("a bin needs support.wall_height_m > 0".into());
    }
    if let (Some(step), Some(window), Some(max_time)) = (
        float("settle.time_step_s"),
        float("settle.window_s"),
        float("settle.max_time_s"),
    ) {
        if !(step < window && window < max_time) {
            return Err(format!(
                "settle: need time_step_s < window_s < max_time_s, got {step} < {window} < {max_time}"
            ));
        }
        let steps = max_time / step;
        if steps > MAX_SETTLE_STEPS {
            return Err(format!(
                "settle: max_time_s / time_step_s = {steps:.3e} steps is more than {MAX_SETTLE_STEPS:.0e}"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped(name: &str) -> String {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../datasets/recipes")
            .join(name);
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    /// clutter.toml with the keys that have a default removed.
    fn without_defaults() -> toml::Table {
        let mut table: toml::Table = shipped("clutter.toml").parse().unwrap();
        for key in RECIPE_REFERENCE {
            if let WhenAbsent::Value(_) | WhenAbsent::Absent(_) = key.when_absent {
                let (section, name) = key.key.split_once('.').unwrap_or(("", key.key));
                let holder = if section.is_empty() {
                    &mut table
                } else {
                    table[section].as_table_mut().unwrap()
                };
                holder.remove(name);
            }
        }
        table
    }

    #[test]
    fn every_shipped_recipe_reads() {
        let folder =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/recipes");
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let text = std::fs::read_to_string(&path).unwrap();
                Recipe::from_toml(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            }
        }
    }

    #[test]
    fn the_fields_are_the_reference_keys_and_the_defaults_its_values() {
        let recipe = Recipe::from_table(without_defaults()).unwrap();
        let written = toml::Table::try_from(&recipe).unwrap();
        for key in RECIPE_REFERENCE {
            let value = lookup(&written, key.key);
            match key.when_absent {
                WhenAbsent::Absent(_) => assert!(value.is_none(), "{}", key.key),
                WhenAbsent::Required => assert!(value.is_some(), "{} is not a field", key.key),
                WhenAbsent::Value(default) => {
                    let documented: toml::Table = format!("v = {default}").parse().unwrap();
                    assert_eq!(value, documented.get("v"), "{}'s default", key.key);
                }
            }
        }
        assert!(
            unknown_keys(&written).is_empty(),
            "{:?}",
            unknown_keys(&written)
        );
    }

    #[test]
    fn a_value_is_refused_with_the_key_and_what_is_accepted() {
        let base = shipped("clutter.toml");
        let refused = |old: &str, new: &str| {
            assert!(base.contains(old), "{old}");
            Recipe::from_toml(&base.replacen(old, new, 1)).unwrap_err()
        };
        assert_eq!(
            refused("samples = ", "samples = 0 #"),
            "key 'render.samples' must be ≥ 1, got 0"
        );
        let wrong = refused("sensor_depth = false", "sensor_depth = 1");
        assert_eq!(wrong, "key 'render.sensor_depth' must be boolean, got 1");
        let choice = refused("kind = \"bin\"", "kind = \"table\"");
        assert!(
            choice.contains("'support.kind' must be \"floor\" or \"bin\" or \"pallet\""),
            "{choice}"
        );
        let range = refused("friction = [0.5, 0.9]", "friction = [0.9, 0.5]");
        assert!(range.contains("min above max"), "{range}");
        let missing = refused("seed = ", "# seed = ");
        assert_eq!(missing, "missing key 'seed'");
        let typo = refused("max_time_s", "max_tiem_s");
        assert!(
            typo.starts_with("unknown key 'settle.max_tiem_s'"),
            "{typo}"
        );
    }

    #[test]
    fn the_rules_between_keys_are_checked() {
        let mut table = without_defaults();
        table["support"]["kind"] = "bin".into();
        table["support"]["wall_height_m"] = 0.0.into();
        assert_eq!(
            check(&table).unwrap_err(),
            "a bin needs support.wall_height_m > 0"
        );
        let mut table = without_defaults();
        table["settle"]["max_time_s"] = 1e6.into();
        assert!(check(&table).unwrap_err().contains("more than 1e7"));
        let mut table = without_defaults();
        table["settle"]["window_s"] = 1e-4.into();
        assert!(
            check(&table)
                .unwrap_err()
                .contains("time_step_s < window_s")
        );
        let mut table = without_defaults();
        table["boxes"]["size_min_m"] = toml::Value::Array(vec![1.0.into(); 3]);
        assert!(check(&table).unwrap_err().contains("size_min_m must be ≤"));
    }

    /// The same bounds test the Python readers pass (tests/test_recipe_reference.py): at an
    /// inclusive bound accepted, at an exclusive one refused, one step past refused, one step
    /// inside accepted.
    #[test]
    fn documented_bounds_are_what_is_refused() {
        for key in RECIPE_REFERENCE {
            let Accepted::Within { min, max, and: "" } = key.accepted else {
                continue;
            };
            let integer = matches!(key.value_type, ValueType::Integer | ValueType::IntegerRange);
            let step = if integer { 1.0 } else { 1e-6 };
            let with = |v: f64| {
                let mut table = without_defaults();
                let item = if integer {
                    toml::Value::Integer(v as i64)
                } else {
                    v.into()
                };
                let value = match key.value_type {
                    ValueType::Integer | ValueType::Float => item,
                    ValueType::FloatXyz => toml::Value::Array(vec![item; 3]),
                    _ => toml::Value::Array(vec![item; 2]),
                };
                let (section, name) = key.key.split_once('.').unwrap_or(("", key.key));
                let holder = if section.is_empty() {
                    &mut table
                } else {
                    table[section].as_table_mut().unwrap()
                };
                holder.insert(name.into(), value);
                check(&table).is_err()
            };
            for (bound, outwards) in [(min, -1.0), (max, 1.0)] {
                let (value, inclusive) = match bound {
                    Bound::Unbounded => continue,
                    Bound::Inclusive(v) => (v, true),
                    Bound::Exclusive(v) => (v, false),
                };
                assert_eq!(with(value), !inclusive, "{} at {value}", key.key);
                assert!(with(value + outwards * step), "{} past {value}", key.key);
                assert!(!with(value - outwards * step), "{} inside {value}", key.key);
            }
        }
    }

    #[test]
    fn the_choices_default_as_documented_and_refuse_other_values_naming_the_key() {
        let base = shipped("clutter.toml");
        let read = |section: &str, line: &str| {
            let header = format!("[{section}]\n");
            assert!(base.contains(&header), "{header}");
            Recipe::from_toml(&base.replacen(&header, &format!("{header}{line}\n"), 1))
        };
        let recipe = Recipe::from_toml(&base).unwrap();
        assert_eq!(
            (
                recipe.settle.engine.as_str(),
                recipe.materials.tape_along.as_str()
            ),
            ("drake", "random")
        );
        assert_eq!(
            read("settle", "engine = 'mujoco'").unwrap().settle.engine,
            "mujoco"
        );
        assert_eq!(
            read("materials", "tape_along = 'long'")
                .unwrap()
                .materials
                .tape_along,
            "long"
        );
        for (section, key, accepted) in [
            ("settle", "engine", "\"drake\" or \"mujoco\""),
            ("materials", "tape_along", "\"long\" or \"random\""),
        ] {
            for bad in ["\"Long\"", "\"bullet\"", "1", "true", "[\"drake\"]"] {
                let problem = read(section, &format!("{key} = {bad}")).unwrap_err();
                assert_eq!(
                    problem,
                    format!("key '{section}.{key}' must be {accepted}, got {bad}")
                );
            }
        }
    }
}
