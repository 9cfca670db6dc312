//! MuJoCo's settle of a stored scene against the settled poses the dataset holds (`boxpose
//! settle`): the same scene dropped again from its stored initial poses, and how the two rests
//! agree.

use std::time::Instant;

use boxpose_data::{Object, Pose};

use crate::down_face;
use crate::error::{PhysicsError, Result};
use crate::scene::{RecipePhysics, SceneDescription};
use crate::settle::{SettleOutcome, Settler};

/// One scene settled again and compared with its stored rest.
#[derive(Debug, Clone)]
pub struct Agreement {
    /// The first settle's outcome (verdict, certificate, poses).
    pub outcome: SettleOutcome,
    /// Seconds to compile the scene's model.
    pub compile_s: f64,
    /// Wall seconds of every settle, sorted (the median is the middle one).
    pub walls_s: Vec<f64>,
    /// Boxes resting on the same face as in the stored pose.
    pub faces_agree: usize,
    /// Largest and mean distance between a box's two settled centres, metres.
    pub max_position_diff_m: f64,
    pub mean_position_diff_m: f64,
}

impl Agreement {
    /// The median settle's wall time.
    pub fn median_wall_s(&self) -> f64 {
        self.walls_s[self.walls_s.len() / 2]
    }
}

/// Settles one scene's `objects` rows (all of them: `num_objects` is the scene's count) with
/// `recipe`'s support and settle parameters, `repeats` times from the same initial poses (the model
/// compiled once), and compares the first rest with the rows' stored `world_box` poses.
pub fn settle_and_compare(
    objects: &[Object],
    num_objects: usize,
    recipe: &RecipePhysics,
    repeats: u32,
) -> Result<Agreement> {
    let mut objects = objects.to_vec();
    objects.sort_by_key(|o| o.object_id);
    if objects.len() != num_objects {
        return Err(PhysicsError::ObjectCount {
            rows: objects.len(),
            declared: num_objects,
        });
    }
    let description = SceneDescription::from_objects(recipe.support, &objects);
    let compile_start = Instant::now();
    let mut settler = Settler::new(&description, &recipe.settle)?;
    let compile_s = compile_start.elapsed().as_secs_f64();
    let outcome = settler.settle()?;
    let mut walls_s = vec![outcome.certificate.wall_time_s];
    let initial = description.initial_poses();
    for _ in 1..repeats.max(1) {
        walls_s.push(settler.settle_from(&initial)?.certificate.wall_time_s);
    }
    walls_s.sort_by(f64::total_cmp);
    let (faces_agree, max_position_diff_m, mean_position_diff_m) =
        compare_rests(&objects, &outcome.poses);
    Ok(Agreement {
        outcome,
        compile_s,
        walls_s,
        faces_agree,
        max_position_diff_m,
        mean_position_diff_m,
    })
}

/// How `poses` agree with the rows' stored rests: boxes resting on the same face, and the largest
/// and mean distance between their centres.
fn compare_rests(objects: &[Object], poses: &[Pose]) -> (usize, f64, f64) {
    let mut faces_agree = 0;
    let mut diffs = Vec::new();
    for (o, p) in objects.iter().zip(poses) {
        faces_agree += usize::from(down_face(o.world_box.quat_wxyz).0 == down_face(p.quat_wxyz).0);
        let d = (0..3)
            .map(|k| (o.world_box.translation[k] - p.translation[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        diffs.push(d);
    }
    let max_diff = diffs.iter().copied().fold(0.0, f64::max);
    let mean_diff = diffs.iter().sum::<f64>() / diffs.len().max(1) as f64;
    (faces_agree, max_diff, mean_diff)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(id: i32, quat_wxyz: [f64; 4], translation: [f64; 3]) -> Object {
        let pose = Pose {
            quat_wxyz,
            translation,
        };
        Object {
            scene_id: 0,
            object_id: id,
            size: [0.2, 0.2, 0.2],
            world_box: pose,
            initial_world_box: pose,
            mass_kg: 1.0,
            friction: 0.5,
            base_color_rgb: [0.5; 3],
            roughness: 0.5,
            texture_seed: 0,
            has_tape: false,
            has_label: false,
        }
    }

    #[test]
    fn rests_agree_by_face_and_centre_distance() {
        let upright = [1.0, 0.0, 0.0, 0.0];
        // a quarter turn about x: another face down
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let turned = [h, h, 0.0, 0.0];
        let objects = [
            object(0, upright, [0.0, 0.0, 0.1]),
            object(1, upright, [0.5, 0.0, 0.1]),
        ];
        let poses = [
            Pose {
                quat_wxyz: upright,
                translation: [0.0, 0.03, 0.14],
            },
            Pose {
                quat_wxyz: turned,
                translation: [0.5, 0.0, 0.1],
            },
        ];
        let (faces, max, mean) = compare_rests(&objects, &poses);
        assert_eq!(faces, 1);
        assert!((max - 0.05).abs() < 1e-12);
        assert!((mean - 0.025).abs() < 1e-12);
    }
}
