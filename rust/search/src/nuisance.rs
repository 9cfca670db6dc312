//! The nuisance of a sampled scene: box masses, frictions and appearance, drawn from the base
//! recipe's ranges (checked when the search space is loaded) and not searched over.

use boxpose_data::recipe::Recipe;
use boxpose_data::{Object, Pose};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;

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
    pub(crate) fn new(recipe: &Recipe, seed: i64) -> Self {
        Self {
            rng: ChaCha12Rng::seed_from_u64(seed as u64),
            density: recipe.boxes.density_kg_m3,
            friction: recipe.boxes.friction,
            roughness: recipe.materials.roughness,
            tape_probability: recipe.materials.tape_probability,
            label_probability: recipe.materials.label_probability,
        }
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
