//! What a scene recipe (`datasets/recipes/*.toml`) may hold, written once: every key with its
//! type, accepted values, default, unit and meaning ([`RECIPE_REFERENCE`], printed as
//! docs/recipes.md by `boxpose schema --recipes-markdown`), the support kinds, and the bound on a
//! settle's length. Each language reads a recipe in one place, against this reference: in Rust
//! the typed [`Recipe`] (the search and `boxpose-physics`'s `RecipePhysics` take their fields
//! from it), in Python `boxpose_io.recipe`, which loads the reference from
//! `python/boxpose_io/schema.json` (its `"recipe"` object, generated from [`to_json`]) and from
//! which the Drake and Blender stages build their dataclasses. The schema's drift test fails when
//! that file disagrees with this module; `tests/test_recipe_reference.py` checks that the
//! documented bounds and defaults are the ones the Python stages apply (the same test runs here
//! on [`Recipe`]), and `tests/test_fuzz_inputs.py` that the Python and Rust readers accept and
//! refuse the same recipes.

mod model;
pub use model::{
    Boxes, Camera, Drop, Lighting, Materials, Recipe, Render, Settle, Support, check,
    check_sections,
};

/// The shape of a recipe value, as TOML writes it. Every float must be finite (a reader refuses
/// `inf` and `nan`), and an integer is accepted where a float is expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueType {
    String,
    Integer,
    Float,
    Boolean,
    /// `[min, max]`, inclusive, integers; a reader refuses min > max.
    IntegerRange,
    /// `[min, max]` floats, a value drawn uniformly between them; a reader refuses min > max.
    FloatRange,
    /// `[x, y]` floats: one value per axis, not a range.
    FloatXy,
    /// `[dx, dy, dz]` floats: one value per axis of a box.
    FloatXyz,
}

impl ValueType {
    /// How docs/recipes.md and schema.json name it.
    pub fn name(self) -> &'static str {
        match self {
            Self::String => "string",
            Self::Integer => "integer",
            Self::Float => "float",
            Self::Boolean => "boolean",
            Self::IntegerRange => "[min, max] integers",
            Self::FloatRange => "[min, max] floats",
            Self::FloatXy => "[x, y] floats",
            Self::FloatXyz => "[dx, dy, dz] floats",
        }
    }
}

/// One end of the interval a number must lie in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    Unbounded,
    Inclusive(f64),
    Exclusive(f64),
}

/// What a reader accepts for a key, beyond its type: for a list, every number of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Accepted {
    /// Numbers between `min` and `max`; `and` is a rule the two bounds cannot say (one that
    /// involves another key), empty when there is none.
    Within {
        min: Bound,
        max: Bound,
        and: &'static str,
    },
    /// One of these strings.
    OneOf(&'static [&'static str]),
    /// Whatever has the key's type: no reader checks more.
    NotChecked,
}

/// What a recipe without the key means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WhenAbsent {
    /// A reader refuses a recipe without it.
    Required,
    /// This value, as TOML writes it.
    Value(&'static str),
    /// Nothing is read; what happens instead.
    Absent(&'static str),
}

/// One recipe key, documented.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecipeKey {
    /// Dotted by section: `camera.width` is `width` under `[camera]`.
    pub key: &'static str,
    pub value_type: ValueType,
    pub accepted: Accepted,
    pub when_absent: WhenAbsent,
    /// Empty for a count, a ratio or a name.
    pub unit: &'static str,
    pub meaning: &'static str,
}

const fn key(
    key: &'static str,
    value_type: ValueType,
    accepted: Accepted,
    when_absent: WhenAbsent,
    unit: &'static str,
    meaning: &'static str,
) -> RecipeKey {
    RecipeKey {
        key,
        value_type,
        accepted,
        when_absent,
        unit,
        meaning,
    }
}

const fn within(min: Bound, max: Bound) -> Accepted {
    Accepted::Within { min, max, and: "" }
}

const POSITIVE: Accepted = within(Bound::Exclusive(0.0), Bound::Unbounded);
const NON_NEGATIVE: Accepted = within(Bound::Inclusive(0.0), Bound::Unbounded);
const AT_LEAST_ONE: Accepted = within(Bound::Inclusive(1.0), Bound::Unbounded);
const PROBABILITY: Accepted = within(Bound::Inclusive(0.0), Bound::Inclusive(1.0));

/// Every key a recipe may hold, in recipe order, with what its readers accept (the bounds are
/// the ones `python/drake_scenes/recipe.py`, `python/blender_scripts/recipe.py` and
/// `boxpose-physics` enforce, no more). `make schema` writes it to docs/recipes.md.
pub const RECIPE_REFERENCE: &[RecipeKey] = {
    use Accepted::NotChecked;
    use Bound::{Exclusive, Inclusive, Unbounded};
    use ValueType::*;
    use WhenAbsent::{Absent, Required, Value};
    &[
        // the recipe itself
        key(
            "name",
            String,
            NotChecked,
            Required,
            "",
            "the recipe's name, stored with every scene (`scenes.recipe`)",
        ),
        key(
            "description",
            String,
            NotChecked,
            Absent("no description"),
            "",
            "what the recipe is for, for people: no stage reads it",
        ),
        key(
            "seed",
            Integer,
            NotChecked,
            Required,
            "",
            "seeds the Drake stage's random draws: the same recipe and seed give the same scenes",
        ),
        key(
            "num_scenes",
            Integer,
            NON_NEGATIVE,
            Required,
            "",
            "scenes to generate, over all shards",
        ),
        // Drake: what is dropped, where, and when it counts as settled
        key(
            "boxes.count",
            IntegerRange,
            AT_LEAST_ONE,
            Required,
            "",
            "boxes per scene",
        ),
        key(
            "boxes.size_min_m",
            FloatXyz,
            Accepted::Within {
                min: Exclusive(0.0),
                max: Unbounded,
                and: "≤ `boxes.size_max_m` on every axis",
            },
            Required,
            "m",
            "the smallest edge lengths; each axis is drawn independently between this and `boxes.size_max_m`",
        ),
        key(
            "boxes.size_max_m",
            FloatXyz,
            Accepted::Within {
                min: Exclusive(0.0),
                max: Unbounded,
                and: "≥ `boxes.size_min_m` on every axis",
            },
            Required,
            "m",
            "the largest edge lengths",
        ),
        key(
            "boxes.density_kg_m3",
            FloatRange,
            POSITIVE,
            Required,
            "kg/m³",
            "a box's mass is its density times its volume (`objects.mass_kg`)",
        ),
        key(
            "boxes.friction",
            FloatRange,
            POSITIVE,
            Required,
            "",
            "a box's Coulomb friction coefficient (`objects.friction`)",
        ),
        key(
            "support.kind",
            String,
            Accepted::OneOf(&SUPPORT_KINDS),
            Required,
            "",
            "what the boxes are dropped on (`scenes.support`; docs/dataset.md, \"Supports\")",
        ),
        key(
            "support.half_extent_m",
            FloatXy,
            POSITIVE,
            Required,
            "m",
            "half the size of the support region the boxes are dropped over, along x and y",
        ),
        key(
            "support.wall_height_m",
            Float,
            Accepted::Within {
                min: Inclusive(0.0),
                max: Unbounded,
                and: "> 0 for a bin",
            },
            Required,
            "m",
            "the height of a bin's walls (0 for a floor or a pallet)",
        ),
        key(
            "drop.height_m",
            FloatRange,
            NON_NEGATIVE,
            Required,
            "m",
            "the gap between a box's lowest point and the support before the drop",
        ),
        key(
            "drop.min_separation_m",
            Float,
            POSITIVE,
            Required,
            "m",
            "the least distance between bodies that the projection before the drop enforces",
        ),
        key(
            "drop.max_solve_attempts",
            Integer,
            AT_LEAST_ONE,
            Required,
            "",
            "jittered retries of the projection before the scene is rejected",
        ),
        key(
            "settle.time_step_s",
            Float,
            Accepted::Within {
                min: Exclusive(0.0),
                max: Unbounded,
                and: "< `settle.window_s`",
            },
            Required,
            "s",
            "the simulation's time step",
        ),
        key(
            "settle.max_time_s",
            Float,
            Accepted::Within {
                min: Exclusive(0.0),
                max: Unbounded,
                and: "> `settle.window_s`, and at most 10⁷ time steps",
            },
            Required,
            "s",
            "a scene not at rest by then is rejected",
        ),
        key(
            "settle.window_s",
            Float,
            Accepted::Within {
                min: Exclusive(0.0),
                max: Unbounded,
                and: "between `settle.time_step_s` and `settle.max_time_s`",
            },
            Required,
            "s",
            "the speeds must stay under the thresholds over this much simulated time",
        ),
        key(
            "settle.max_linear_speed_mps",
            Float,
            POSITIVE,
            Required,
            "m/s",
            "at rest: every box slower than this",
        ),
        key(
            "settle.max_angular_speed_radps",
            Float,
            POSITIVE,
            Required,
            "rad/s",
            "at rest: every box turning slower than this",
        ),
        key(
            "settle.engine",
            String,
            Accepted::OneOf(&SETTLE_ENGINES),
            Value("\"drake\""),
            "",
            "the simulator that drops and settles the scenes (`scenes.physics_backend`): \"drake\" certifies them; \"mujoco\" settles ≈ 50× faster under the same stop rule and checks, for training data (docs/dataset.md, \"Recipes\")",
        ),
        key(
            "settle.max_penetration_m",
            Float,
            POSITIVE,
            Required,
            "m",
            "stable: no two bodies interpenetrate by more (the Blender stage's occlusion test tolerates it too)",
        ),
        // both: the boxes' surfaces
        key(
            "materials.roughness",
            FloatRange,
            NotChecked,
            Required,
            "",
            "the cardboard's roughness (`objects.roughness`)",
        ),
        key(
            "materials.tape_probability",
            Float,
            PROBABILITY,
            Required,
            "",
            "the chance that a box is taped (`objects.has_tape`)",
        ),
        key(
            "materials.label_probability",
            Float,
            PROBABILITY,
            Required,
            "",
            "the chance that a box carries a printed label (`objects.has_label`)",
        ),
        key(
            "materials.tape_along",
            String,
            Accepted::OneOf(&TAPE_ALONG),
            Value("\"random\""),
            "",
            "the side of a box's top face that the tape and the label's long axis follow: \"long\" as on a carton (the shipped keypoint network's unlabelled heatmap cannot read it; docs/dataset.md, \"Recipes\")",
        ),
        // Blender: cameras, lights, render settings
        key(
            "camera.frames_per_scene",
            Integer,
            AT_LEAST_ONE,
            Required,
            "",
            "camera views rendered of each scene",
        ),
        key(
            "camera.width",
            Integer,
            AT_LEAST_ONE,
            Required,
            "px",
            "image width",
        ),
        key(
            "camera.height",
            Integer,
            AT_LEAST_ONE,
            Required,
            "px",
            "image height",
        ),
        key(
            "camera.hfov_deg",
            FloatRange,
            within(Exclusive(0.0), Exclusive(180.0)),
            Required,
            "°",
            "horizontal field of view (square pixels, principal point at the centre)",
        ),
        key(
            "camera.distance_m",
            FloatRange,
            POSITIVE,
            Required,
            "m",
            "camera centre to the look-at point",
        ),
        key(
            "camera.elevation_deg",
            FloatRange,
            within(Exclusive(-90.0), Exclusive(90.0)),
            Required,
            "°",
            "the camera's elevation above the support plane, seen from the look-at point",
        ),
        key(
            "camera.azimuth_deg",
            FloatRange,
            NotChecked,
            Required,
            "°",
            "the camera's azimuth about world z",
        ),
        key(
            "camera.look_at_jitter_m",
            Float,
            NotChecked,
            Required,
            "m",
            "the look-at point moves uniformly by up to this much along each axis (≤ 0: not at all)",
        ),
        key(
            "camera.region",
            String,
            Accepted::OneOf(&CAMERA_REGIONS),
            Value("\"frame\""),
            "",
            "what a frame renders: \"frame\", the whole image; \"box\", only the square region around one box (frame f: the scene's boxes in object_id order, cyclically) at the image's own pixel density — the keypoint network's crop without the rest of the frame (docs/dataset.md, \"Recipes\")",
        ),
        key(
            "camera.region_margin",
            Float,
            within(Bound::Inclusive(1.0), Bound::Unbounded),
            Value("1.75"),
            "",
            "with `camera.region = \"box\"`: the region's side over the longer side of the box's projected bounding box (1.75 holds the keypoint loader's 1.25 crop, shifted and scaled by its augmentation)",
        ),
        key(
            "camera.look_at_object",
            Integer,
            NON_NEGATIVE,
            Absent("the camera aims at the boxes' centroid"),
            "",
            "the `object_id` of the box the camera aims at (the search's target box)",
        ),
        key(
            "lighting.sun_strength",
            FloatRange,
            NotChecked,
            Required,
            "W/m²",
            "the sun's strength (Blender's sun irradiance)",
        ),
        key(
            "lighting.sun_elevation_deg",
            FloatRange,
            within(Inclusive(-90.0), Inclusive(90.0)),
            Value("[30.0, 80.0]"),
            "°",
            "the elevation of the direction towards the sun",
        ),
        key(
            "lighting.sun_azimuth_deg",
            FloatRange,
            NotChecked,
            Value("[0.0, 360.0]"),
            "°",
            "the azimuth of the direction towards the sun, about world z",
        ),
        key(
            "lighting.area_lights",
            IntegerRange,
            NON_NEGATIVE,
            Required,
            "",
            "area lights per frame",
        ),
        key(
            "lighting.area_power_w",
            FloatRange,
            NotChecked,
            Required,
            "W",
            "each area light's power",
        ),
        key(
            "lighting.world_strength",
            FloatRange,
            NotChecked,
            Required,
            "",
            "the ambient world light's strength (Blender's background strength)",
        ),
        key(
            "lighting.world_color_jitter",
            Float,
            NotChecked,
            Required,
            "",
            "each channel of the world light's colour is 1 plus up to this much, uniformly (≤ 0: white)",
        ),
        key(
            "render.samples",
            Integer,
            AT_LEAST_ONE,
            Required,
            "",
            "Cycles samples per pixel",
        ),
        key(
            "render.denoise",
            Boolean,
            NotChecked,
            Required,
            "",
            "denoise the render (4 samples with it are clean on these diffuse scenes; docs/benchmarks.md)",
        ),
        key(
            "render.sensor_depth",
            Boolean,
            NotChecked,
            Required,
            "",
            "also render a simulated structured-light depth channel (`frames.sensor_depth_m_f32le`)",
        ),
        key(
            "render.max_bounces",
            Integer,
            NON_NEGATIVE,
            Value("4"),
            "",
            "Cycles light bounces (cardboard is diffuse: 4 is plenty)",
        ),
        key(
            "render.view_transform",
            String,
            NotChecked,
            Value("\"AgX\""),
            "",
            "Blender's colour-management view transform of the PNGs (Blender refuses an unknown one when rendering)",
        ),
        key(
            "render.exposure",
            Float,
            NotChecked,
            Value("-1.0"),
            "stops",
            "Blender's colour-management exposure",
        ),
    ]
};

/// Every key a recipe may hold, dotted by section ([`RECIPE_REFERENCE`]'s keys); a reader
/// refuses any other key.
pub const RECIPE_KEYS: &[&str] = &{
    let mut keys = [""; RECIPE_REFERENCE.len()];
    let mut i = 0;
    while i < keys.len() {
        keys[i] = RECIPE_REFERENCE[i].key;
        i += 1;
    }
    keys
};

/// The values of `support.kind` (and of the `scenes.support` column): see [`crate::support`].
pub const SUPPORT_KINDS: [&str; 3] = ["floor", "bin", "pallet"];

/// The values of `materials.tape_along`: which side of a box's top (+z) face its tape strip and
/// its label's long (u) axis follow. `"long"`: the longer side (x when dx ≥ dy), as on a regular
/// slotted carton, so the texture tells the two sides of a nearly square top apart (a network
/// whose output has corner identity could learn the quarter turn from it; the shipped one's
/// unlabelled heatmap cannot). `"random"`: either side at random (the default, and what
/// every dataset written before the key existed holds). Both draw the same random numbers, so only
/// those two choices differ. The Blender stage applies it (`blender_scripts.sampling`).
pub const TAPE_ALONG: [&str; 2] = ["long", "random"];

/// `materials.tape_along` when a recipe does not give it: the datasets (and the networks trained
/// on them) that predate the key must render as they did.
pub const TAPE_ALONG_DEFAULT: &str = "random";

/// The values of `camera.region`: `"frame"` renders each frame whole (the default, and every
/// dataset written before the key existed); `"box"` renders only the region around one box per
/// frame (the Blender stage's `crop_object`), so that keypoint-training data costs the pixels the
/// network reads rather than a whole 640×480 image per frame.
pub const CAMERA_REGIONS: [&str; 2] = ["frame", "box"];

/// `camera.region` when a recipe does not give it.
pub const CAMERA_REGION_DEFAULT: &str = "frame";

/// The values of `settle.engine` (and of the `scenes.physics_backend` column of the scenes they
/// settle): `"drake"`, the scene stage's certified simulation (the default, and what every
/// dataset written before the key existed used), or `"mujoco"` (`boxpose-physics`, the search's
/// simulator: the same drop, stop rule and stability checks, ≈ 50× less CPU per scene,
/// docs/benchmarks.md "Settling"), for training data where the scene stage's time matters more
/// than Drake's contact model.
pub const SETTLE_ENGINES: [&str; 2] = ["drake", "mujoco"];

/// `settle.engine` when a recipe does not give it.
pub const SETTLE_ENGINE_DEFAULT: &str = "drake";

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

impl Bound {
    fn to_json(self) -> serde_json::Value {
        match self {
            Self::Unbounded => serde_json::Value::Null,
            Self::Inclusive(v) => serde_json::json!({"value": v, "inclusive": true}),
            Self::Exclusive(v) => serde_json::json!({"value": v, "inclusive": false}),
        }
    }

    /// The number of a bounded end (NaN for an unbounded one, never printed).
    fn value(self) -> f64 {
        match self {
            Self::Inclusive(v) | Self::Exclusive(v) => v,
            Self::Unbounded => f64::NAN,
        }
    }
}

impl Accepted {
    /// As docs/recipes.md writes it: "[0, 1]", "> 0; > 0 for a bin", "\"long\" or \"random\"".
    fn to_markdown(self, value_type: ValueType) -> String {
        match self {
            Self::Within { min, max, and } => {
                let interval = match (min, max) {
                    (Bound::Unbounded, Bound::Unbounded) => String::new(),
                    (Bound::Inclusive(lo), Bound::Unbounded) => format!("≥ {lo}"),
                    (Bound::Exclusive(lo), Bound::Unbounded) => format!("> {lo}"),
                    (Bound::Unbounded, Bound::Inclusive(hi)) => format!("≤ {hi}"),
                    (Bound::Unbounded, Bound::Exclusive(hi)) => format!("< {hi}"),
                    (lo, hi) => {
                        let open = if matches!(lo, Bound::Inclusive(_)) {
                            '['
                        } else {
                            '('
                        };
                        let close = if matches!(hi, Bound::Inclusive(_)) {
                            ']'
                        } else {
                            ')'
                        };
                        format!("{open}{}, {}{close}", lo.value(), hi.value())
                    }
                };
                match (interval.is_empty(), and.is_empty()) {
                    (true, true) => "not checked".into(),
                    (false, true) => interval,
                    (true, false) => and.into(),
                    (false, false) => format!("{interval}; {and}"),
                }
            }
            Self::OneOf(values) => {
                let quoted: Vec<String> = values.iter().map(|v| format!("`\"{v}\"`")).collect();
                match quoted.split_last() {
                    Some((last, [])) => last.clone(),
                    Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
                    None => String::new(),
                }
            }
            Self::NotChecked if value_type == ValueType::Boolean => "`true` or `false`".into(),
            Self::NotChecked => "not checked".into(),
        }
    }

    /// As schema.json writes it; `text` is how a refusal says it ("must be ≥ 1").
    fn to_json(self, value_type: ValueType) -> serde_json::Value {
        match self {
            Self::Within { min, max, and } => serde_json::json!({
                "min": min.to_json(),
                "max": max.to_json(),
                "and": and,
                "text": self.to_markdown(value_type),
            }),
            Self::OneOf(values) => serde_json::json!({ "one_of": values }),
            Self::NotChecked => serde_json::Value::Null,
        }
    }
}

/// docs/recipes.md: [`RECIPE_REFERENCE`] as one table per recipe section.
pub fn to_markdown() -> String {
    let mut out = String::from(
        "# Recipe keys\n\n\
         <!-- Generated by `make schema` (`boxpose schema --recipes-markdown`) from \
         rust/data/src/recipe.rs: edit that file, not this one. -->\n\n\
         A recipe (`datasets/recipes/*.toml`) says how a dataset is made: `make scenes \
         RECIPE=name` reads `datasets/recipes/name.toml`, and every `scenes` row stores it verbatim \
         (`scenes.recipe_toml`). These are all the keys a recipe may hold; the Drake stage, the \
         Blender stage, `boxpose render` and `boxpose search` refuse any other key (`boxpose \
         schema` lists them too, under \"recipe\"), a value of another type, a float that is not \
         finite, and a `[min, max]` range whose min is above its max.\n\n\
         - **accepted**: what a reader refuses outside of; for a list, every number of it. \
         \"not checked\": no reader checks more than the type.\n\
         - **default**: what a recipe without the key means; \"required\": a reader refuses a recipe \
         without it (the Drake stage reads the top level, `[boxes]`, `[support]`, `[drop]`, \
         `[settle]` and `[materials]`; the Blender stage `[camera]`, `[lighting]`, `[materials]`, \
         `[render]`, `[support]`, `name` and `settle.max_penetration_m`).\n",
    );
    let mut section = None;
    for k in RECIPE_REFERENCE {
        let this_section = k.key.split_once('.').map(|(s, _)| s);
        if section != Some(this_section) {
            section = Some(this_section);
            out += &match this_section {
                Some(name) => format!("\n## `[{name}]`\n\n"),
                None => "\n## Top level\n\n".into(),
            };
            out +=
                "| key | type | accepted | default | unit | meaning |\n|---|---|---|---|---|---|\n";
        }
        let default = match k.when_absent {
            WhenAbsent::Required => "required".into(),
            WhenAbsent::Value(toml) => format!("`{toml}`"),
            WhenAbsent::Absent(what) => format!("none: {what}"),
        };
        let row = [
            format!("`{}`", k.key),
            k.value_type.name().into(),
            k.accepted.to_markdown(k.value_type),
            default,
            k.unit.into(),
            k.meaning.into(),
        ];
        let cells: Vec<String> = row.iter().map(|c| c.replace('|', "\\|")).collect();
        out += &format!("| {} |\n", cells.join(" | "));
    }
    out
}

/// The facts as the `"recipe"` object of `schema.json`.
pub fn to_json() -> serde_json::Value {
    let reference: Vec<serde_json::Value> = RECIPE_REFERENCE
        .iter()
        .map(|k| {
            serde_json::json!({
                "key": k.key,
                "type": k.value_type.name(),
                "accepted": k.accepted.to_json(k.value_type),
                "required": k.when_absent == WhenAbsent::Required,
                "default_toml": match k.when_absent {
                    WhenAbsent::Value(toml) => Some(toml),
                    _ => None,
                },
                "unit": k.unit,
                "meaning": k.meaning,
            })
        })
        .collect();
    serde_json::json!({
        "keys": RECIPE_KEYS,
        "reference": reference,
        "support_kinds": SUPPORT_KINDS,
        "tape_along": TAPE_ALONG,
        "tape_along_default": TAPE_ALONG_DEFAULT,
        "settle_engines": SETTLE_ENGINES,
        "settle_engine_default": SETTLE_ENGINE_DEFAULT,
        "camera_regions": CAMERA_REGIONS,
        "camera_region_default": CAMERA_REGION_DEFAULT,
        "max_settle_steps": MAX_SETTLE_STEPS,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/recipes.md is [`to_markdown`], verbatim: `make schema` writes it.
    #[test]
    fn recipes_doc_matches_this_module() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/recipes.md");
        let doc = std::fs::read_to_string(path).expect("read docs/recipes.md");
        assert!(
            doc == to_markdown(),
            "{path} is stale: regenerate it with `make schema`"
        );
    }

    /// Every key of every shipped recipe is documented: a reader refuses the others, so a shipped
    /// recipe with one would not even load.
    #[test]
    fn every_key_of_a_shipped_recipe_is_documented() {
        let folder = concat!(env!("CARGO_MANIFEST_DIR"), "/../../datasets/recipes");
        let mut recipes = 0;
        for entry in std::fs::read_dir(folder).expect("read datasets/recipes") {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let recipe: toml::Table =
                    toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
                assert_eq!(unknown_keys(&recipe), Vec::<String>::new(), "{path:?}");
                recipes += 1;
            }
        }
        assert!(recipes > 0, "no recipe in {folder}");
    }

    #[test]
    fn every_key_is_documented_once_with_its_unit_in_its_name() {
        let mut keys = RECIPE_KEYS.to_vec();
        keys.sort();
        keys.dedup();
        assert_eq!(
            keys.len(),
            RECIPE_REFERENCE.len(),
            "a key is documented twice"
        );
        for k in RECIPE_REFERENCE {
            assert!(!k.meaning.is_empty(), "{} has no meaning", k.key);
            // the keys name their unit (`_m`, `_deg`, ...): the documented unit must agree
            for (suffix, unit) in [("_m", "m"), ("_deg", "°"), ("_s", "s"), ("_w", "W")] {
                if k.key.ends_with(suffix) {
                    assert_eq!(k.unit, unit, "{}", k.key);
                }
            }
        }
    }

    #[test]
    fn accepted_values_read_as_intervals() {
        let text = |a: Accepted| a.to_markdown(ValueType::Float);
        assert_eq!(text(PROBABILITY), "[0, 1]");
        assert_eq!(text(POSITIVE), "> 0");
        assert_eq!(
            text(within(Bound::Exclusive(-90.0), Bound::Exclusive(90.0))),
            "(-90, 90)"
        );
        assert_eq!(text(Accepted::NotChecked), "not checked");
        assert_eq!(
            Accepted::NotChecked.to_markdown(ValueType::Boolean),
            "`true` or `false`"
        );
        assert_eq!(
            text(Accepted::OneOf(&SUPPORT_KINDS)),
            "`\"floor\"`, `\"bin\"` or `\"pallet\"`"
        );
    }

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
