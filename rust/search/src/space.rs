//! The search space: a base scene recipe plus named, bounded parameters with their nominal
//! distribution p(x), read from a TOML file (`configs/search/*.toml`, documented in
//! `docs/search.md`).
//!
//! Every sampled input is written as a deterministic function of a fixed-length vector
//! z ∈ ℝᵈ of standard normals: a bounded parameter x = F⁻¹(Φ(z)) through its nominal CDF F, an
//! orientation as the unit quaternion z/‖z‖ of four of them (uniform on SO(3)). The nominal
//! density is then exactly N(0, I) in z, whatever the parameters' own distributions, so the
//! samplers (Monte Carlo, cross-entropy) work on z alone and any sample replays from its z.
//! The number of neighbouring boxes is discrete: it is a stratum, drawn from its nominal
//! (uniform over the inclusive range), never tilted.

use std::collections::BTreeMap;
use std::path::Path;

use boxpose_data::{Object, Pose};
use boxpose_search_stats::stats::{normal_cdf as standard_normal_cdf, normal_quantile};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SearchError};

/// `{ normal = [mean, std], within = [min, max] }`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruncatedNormal {
    pub normal: [f64; 2],
    pub within: [f64; 2],
}

/// A bounded scalar parameter and its nominal distribution.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(
    untagged,
    expecting = "[min, max] (uniform) or { normal = [mean, std], within = [min, max] } (a truncated normal), numbers"
)]
pub enum Distribution {
    /// `[min, max]`: uniform.
    Uniform([f64; 2]),
    /// `{ normal = [mean, std], within = [min, max] }`: a normal truncated to [min, max].
    TruncatedNormal(TruncatedNormal),
}

impl Distribution {
    /// The parameter value of the standard normal `z`: F⁻¹(Φ(z)).
    pub fn value(&self, z: f64) -> f64 {
        let u = standard_normal_cdf(z);
        match *self {
            Distribution::Uniform([lo, hi]) => lo + (hi - lo) * u,
            Distribution::TruncatedNormal(TruncatedNormal {
                normal: [mean, std],
                within: [lo, hi],
            }) => {
                let (a, b) = (
                    standard_normal_cdf((lo - mean) / std),
                    standard_normal_cdf((hi - mean) / std),
                );
                (mean + std * standard_normal_quantile(a + u * (b - a))).clamp(lo, hi)
            }
        }
    }

    /// The interval its values lie in: the uniform's range or the normal's truncation.
    pub fn range(&self) -> [f64; 2] {
        match *self {
            Distribution::Uniform(range) => range,
            Distribution::TruncatedNormal(TruncatedNormal { within, .. }) => within,
        }
    }

    /// Checks that the distribution is proper: finite bounds, a non-empty range, a positive
    /// standard deviation and a truncation interval with positive mass.
    fn validate(&self, key: &str) -> Result<()> {
        let bad = |problem: String| {
            Err(SearchError::Space {
                key: key.to_string(),
                problem,
            })
        };
        let [lo, hi] = self.range();
        if !(lo.is_finite() && hi.is_finite()) {
            return bad(format!("range [{lo}, {hi}] must be finite"));
        }
        if lo > hi {
            return bad(format!("range [{lo}, {hi}] is empty (min > max)"));
        }
        if let Distribution::TruncatedNormal(TruncatedNormal {
            normal: [mean, std],
            within: [lo, hi],
        }) = *self
        {
            if !(mean.is_finite() && std.is_finite() && std > 0.0) {
                return bad(format!(
                    "normal = [{mean}, {std}] needs a finite mean and a finite positive std"
                ));
            }
            let mass =
                standard_normal_cdf((hi - mean) / std) - standard_normal_cdf((lo - mean) / std);
            if !(mass > 1e-12) {
                return bad(format!(
                    "normal = [{mean}, {std}] has no mass within [{lo}, {hi}]: it cannot be normalised"
                ));
            }
        }
        Ok(())
    }
}

/// Φ⁻¹(u), the standard normal quantile, with u kept inside (0, 1) so that a truncated draw at
/// its range's edge stays finite.
fn standard_normal_quantile(u: f64) -> f64 {
    normal_quantile(u.clamp(1e-300, 1.0 - 1e-16))
}

/// A per-axis box size: each edge drawn independently.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SizeSpec {
    pub x: Distribution,
    pub y: Distribution,
    pub z: Distribution,
}

/// How the target box starts before it is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Orientation {
    /// Uniform on SO(3) (four standard normals, normalised): it lands on any face.
    So3,
    /// Resting on its −z face, turned about the vertical by `[target] yaw_deg`.
    Yaw,
}

/// `[target]`: the box whose pose the pipeline must recover.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    pub size_m: SizeSpec,
    pub orientation: Orientation,
    /// With `orientation = "yaw"`: the turn about the vertical, degrees.
    pub yaw_deg: Option<Distribution>,
    /// Centre over the support, metres (x, y).
    pub x_m: Distribution,
    pub y_m: Distribution,
    /// Gap between the box's lowest point and the support before the drop, metres.
    pub drop_height_m: Distribution,
}

/// `[neighbours]`: other boxes dropped around the target (clutter).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeighbourSpec {
    /// Inclusive range of the number of neighbours: each count is a stratum of equal nominal
    /// probability.
    #[serde(deserialize_with = "neighbour_counts")]
    pub count: [u32; 2],
    pub size_m: SizeSpec,
    pub yaw_deg: Distribution,
    pub x_m: Distribution,
    pub y_m: Distribution,
}

/// `[min, max]` whole numbers of neighbours, said so when a count is negative or fractional
/// (serde would say "expected u32").
fn neighbour_counts<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[u32; 2], D::Error> {
    let [lo, hi] = <[f64; 2]>::deserialize(d)?;
    let whole =
        |c: f64| (c >= 0.0 && c.fract() == 0.0 && c <= f64::from(u32::MAX)).then_some(c as u32);
    match (whole(lo), whole(hi)) {
        (Some(lo), Some(hi)) => Ok([lo, hi]),
        _ => Err(serde::de::Error::custom(format!(
            "neighbours.count = [{lo}, {hi}]: counts are whole numbers from 0, [min, max]"
        ))),
    }
}

/// `[pile]`: the target is dropped onto a settled pile stored in a dataset (one scene's boxes at
/// their settled poses) instead of with neighbours. The pile's boxes start asleep and only what
/// the drop touches moves (`boxpose_physics::resettle`): a sample costs the drop, not the pile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PileSpec {
    /// Dataset folder holding the pile's `scenes` and `objects` rows.
    pub dataset: String,
    pub scene_id: i64,
}

/// One box of a stored pile at its settled pose: its `objects` row without the ids. A run keeps
/// them in `run.json`, so that resuming or replaying it never reads the dataset again, and a
/// dataset that changed under a run cannot change what the run searched.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PileBox {
    pub size_m: [f64; 3],
    pub quat_wxyz: [f64; 4],
    pub translation_m: [f64; 3],
    pub mass_kg: f64,
    pub friction: f64,
    pub base_color_rgb: [f32; 3],
    pub roughness: f32,
    pub texture_seed: i64,
    pub has_tape: bool,
    pub has_label: bool,
}

impl PileBox {
    fn from_object(object: &Object) -> Self {
        Self {
            size_m: object.size,
            quat_wxyz: object.world_box.quat_wxyz,
            translation_m: object.world_box.translation,
            mass_kg: object.mass_kg,
            friction: object.friction,
            base_color_rgb: object.base_color_rgb,
            roughness: object.roughness,
            texture_seed: object.texture_seed,
            has_tape: object.has_tape,
            has_label: object.has_label,
        }
    }

    /// The box as an `objects` row of another scene, at rest where the pile left it.
    pub fn object(&self, scene_id: i64, object_id: i32) -> Object {
        let pose = Pose {
            quat_wxyz: self.quat_wxyz,
            translation: self.translation_m,
        };
        Object {
            scene_id,
            object_id,
            size: self.size_m,
            world_box: pose,
            initial_world_box: pose,
            mass_kg: self.mass_kg,
            friction: self.friction,
            base_color_rgb: self.base_color_rgb,
            roughness: self.roughness,
            texture_seed: self.texture_seed,
            has_tape: self.has_tape,
            has_label: self.has_label,
        }
    }
}

/// Reads the pile of `spec` from its dataset: a scene certified settled, on the same support as
/// the space's recipe (`recipe_toml`).
pub fn load_pile(spec: &PileSpec, recipe_toml: &str) -> Result<Vec<PileBox>> {
    let bad = |problem: String| SearchError::Space {
        key: "pile".into(),
        problem: format!("{} scene {}: {problem}", spec.dataset, spec.scene_id),
    };
    let dataset = boxpose_data::Dataset::open(&spec.dataset)?;
    let scene = dataset
        .scenes()?
        .into_iter()
        .find(|s| s.scene_id == spec.scene_id)
        .ok_or_else(|| bad("no such scene in the dataset".into()))?;
    if !scene.stable {
        return Err(bad(
            "not certified settled (stable = false); choose a settled pile".into(),
        ));
    }
    let support = |toml: &str| boxpose_physics::RecipePhysics::from_toml(toml).map(|p| p.support);
    let (own, wanted) = (support(&scene.recipe_toml)?, support(recipe_toml)?);
    if own != wanted {
        return Err(bad(format!(
            "it was settled on another support ({own:?}) than the space's recipe has ({wanted:?})"
        )));
    }
    let mut objects: Vec<Object> = dataset
        .objects()?
        .into_iter()
        .filter(|o| o.scene_id == spec.scene_id)
        .collect();
    objects.sort_by_key(|o| o.object_id);
    if objects.is_empty() {
        return Err(bad("the scene has no objects rows".into()));
    }
    Ok(objects.iter().map(PileBox::from_object).collect())
}

/// `[camera]`: the view, relative to the target box (the camera looks at its settled centre).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub distance_m: Distribution,
    pub elevation_deg: Distribution,
    pub azimuth_deg: Distribution,
    pub hfov_deg: Distribution,
}

/// `[lighting]`: the sun's direction and strength, the ambient world's strength.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightingSpec {
    pub sun_elevation_deg: Distribution,
    pub sun_azimuth_deg: Distribution,
    pub sun_strength: Distribution,
    pub world_strength: Distribution,
}

/// A search space file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpaceFile {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// The base scene recipe (a name in `datasets/recipes/` or a path): support, settling,
    /// image size, materials, render settings.
    pub recipe: String,
    pub target: TargetSpec,
    pub neighbours: Option<NeighbourSpec>,
    pub pile: Option<PileSpec>,
    pub camera: CameraSpec,
    pub lighting: LightingSpec,
}

/// One dimension of z: which parameter it drives.
#[derive(Debug, Clone, PartialEq)]
pub struct Dimension {
    pub name: String,
    /// `None` for the four components of an orientation (normalised together).
    pub distribution: Option<Distribution>,
}

/// A validated search space: the file, its base recipe's text, and the layout of z.
#[derive(Debug, Clone)]
pub struct SearchSpace {
    pub file: SpaceFile,
    /// The file's own text (stored in the run folder, so a run knows what it searched).
    pub text: String,
    /// The base recipe's TOML text.
    pub recipe_toml: String,
    /// The base recipe, read and checked once when the space is loaded.
    pub recipe: boxpose_data::recipe::Recipe,
    /// Its `[support]` and `[settle]`, as the simulator takes them.
    pub physics: boxpose_physics::RecipePhysics,
    pub dimensions: Vec<Dimension>,
    /// With `[pile]`: its boxes, read from the dataset when the space was loaded.
    pub pile: Option<Vec<PileBox>>,
}

/// Sampled scene inputs, typed: what the scene builder reads. Made only by
/// [`SearchSpace::parameters`], which takes each value from the dimension of its name, so a name
/// that does not match is one error there (and at load time, which builds a sample once), never a
/// panic in the scene builder.
#[derive(Debug, Clone, PartialEq)]
pub struct Parameters {
    /// Number of neighbouring boxes (the stratum).
    pub neighbours: u32,
    /// Every scalar dimension's value by name, as the run's tables record them.
    pub values: BTreeMap<String, f64>,
    /// The target's drop orientation (unit quaternion w, x, y, z).
    pub target_quat_wxyz: [f64; 4],
    pub target: TargetParameters,
    /// One per neighbour, in drop order.
    pub neighbour_boxes: Vec<NeighbourParameters>,
    pub camera: CameraParameters,
    pub lighting: LightingParameters,
}

/// The target box: its size, where it is dropped on the support and from how high.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetParameters {
    pub size_m: [f64; 3],
    pub x_m: f64,
    pub y_m: f64,
    pub drop_height_m: f64,
}

/// A neighbouring box: its size, place and yaw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeighbourParameters {
    pub size_m: [f64; 3],
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_deg: f64,
}

/// The camera, as the recipe's `[camera]` keys pin it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraParameters {
    pub distance_m: f64,
    pub elevation_deg: f64,
    pub azimuth_deg: f64,
    pub hfov_deg: f64,
}

/// The light, as the recipe's `[lighting]` keys pin it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightingParameters {
    pub sun_elevation_deg: f64,
    pub sun_azimuth_deg: f64,
    pub sun_strength: f64,
    pub world_strength: f64,
}

impl CameraParameters {
    /// (recipe key, value) of each.
    pub fn recipe_keys(&self) -> [(&'static str, f64); 4] {
        [
            ("distance_m", self.distance_m),
            ("elevation_deg", self.elevation_deg),
            ("azimuth_deg", self.azimuth_deg),
            ("hfov_deg", self.hfov_deg),
        ]
    }
}

impl LightingParameters {
    /// (recipe key, value) of each.
    pub fn recipe_keys(&self) -> [(&'static str, f64); 4] {
        [
            ("sun_elevation_deg", self.sun_elevation_deg),
            ("sun_azimuth_deg", self.sun_azimuth_deg),
            ("sun_strength", self.sun_strength),
            ("world_strength", self.world_strength),
        ]
    }
}

/// The value of the dimension `name`; an error naming it when the space has none.
fn value_of(values: &BTreeMap<String, f64>, name: &str) -> Result<f64> {
    values.get(name).copied().ok_or_else(|| {
        SearchError::Sample(format!(
            "the search space has no parameter `{name}` (it has {})",
            values.keys().cloned().collect::<Vec<_>>().join(", ")
        ))
    })
}

impl Parameters {
    /// The typed parameters of the scalar `values` in stratum `neighbours`.
    fn typed(
        values: BTreeMap<String, f64>,
        neighbours: u32,
        target_quat_wxyz: [f64; 4],
    ) -> Result<Self> {
        let v = |name: &str| value_of(&values, name);
        let size = |prefix: &str| -> Result<[f64; 3]> {
            Ok([
                v(&format!("{prefix}.size_m.x"))?,
                v(&format!("{prefix}.size_m.y"))?,
                v(&format!("{prefix}.size_m.z"))?,
            ])
        };
        let target = TargetParameters {
            size_m: size("target")?,
            x_m: v("target.x_m")?,
            y_m: v("target.y_m")?,
            drop_height_m: v("target.drop_height_m")?,
        };
        let neighbour_boxes = (0..neighbours)
            .map(|i| {
                let prefix = format!("neighbour{i}");
                Ok(NeighbourParameters {
                    size_m: size(&prefix)?,
                    x_m: v(&format!("{prefix}.x_m"))?,
                    y_m: v(&format!("{prefix}.y_m"))?,
                    yaw_deg: v(&format!("{prefix}.yaw_deg"))?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let camera = CameraParameters {
            distance_m: v("camera.distance_m")?,
            elevation_deg: v("camera.elevation_deg")?,
            azimuth_deg: v("camera.azimuth_deg")?,
            hfov_deg: v("camera.hfov_deg")?,
        };
        let lighting = LightingParameters {
            sun_elevation_deg: v("lighting.sun_elevation_deg")?,
            sun_azimuth_deg: v("lighting.sun_azimuth_deg")?,
            sun_strength: v("lighting.sun_strength")?,
            world_strength: v("lighting.world_strength")?,
        };
        Ok(Self {
            neighbours,
            values,
            target_quat_wxyz,
            target,
            neighbour_boxes,
            camera,
            lighting,
        })
    }
}

/// Refuses a position range (`x_m`, `y_m` of the target and the neighbours) that reaches beyond
/// the base recipe's support region: such draws are clamped to the region's edge when the scene is
/// built, so the parameter recorded for a sample would not be the position used.
fn check_positions_on_the_support(file: &SpaceFile, recipe_toml: &str) -> Result<()> {
    let Ok(physics) = boxpose_physics::RecipePhysics::from_toml(recipe_toml) else {
        // the recipe's own errors are reported where it is read in full
        return Ok(());
    };
    let [hx, hy] = physics.support.half_extent_m;
    let mut ranges = vec![
        ("target.x_m", file.target.x_m, hx),
        ("target.y_m", file.target.y_m, hy),
    ];
    if let Some(n) = &file.neighbours {
        ranges.push(("neighbours.x_m", n.x_m, hx));
        ranges.push(("neighbours.y_m", n.y_m, hy));
    }
    for (key, distribution, half) in ranges {
        let [lo, hi] = distribution.range();
        if lo < -half || hi > half {
            return Err(SearchError::Space {
                key: key.to_string(),
                problem: format!(
                    "[{lo}, {hi}] reaches beyond the recipe's support, which spans [{}, {half}] m \
                     along this axis: a box would be clamped to its edge and the recorded \
                     parameter would not be the position used; keep the range within it",
                    -half
                ),
            });
        }
    }
    Ok(())
}

/// "; the known WHAT: a, b, c" — the `*.toml` names in `dir`, for an error about a name that is
/// not one of them; empty when `dir` cannot be listed.
fn known_names(dir: &Path, what: &str) -> String {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return String::new();
    };
    let mut names: Vec<String> = entries
        .filter_map(|entry| {
            let path = entry.ok()?.path();
            let stem = path.file_stem()?.to_string_lossy().into_owned();
            (path.extension()? == "toml").then_some(stem)
        })
        .collect();
    names.sort();
    if names.is_empty() {
        String::new()
    } else {
        format!(
            "; the known {what} in {}: {}",
            dir.display(),
            names.join(", ")
        )
    }
}

impl SearchSpace {
    /// Reads and validates a search space: a TOML path, or a name in `configs/search/`.
    pub fn load(name_or_path: &str, recipes_dir: &Path) -> Result<Self> {
        let path = Path::new(name_or_path);
        let path = if path.is_file() {
            path.to_path_buf()
        } else {
            boxpose_data::shipped::resolve(
                &Path::new("configs/search").join(format!("{name_or_path}.toml")),
            )
        };
        let text = std::fs::read_to_string(&path).map_err(|e| SearchError::Io {
            path: path.clone(),
            message: format!(
                "{e}{}",
                known_names(
                    &boxpose_data::shipped::resolve(Path::new("configs/search")),
                    "search spaces"
                )
            ),
        })?;
        Self::parse(&text, &path.display().to_string(), recipes_dir)
    }

    /// Parses a search space's TOML text; `source` names it in errors.
    pub fn parse(text: &str, source: &str, recipes_dir: &Path) -> Result<Self> {
        let file: SpaceFile = toml::from_str(text).map_err(|e| SearchError::Space {
            key: source.to_string(),
            problem: e.to_string(),
        })?;
        let recipe_path = {
            let p = Path::new(&file.recipe);
            if p.is_file() {
                p.to_path_buf()
            } else {
                recipes_dir.join(format!("{}.toml", file.recipe))
            }
        };
        let recipe_toml =
            std::fs::read_to_string(&recipe_path).map_err(|e| SearchError::Space {
                key: "recipe".into(),
                problem: format!(
                    "{}: {e}{}",
                    recipe_path.display(),
                    known_names(recipes_dir, "recipes")
                ),
            })?;
        check_positions_on_the_support(&file, &recipe_toml)?;
        // with [neighbours] beside it, from_parts refuses the space before any dataset is read
        let pile = match (&file.pile, &file.neighbours) {
            (Some(spec), None) => Some(load_pile(spec, &recipe_toml)?),
            _ => None,
        };
        Self::from_parts(file, text.to_string(), recipe_toml, pile).map_err(|e| match e {
            SearchError::Space { key, problem } => SearchError::Space {
                key: format!("{source}: {key}"),
                problem,
            },
            other => other,
        })
    }

    /// The space a run searched, from what its `run.json` stores (no file is read).
    pub fn from_texts(
        space_toml: &str,
        recipe_toml: &str,
        pile: Option<Vec<PileBox>>,
    ) -> Result<Self> {
        let file: SpaceFile = toml::from_str(space_toml).map_err(|e| SearchError::Space {
            key: "run.json space_toml".into(),
            problem: e.to_string(),
        })?;
        Self::from_parts(file, space_toml.to_string(), recipe_toml.to_string(), pile)
    }

    /// Validates a parsed file against its base recipe (and its pile's boxes, for a `[pile]`)
    /// and lays out z.
    pub fn from_parts(
        file: SpaceFile,
        text: String,
        recipe_toml: String,
        pile: Option<Vec<PileBox>>,
    ) -> Result<Self> {
        match (&file.pile, &pile, &file.neighbours) {
            (Some(_), _, Some(_)) => {
                return Err(SearchError::Space {
                    key: "pile".into(),
                    problem:
                        "a space drops the target with [neighbours] or onto a [pile], not both"
                            .into(),
                });
            }
            (Some(_), None, _) | (None, Some(_), _) => {
                return Err(SearchError::Space {
                    key: "pile".into(),
                    problem: "the pile's boxes must come with the [pile] section (a run.json \
                              written without them cannot replay a pile space)"
                        .into(),
                });
            }
            (Some(_), Some(boxes), _) if boxes.is_empty() => {
                return Err(SearchError::Space {
                    key: "pile".into(),
                    problem: "the pile has no boxes".into(),
                });
            }
            _ => {}
        }
        let refused = |problem: String| SearchError::Space {
            key: "recipe".into(),
            problem: format!("{}: {problem}", file.recipe),
        };
        let recipe = boxpose_data::recipe::Recipe::from_toml(&recipe_toml).map_err(refused)?;
        let physics = boxpose_physics::RecipePhysics::from_recipe(&recipe)
            .map_err(|e| refused(e.to_string()))?;
        let mut dimensions = Vec::new();
        let mut scalar = |name: &str, d: &Distribution| -> Result<()> {
            d.validate(name)?;
            dimensions.push(Dimension {
                name: name.to_string(),
                distribution: Some(*d),
            });
            Ok(())
        };
        let t = &file.target;
        for (axis, d) in ["x", "y", "z"]
            .iter()
            .zip([&t.size_m.x, &t.size_m.y, &t.size_m.z])
        {
            scalar(&format!("target.size_m.{axis}"), d)?;
            let [lo, _] = bounds(d);
            if lo <= 0.0 {
                return Err(SearchError::Space {
                    key: format!("target.size_m.{axis}"),
                    problem: "box sizes must be positive".into(),
                });
            }
        }
        match (t.orientation, &t.yaw_deg) {
            (Orientation::Yaw, Some(d)) => scalar("target.yaw_deg", d)?,
            (Orientation::Yaw, None) => {
                return Err(SearchError::Space {
                    key: "target.yaw_deg".into(),
                    problem: "orientation = \"yaw\" needs yaw_deg".into(),
                });
            }
            (Orientation::So3, Some(_)) => {
                return Err(SearchError::Space {
                    key: "target.yaw_deg".into(),
                    problem: "only used with orientation = \"yaw\"".into(),
                });
            }
            (Orientation::So3, None) => {}
        }
        scalar("target.x_m", &t.x_m)?;
        scalar("target.y_m", &t.y_m)?;
        scalar("target.drop_height_m", &t.drop_height_m)?;
        if bounds(&t.drop_height_m)[0] < 0.0 {
            return Err(SearchError::Space {
                key: "target.drop_height_m".into(),
                problem: "must be non-negative".into(),
            });
        }
        let c = &file.camera;
        scalar("camera.distance_m", &c.distance_m)?;
        scalar("camera.elevation_deg", &c.elevation_deg)?;
        scalar("camera.azimuth_deg", &c.azimuth_deg)?;
        scalar("camera.hfov_deg", &c.hfov_deg)?;
        let (d, e, h) = (
            bounds(&c.distance_m),
            bounds(&c.elevation_deg),
            bounds(&c.hfov_deg),
        );
        if d[0] <= 0.0 {
            return Err(SearchError::Space {
                key: "camera.distance_m".into(),
                problem: "must be positive".into(),
            });
        }
        if !(e[0] > -90.0 && e[1] < 90.0) {
            return Err(SearchError::Space {
                key: "camera.elevation_deg".into(),
                problem: "must lie in (-90, 90)".into(),
            });
        }
        if !(h[0] > 0.0 && h[1] < 180.0) {
            return Err(SearchError::Space {
                key: "camera.hfov_deg".into(),
                problem: "must lie in (0, 180)".into(),
            });
        }
        let l = &file.lighting;
        scalar("lighting.sun_elevation_deg", &l.sun_elevation_deg)?;
        scalar("lighting.sun_azimuth_deg", &l.sun_azimuth_deg)?;
        scalar("lighting.sun_strength", &l.sun_strength)?;
        scalar("lighting.world_strength", &l.world_strength)?;
        if !(bounds(&l.sun_elevation_deg)[0] >= -90.0 && bounds(&l.sun_elevation_deg)[1] <= 90.0) {
            return Err(SearchError::Space {
                key: "lighting.sun_elevation_deg".into(),
                problem: "must lie in [-90, 90]".into(),
            });
        }
        for (key, d) in [
            ("lighting.sun_strength", &l.sun_strength),
            ("lighting.world_strength", &l.world_strength),
        ] {
            if bounds(d)[0] < 0.0 {
                return Err(SearchError::Space {
                    key: key.into(),
                    problem: "must be non-negative".into(),
                });
            }
        }
        if let Some(n) = &file.neighbours {
            let [lo, hi] = n.count;
            if lo > hi {
                return Err(SearchError::Space {
                    key: "neighbours.count".into(),
                    problem: format!("range [{lo}, {hi}] is empty (min > max)"),
                });
            }
            if hi > MAX_NEIGHBOURS {
                return Err(SearchError::Space {
                    key: "neighbours.count".into(),
                    problem: format!("at most {MAX_NEIGHBOURS} neighbours"),
                });
            }
            // checked once under their TOML keys, then laid out once per possible neighbour
            let per_box = [
                ("size_m.x", &n.size_m.x),
                ("size_m.y", &n.size_m.y),
                ("size_m.z", &n.size_m.z),
                ("yaw_deg", &n.yaw_deg),
                ("x_m", &n.x_m),
                ("y_m", &n.y_m),
            ];
            for (key, d) in per_box {
                d.validate(&format!("neighbours.{key}"))?;
                if key.starts_with("size_m") && bounds(d)[0] <= 0.0 {
                    return Err(SearchError::Space {
                        key: format!("neighbours.{key}"),
                        problem: "box sizes must be positive".into(),
                    });
                }
            }
            for i in 0..hi {
                for (key, d) in per_box {
                    scalar(&format!("neighbour{i}.{key}"), d)?;
                }
            }
        }
        if t.orientation == Orientation::So3 {
            for k in 0..4 {
                dimensions.push(Dimension {
                    name: format!("target.orientation.q{k}"),
                    distribution: None,
                });
            }
        }
        let space = Self {
            file,
            text,
            recipe_toml,
            recipe,
            physics,
            dimensions,
            pile,
        };
        // every name the scene builder reads resolves: one sample of the largest stratum, built
        // once here, so a mismatch is a load error and never a failure mid-run
        let largest = space.strata().into_iter().max().unwrap_or(0);
        space.parameters(&vec![0.5; space.dim()], largest)?;
        Ok(space)
    }

    /// Length of z.
    pub fn dim(&self) -> usize {
        self.dimensions.len()
    }

    /// The strata: every neighbour count, each with nominal probability 1 / (number of counts).
    pub fn strata(&self) -> Vec<u32> {
        match &self.file.neighbours {
            Some(n) => (n.count[0]..=n.count[1]).collect(),
            None => vec![0],
        }
    }

    /// The scene inputs of z in stratum `neighbours`.
    pub fn parameters(&self, z: &[f64], neighbours: u32) -> Result<Parameters> {
        if z.len() != self.dim() || !z.iter().all(|v| v.is_finite()) {
            return Err(SearchError::Sample(format!(
                "z must hold {} finite values, got {:?}",
                self.dim(),
                z
            )));
        }
        let mut values = BTreeMap::new();
        let mut quat = [0.0; 4];
        for (dimension, &zi) in self.dimensions.iter().zip(z) {
            match &dimension.distribution {
                Some(d) => {
                    values.insert(dimension.name.clone(), d.value(zi));
                }
                None => {
                    let k = dimension.name.as_bytes()[dimension.name.len() - 1] - b'0';
                    quat[k as usize] = zi;
                }
            }
        }
        let target_quat_wxyz = match self.file.target.orientation {
            Orientation::So3 => {
                let norm = quat.iter().map(|v| v * v).sum::<f64>().sqrt();
                if norm < 1e-12 {
                    return Err(SearchError::Sample(
                        "the orientation's four normals are all zero".into(),
                    ));
                }
                let sign = if quat[0] < 0.0 { -1.0 } else { 1.0 };
                quat.map(|v| sign * v / norm)
            }
            Orientation::Yaw => {
                let half = value_of(&values, "target.yaw_deg")?.to_radians() / 2.0;
                [half.cos(), 0.0, 0.0, half.sin()]
            }
        };
        Parameters::typed(values, neighbours, target_quat_wxyz)
    }
}

/// Neighbour counts above this are refused (each adds six dimensions and a box to settle).
pub const MAX_NEIGHBOURS: u32 = 24;

fn bounds(d: &Distribution) -> [f64; 2] {
    match *d {
        Distribution::Uniform(r) => r,
        Distribution::TruncatedNormal(TruncatedNormal { within, .. }) => within,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RECIPE: &str = include_str!("../../../datasets/recipes/single_box.toml");
    const SINGLE: &str = include_str!("../../../configs/search/single_box.toml");
    const CLUTTER: &str = include_str!("../../../configs/search/clutter.toml");

    fn parse(text: &str) -> Result<SearchSpace> {
        let file: SpaceFile = toml::from_str(text).map_err(|e| SearchError::Space {
            key: "<test>".into(),
            problem: e.to_string(),
        })?;
        SearchSpace::from_parts(file, text.into(), RECIPE.into(), None)
    }

    fn error_of(text: &str) -> String {
        parse(text).expect_err("must be refused").to_string()
    }

    #[test]
    fn shipped_spaces_parse() {
        let single = parse(SINGLE).unwrap();
        assert_eq!(single.strata(), vec![0]);
        assert_eq!(single.dim(), 3 + 2 + 1 + 4 + 4 + 4);
        let clutter = parse(CLUTTER).unwrap();
        assert!(clutter.strata().len() > 1);
    }

    #[test]
    fn bad_spaces_name_the_key() {
        assert!(error_of(&SINGLE.replace("[camera]", "[camera]\nzoom = 2")).contains("zoom"));
        let empty = SINGLE.replace("distance_m = [0.6, 0.9]", "distance_m = [0.9, 0.6]");
        assert_ne!(empty, SINGLE);
        let message = error_of(&empty);
        assert!(
            message.contains("camera.distance_m") && message.contains("empty"),
            "{message}"
        );
        let improper = SINGLE.replace(
            "distance_m = [0.6, 0.9]",
            "distance_m = { normal = [5.0, 0.01], within = [0.6, 0.9] }",
        );
        assert!(error_of(&improper).contains("cannot be normalised"));
        let extra = SINGLE.replace(
            "distance_m = [0.6, 0.9]",
            "distance_m = { normal = [0.7, 0.1], within = [0.6, 0.9], skew = 1.0 }",
        );
        assert!(parse(&extra).is_err());
        let sun = SINGLE.replace(
            "sun_elevation_deg = [30.0, 80.0]",
            "sun_elevation_deg = [-100.0, 80.0]",
        );
        assert!(error_of(&sun).contains("lighting.sun_elevation_deg"));
        let nan = SINGLE.replace("distance_m = [0.6, 0.9]", "distance_m = [nan, 0.9]");
        assert!(error_of(&nan).contains("camera.distance_m"));
    }

    #[test]
    fn values_follow_the_nominal_distribution() {
        let d = Distribution::Uniform([2.0, 4.0]);
        assert!((d.value(0.0) - 3.0).abs() < 1e-12);
        assert!(d.value(-40.0) >= 2.0 && d.value(40.0) <= 4.0);
        let t = Distribution::TruncatedNormal(TruncatedNormal {
            normal: [0.0, 1.0],
            within: [-1.0, 1.0],
        });
        assert!(t.value(0.0).abs() < 1e-9);
        // an asymmetric truncation: the truncated CDF of value(z) is Φ(z), so z's quantiles map
        // to the parameter's
        let (mean, std, lo, hi) = (0.3, 0.2, 0.25, 0.9);
        let t = Distribution::TruncatedNormal(TruncatedNormal {
            normal: [mean, std],
            within: [lo, hi],
        });
        let cdf = |x: f64| {
            let (a, b) = (
                standard_normal_cdf((lo - mean) / std),
                standard_normal_cdf((hi - mean) / std),
            );
            (standard_normal_cdf((x - mean) / std) - a) / (b - a)
        };
        for z in [-2.0, -0.7, 0.0, 0.4, 1.9] {
            let x = t.value(z);
            assert!((lo..=hi).contains(&x));
            assert!(
                (cdf(x) - standard_normal_cdf(z)).abs() < 1e-9,
                "z {z}: F(x) {} Φ(z) {}",
                cdf(x),
                standard_normal_cdf(z)
            );
        }
    }

    #[test]
    fn orientation_is_a_unit_quaternion_with_non_negative_w() {
        let space = parse(SINGLE).unwrap();
        let mut z = vec![0.3; space.dim()];
        let n = z.len();
        z[n - 4..].copy_from_slice(&[-1.0, 2.0, 0.5, -0.2]);
        let p = space.parameters(&z, 0).unwrap();
        let norm: f64 = p.target_quat_wxyz.iter().map(|v| v * v).sum();
        assert!((norm - 1.0).abs() < 1e-12 && p.target_quat_wxyz[0] >= 0.0);
    }

    #[test]
    fn a_parameter_the_space_lacks_is_an_error_naming_it_not_a_panic() {
        let values: BTreeMap<String, f64> = [("camera.distance_m".to_string(), 1.0)].into();
        let error = Parameters::typed(values, 0, [1.0, 0.0, 0.0, 0.0]).unwrap_err();
        let message = error.to_string();
        assert!(message.contains("`target.size_m.x`"), "{message}");
        assert!(message.contains("camera.distance_m"), "{message}");
    }
}
