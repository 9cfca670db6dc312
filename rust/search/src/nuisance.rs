//! The nuisance of a sampled scene: box masses, frictions and appearance, drawn from the base
//! recipe's ranges and not searched over. Read by the scene builder and checked when a search
//! space is loaded, so a bad recipe is refused before any work starts.

use boxpose_data::{Object, Pose};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;

use crate::error::{Result, SearchError};

/// Linear RGB of plain cardboard, as python/drake_scenes/sampling.py draws it.
const CARDBOARD_LINEAR_RGB: [f64; 3] = [0.43, 0.25, 0.11];

/// The nuisance draws of one scene (box masses, frictions, appearance), seeded by the scene seed.
/// They are not searched over: their nominal distribution is kept, as the recipe's.
pub(crate) struct Nuisance {
    rng: ChaCha12Rng,
    density: [f64; 2],
    friction: [f64; 2],
    roughness: [f64; 2],
    tape_probability: f64,
    label_probability: f64,
}

impl Nuisance {
    pub(crate) fn new(recipe: &toml::Table, seed: i64) -> Result<Self> {
        let pair = |section: &str, key: &str| -> Result<[f64; 2]> {
            let v = recipe
                .get(section)
                .and_then(|s| s.get(key))
                .and_then(|v| v.as_array());
            let v: Option<Vec<f64>> = v.map(|a| {
                a.iter()
                    .filter_map(|x| x.as_float().or(x.as_integer().map(|i| i as f64)))
                    .collect()
            });
            match v.as_deref() {
                Some(&[lo, hi]) if lo.is_finite() && hi.is_finite() && lo <= hi => Ok([lo, hi]),
                _ => Err(SearchError::Space {
                    key: format!("recipe {section}.{key}"),
                    problem: "must be a range [min, max]".into(),
                }),
            }
        };
        let probability = |key: &str| -> Result<f64> {
            match recipe
                .get("materials")
                .and_then(|s| s.get(key))
                .and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))
            {
                Some(p) if (0.0..=1.0).contains(&p) => Ok(p),
                _ => Err(SearchError::Space {
                    key: format!("recipe materials.{key}"),
                    problem: "must be a probability in [0, 1]".into(),
                }),
            }
        };
        // The appearance is drawn by the Blender stage from the scene's recipe, which keeps the
        // base recipe's [materials]; a value it would refuse is refused here, before any work.
        boxpose_data::recipe::tape_along(recipe).map_err(|problem| SearchError::Space {
            key: "recipe".into(),
            problem,
        })?;
        Ok(Self {
            rng: ChaCha12Rng::seed_from_u64(seed as u64),
            density: pair("boxes", "density_kg_m3")?,
            friction: pair("boxes", "friction")?,
            roughness: pair("materials", "roughness")?,
            tape_probability: probability("tape_probability")?,
            label_probability: probability("label_probability")?,
        })
    }

    fn uniform(&mut self, [lo, hi]: [f64; 2]) -> f64 {
        if hi > lo {
            self.rng.random_range(lo..hi)
        } else {
            lo
        }
    }

    pub(crate) fn object(
        &mut self,
        scene_id: i64,
        object_id: i32,
        size: [f64; 3],
        initial: Pose,
    ) -> Object {
        let mass_kg = self.uniform(self.density) * size.iter().product::<f64>();
        let friction = self.uniform(self.friction);
        let brightness = self.uniform([0.7, 1.25]);
        let warmth = self.uniform([-0.15, 0.15]);
        let tint = [1.0 + warmth, 1.0, 1.0 - warmth];
        let base_color_rgb = std::array::from_fn(|k| {
            (CARDBOARD_LINEAR_RGB[k] * brightness * tint[k]).clamp(0.0, 1.0) as f32
        });
        let roughness = self.uniform(self.roughness) as f32;
        let texture_seed = self.rng.random_range(0..i64::MAX);
        let has_tape = self.rng.random::<f64>() < self.tape_probability;
        let has_label = self.rng.random::<f64>() < self.label_probability;
        Object {
            scene_id,
            object_id,
            size,
            world_box: initial,
            initial_world_box: initial,
            mass_kg,
            friction,
            base_color_rgb,
            roughness,
            texture_seed,
            has_tape,
            has_label,
        }
    }
}

/// Checks the base recipe's sections the scenes draw their nuisance from ([boxes] density and
/// friction, [materials]), so a bad recipe is refused before any work starts.
pub(crate) fn check_recipe(recipe_toml: &str) -> Result<()> {
    let recipe: toml::Table = recipe_toml.parse().map_err(|e| SearchError::Space {
        key: "recipe".into(),
        problem: format!("{e}"),
    })?;
    Nuisance::new(&recipe, 0).map(|_| ())
}
