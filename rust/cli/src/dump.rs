use std::path::Path;

use boxpose_data::{Dataset, Frame, Instance, Object, Pose, Scene};
use serde_json::{Value, json};

/// Prints every scene, object and decoded frame (instances included) as one JSON object per
/// line, tagged with its table.
pub fn run(path: &Path) -> anyhow::Result<()> {
    let dataset = Dataset::open(path)?;
    crate::to_stdout(|out| {
        for scene in dataset.scenes()? {
            writeln!(out, "{}", scene_json(&scene))?;
        }
        for object in dataset.objects()? {
            writeln!(out, "{}", object_json(&object))?;
        }
        if dataset.shards(&boxpose_data::schema::FRAMES).is_ok() {
            for frame in dataset.frames()? {
                writeln!(out, "{}", frame_json(&frame?))?;
            }
        }
        Ok(())
    })
}

fn scene_json(s: &Scene) -> Value {
    json!({
        "table": "scenes",
        "scene_id": s.scene_id,
        "seed": s.seed,
        "recipe": s.recipe,
        "recipe_toml": s.recipe_toml,
        "tool_versions": s.tool_versions,
        "physics_backend": s.physics_backend,
        "support": s.support,
        "num_objects": s.num_objects,
        "solver": s.solver,
        "solver_status": s.solver_status,
        "solve_attempts": s.solve_attempts,
        "settle_time_s": s.settle_time_s,
        "max_linear_speed_mps": s.max_linear_speed_mps,
        "max_angular_speed_radps": s.max_angular_speed_radps,
        "min_signed_distance_m": s.min_signed_distance_m,
        "stable": s.stable,
    })
}

fn object_json(o: &Object) -> Value {
    json!({
        "table": "objects",
        "scene_id": o.scene_id,
        "object_id": o.object_id,
        "size_m": o.size,
        "world_box": pose_json(&o.world_box),
        "initial_world_box": pose_json(&o.initial_world_box),
        "mass_kg": o.mass_kg,
        "friction": o.friction,
        "base_color_rgb": o.base_color_rgb,
        "roughness": o.roughness,
        "texture_seed": o.texture_seed,
        "has_tape": o.has_tape,
        "has_label": o.has_label,
    })
}

fn pose_json(p: &Pose) -> Value {
    json!({ "quat_wxyz": p.quat_wxyz, "translation_m": p.translation })
}

fn instance_json(i: &Instance) -> Value {
    json!({
        "object_id": i.object_id,
        "size_m": i.size,
        "camera_box": pose_json(&i.camera_box),
        "corners_camera_m": i.corners_camera,
        "corners_px": i.corners_px,
        "corner_visibility": i.visibility.map(|v| v as i8),
        "label_keypoints_camera_m": i.label_keypoints_camera,
        "label_keypoints_px": i.label_keypoints_px,
        "visible_bbox_px": i.visible_bbox,
        "visible_pixels": i.visible_pixels,
        "visible_fraction": i.visible_fraction,
    })
}

fn frame_json(f: &Frame) -> Value {
    json!({
        "table": "frames",
        "scene_id": f.scene_id,
        "frame_id": f.frame_id,
        "width": f.width,
        "height": f.height,
        "intrinsics": [f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy],
        "world_camera": pose_json(&f.world_camera),
        "samples": f.samples,
        "denoise": f.denoise,
        "render_seed": f.render_seed,
        "blender_version": f.blender_version,
        "rgb": f.rgb,
        "depth_m": f.depth,
        "instance_mask": f.instance_mask,
        "sensor_depth_m": f.sensor_depth,
        "instances": f.instances.iter().map(instance_json).collect::<Vec<_>>(),
    })
}
