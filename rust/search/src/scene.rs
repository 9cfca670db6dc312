//! Sampled inputs → a scene in the dataset contract: the `scenes` row (with a recipe whose camera
//! and lighting ranges are pinned to the sampled values, so that the row alone re-renders the
//! sample exactly) and the `objects` rows, dropped and settled with MuJoCo.

use boxpose_data::{Object, Pose, Scene};
use boxpose_physics::{RecipePhysics, SceneDescription, SettleOutcome, Settler, rotation_matrix};

use crate::error::{Result, SearchError};
use crate::nuisance::Nuisance;
use crate::space::{Parameters, SearchSpace};

/// The object_id of the box the pipeline is scored on.
pub const TARGET_OBJECT_ID: i32 = 0;

/// Vertical gap between boxes stacked for the drop, metres: they start apart and fall in turn.
const STACK_GAP_M: f64 = 0.02;

/// A sampled scene before and after settling.
#[derive(Debug, Clone)]
pub struct SampledScene {
    pub scene: Scene,
    /// In object_id order; the target first. `world_box` holds the settled pose once settled.
    pub objects: Vec<Object>,
    /// The boxes after the target are a settled pile (`[pile]`): they start at rest, asleep,
    /// and only the target is dropped.
    pub onto_pile: bool,
}

/// Half the vertical extent of a box of `size` turned by `quat_wxyz`: its centre's height above
/// its lowest point.
fn half_height(size: [f64; 3], quat_wxyz: [f64; 4]) -> f64 {
    let r = rotation_matrix(quat_wxyz);
    (0..3).map(|k| r[2][k].abs() * size[k] / 2.0).sum()
}

/// Keeps a footprint of radius `radius` inside the support region (a box placed at its edge
/// would start inside a bin wall or hang over a pallet).
fn inside(value: f64, half_extent: f64, radius: f64) -> f64 {
    let limit = (half_extent - radius).max(0.0);
    value.clamp(-limit, limit)
}

fn yaw_quaternion(yaw_deg: f64) -> [f64; 4] {
    let half = yaw_deg.to_radians() / 2.0;
    [half.cos(), 0.0, 0.0, half.sin()]
}

/// The scene of one sample, boxes at their drop poses (not yet settled): the target at the
/// sampled pose, neighbours stacked above it (each starting clear of the others) to fall in turn.
pub fn build(
    space: &SearchSpace,
    parameters: &Parameters,
    scene_id: i64,
    seed: i64,
) -> Result<SampledScene> {
    let support = space.physics.support;
    let [hx, hy] = support.half_extent_m;
    let top = support.top_z();
    let mut nuisance = Nuisance::new(&space.recipe, seed);
    let target = &parameters.target;
    let size = target.size_m;
    let quat = parameters.target_quat_wxyz;
    let radius = (size[0].powi(2) + size[1].powi(2) + size[2].powi(2)).sqrt() / 2.0;
    let lift = half_height(size, quat);
    let mut centre = [
        inside(target.x_m, hx, radius),
        inside(target.y_m, hy, radius),
        top + target.drop_height_m + lift,
    ];
    if let Some(pile) = &space.pile {
        // the drop height is counted from the pile's highest point: the target starts clear of
        // every box, as a re-settle needs (a box touched at the start cannot sleep)
        let pile_top = pile
            .iter()
            .map(|b| b.translation_m[2] + half_height(b.size_m, b.quat_wxyz))
            .fold(top, f64::max);
        centre[2] = pile_top + target.drop_height_m + lift;
    }
    let mut objects = vec![nuisance.object(
        scene_id,
        TARGET_OBJECT_ID,
        size,
        Pose {
            quat_wxyz: quat,
            translation: centre,
        },
    )];
    for (i, pile_box) in space.pile.iter().flatten().enumerate() {
        objects.push(pile_box.object(scene_id, TARGET_OBJECT_ID + 1 + i as i32));
    }
    let mut floor = centre[2] + lift + STACK_GAP_M;
    for (i, neighbour) in parameters.neighbour_boxes.iter().enumerate() {
        let size = neighbour.size_m;
        let radius = (size[0].powi(2) + size[1].powi(2)).sqrt() / 2.0;
        let translation = [
            inside(neighbour.x_m, hx, radius),
            inside(neighbour.y_m, hy, radius),
            floor + size[2] / 2.0,
        ];
        floor += size[2] + STACK_GAP_M;
        let pose = Pose {
            quat_wxyz: yaw_quaternion(neighbour.yaw_deg),
            translation,
        };
        objects.push(nuisance.object(scene_id, i as i32 + 1, size, pose));
    }
    let scene = Scene {
        scene_id,
        seed,
        recipe: space.file.name.clone(),
        recipe_toml: pinned_recipe(space, parameters)?,
        tool_versions: serde_json::json!({"boxpose-search": env!("CARGO_PKG_VERSION"), "mujoco": boxpose_physics::MUJOCO_VERSION}).to_string(),
        physics_backend: "mujoco".into(),
        support: support.kind.name().into(),
        num_objects: objects.len() as i32,
        solver: "none".into(),
        solver_status: if space.pile.is_some() {
            "dropped onto a settled pile".into()
        } else {
            "dropped from sampled poses".into()
        },
        solve_attempts: 0,
        settle_time_s: f64::NAN,
        max_linear_speed_mps: f64::NAN,
        max_angular_speed_radps: f64::NAN,
        min_signed_distance_m: f64::NAN,
        stable: false,
    };
    Ok(SampledScene {
        scene,
        objects,
        onto_pile: space.pile.is_some(),
    })
}

/// The base recipe's text with this sample's camera and lighting as degenerate ranges, one
/// frame, and the camera aimed at the target box: the Blender stage then draws exactly these
/// values. The base recipe's table, not the typed recipe, is edited, so that the scene's recipe
/// holds the keys the base recipe wrote and no defaults it left out.
fn pinned_recipe(space: &SearchSpace, parameters: &Parameters) -> Result<String> {
    let mut recipe: toml::Table = space.recipe_toml.parse().map_err(|e| SearchError::Space {
        key: "recipe".into(),
        problem: format!("{e}"),
    })?;
    let pin = |v: f64| toml::Value::Array(vec![toml::Value::Float(v), toml::Value::Float(v)]);
    let section = |recipe: &mut toml::Table, name: &str| -> Result<toml::Table> {
        match recipe.remove(name) {
            Some(toml::Value::Table(t)) => Ok(t),
            _ => Err(SearchError::Space {
                key: format!("recipe [{name}]"),
                problem: "missing section".into(),
            }),
        }
    };
    let mut camera = section(&mut recipe, "camera")?;
    for (key, value) in parameters.camera.recipe_keys() {
        camera.insert(key.into(), pin(value));
    }
    camera.insert("frames_per_scene".into(), toml::Value::Integer(1));
    camera.insert("look_at_jitter_m".into(), toml::Value::Float(0.0));
    camera.insert(
        "look_at_object".into(),
        toml::Value::Integer(TARGET_OBJECT_ID.into()),
    );
    let mut lighting = section(&mut recipe, "lighting")?;
    for (key, value) in parameters.lighting.recipe_keys() {
        lighting.insert(key.into(), pin(value));
    }
    recipe.insert("camera".into(), toml::Value::Table(camera));
    recipe.insert("lighting".into(), toml::Value::Table(lighting));
    recipe.insert("name".into(), toml::Value::String(space.file.name.clone()));
    toml::to_string(&recipe)
        .map_err(|e| SearchError::Sample(format!("cannot write the scene's recipe: {e}")))
}

/// Drops and settles the scene with MuJoCo (onto a pile: re-settles it, the pile asleep until
/// touched); the objects' `world_box` become the settled poses and the scene row gets the
/// certificate.
pub fn settle(sampled: &mut SampledScene, physics: &RecipePhysics) -> Result<SettleOutcome> {
    let description = SceneDescription::from_objects(physics.support, &sampled.objects);
    description.validate()?;
    let outcome = if sampled.onto_pile {
        let target = TARGET_OBJECT_ID as usize;
        boxpose_physics::resettle(
            &description,
            &description.initial_poses(),
            target,
            description.boxes[target].initial,
            &physics.settle,
        )?
    } else {
        Settler::new(&description, &physics.settle)?.settle()?
    };
    for (object, pose) in sampled.objects.iter_mut().zip(&outcome.poses) {
        object.world_box = *pose;
    }
    let c = &outcome.certificate;
    let scene = &mut sampled.scene;
    scene.settle_time_s = c.settle_time_s;
    scene.max_linear_speed_mps = c.max_linear_speed_mps;
    scene.max_angular_speed_radps = c.max_angular_speed_radps;
    scene.min_signed_distance_m = c.min_signed_distance_m;
    scene.stable = outcome.stable;
    Ok(outcome)
}

#[cfg(test)]
mod tests {
    use super::*;

    const RECIPE: &str = include_str!("../../../datasets/recipes/single_box.toml");
    const SINGLE: &str = include_str!("../../../configs/search/single_box.toml");

    fn with_tape_along(value: &str) -> String {
        let recipe = RECIPE.replace(
            "[materials]\n",
            &format!("[materials]\ntape_along = {value}\n"),
        );
        assert_ne!(recipe, RECIPE);
        recipe
    }

    #[test]
    fn a_sampled_scene_carries_tape_along_to_the_renderer() {
        // the Blender stage draws the boxes' look from the scene row's recipe: the option must
        // survive the pinning of the camera and the lights
        let space = SearchSpace::from_texts(SINGLE, &with_tape_along("\"long\""), None).unwrap();
        let parameters = space.parameters(&vec![0.3; space.dim()], 0).unwrap();
        let sampled = build(&space, &parameters, 0, 7).unwrap();
        let recipe = boxpose_data::recipe::Recipe::from_toml(&sampled.scene.recipe_toml).unwrap();
        assert_eq!(recipe.materials.tape_along, "long");
    }

    #[test]
    fn a_base_recipe_with_another_tape_along_is_refused_naming_the_key() {
        let message = SearchSpace::from_texts(SINGLE, &with_tape_along("\"short\""), None)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("materials.tape_along") && message.contains("\"long\" or \"random\""),
            "{message}"
        );
    }
}
