//! A dataset in the BOP scene-wise format that bop_toolkit reads: per scene rgb/, depth/ (uint16
//! PNG with a depth_scale), mask/ and mask_visib/, scene_camera.json, scene_gt.json and
//! scene_gt_info.json; models/ and models_eval/ (one PLY per distinct box size, in mm, with
//! models_info.json and the box's discrete symmetries), camera.json, test_targets_bop19.json and
//! dataset_info.{json,md}. docs/export.md lists every file and field.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use boxpose_data::{Dataset, Pose};
use boxpose_geometry::pipeline::isometry;
use boxpose_geometry::silhouette::silhouette;
use nalgebra::Rotation3;
use serde_json::{Value, json};

use crate::error::{FormatError, Result};
use crate::files::{
    create_dir, write_depth, write_json, write_keyed, write_mask, write_rgb, write_text,
};
use crate::objects::{box_ply, box_symmetries, key_mm, model_info, obj_id, object_ids};

/// What `write_bop` was asked for beyond the dataset and the folder.
#[derive(Debug, Clone)]
pub struct BopOptions {
    /// Split folder the scenes go to (test, val or train, optionally with a _TYPE suffix).
    pub split: String,
    /// Smallest visib_fract of an instance listed in test_targets_bop19.json (BOP'19: 0.1).
    pub min_visib_fract: f64,
    /// The dataset's name as the export records its source (dataset_info.json and .md).
    pub source: String,
    /// The export's name for bop_toolkit (its folder's name): the key of the entry in
    /// bop_toolkit_dataset_params.txt.
    pub name: String,
}

/// What an export wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BopSummary {
    pub scenes: usize,
    pub images: usize,
    pub instances: usize,
    pub models: usize,
}

#[derive(Default)]
struct BopScene {
    camera: BTreeMap<i64, Value>,
    gt: BTreeMap<i64, Value>,
    gt_info: BTreeMap<i64, Value>,
}

/// A row-major rotation as BOP's flat 9 values.
fn flat(r: &Rotation3<f64>) -> Vec<f64> {
    (0..3)
        .flat_map(|row| (0..3).map(move |col| r[(row, col)]))
        .collect()
}

fn mm(t: [f64; 3]) -> Vec<f64> {
    t.iter().map(|v| v * 1000.0).collect()
}

/// R_w2c and t_w2c (metres) of the camera pose T_world_camera.
fn world_to_camera(world_camera: &Pose) -> (Rotation3<f64>, [f64; 3]) {
    let w2c = isometry(world_camera.quat_wxyz, world_camera.translation).inverse();
    (
        w2c.rotation.to_rotation_matrix(),
        w2c.translation.vector.into(),
    )
}

/// [x, y, w, h] of a visible_bbox (x_min, y_min, x_max, y_max; max exclusive), or [-1; 4].
pub(crate) fn xywh(bbox: Option<[i32; 4]>) -> [i64; 4] {
    bbox.map_or([-1; 4], |b| {
        [
            b[0] as i64,
            b[1] as i64,
            (b[2] - b[0]) as i64,
            (b[3] - b[1]) as i64,
        ]
    })
}

/// Writes `dataset` into the empty folder `out` in the BOP scene-wise format; `on_frame` is
/// called after each frame (a progress bar).
pub fn write_bop(
    dataset: &Dataset,
    options: &BopOptions,
    out: &Path,
    on_frame: &mut dyn FnMut(),
) -> Result<BopSummary> {
    let split = options.split.as_str();
    if split.is_empty() || split.contains(['/', '\\']) || ["models", "models_eval"].contains(&split)
    {
        return Err(FormatError::Invalid(format!(
            "--split {split:?} must be a plain folder name other than models"
        )));
    }
    let ids = object_ids(dataset)?;
    for models in ["models", "models_eval"] {
        let dir = out.join(models);
        create_dir(&dir)?;
        let mut info = BTreeMap::new();
        for (&key, &id) in &ids {
            write_text(&dir.join(format!("obj_{id:06}.ply")), &box_ply(key_mm(key)))?;
            info.insert(id as i64, model_info(key)?);
        }
        write_keyed(&dir.join("models_info.json"), &info)?;
    }

    let mut scenes: BTreeMap<i64, BopScene> = BTreeMap::new();
    let mut targets: Vec<Value> = Vec::new();
    let mut camera: Option<Value> = None;
    let (mut images, mut annotations) = (0usize, 0usize);
    for frame in dataset.frames()? {
        let frame = frame?;
        let im_id = frame.frame_id as i64;
        let dir = out.join(split).join(format!("{:06}", frame.scene_id));
        for sub in ["rgb", "depth", "mask", "mask_visib"] {
            create_dir(&dir.join(sub))?;
        }
        write_rgb(&dir.join("rgb").join(format!("{im_id:06}.png")), &frame)?;
        let depth_scale = write_depth(&dir.join("depth").join(format!("{im_id:06}.png")), &frame)?;
        let k = frame.intrinsics;
        let cam_k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0];
        camera.get_or_insert_with(|| {
            json!({"cx": k.cx, "cy": k.cy, "depth_scale": depth_scale, "fx": k.fx, "fy": k.fy,
                   "height": frame.height, "width": frame.width})
        });
        let (r_w2c, t_w2c) = world_to_camera(&frame.world_camera);
        let scene = scenes.entry(frame.scene_id).or_default();
        scene.camera.insert(
            im_id,
            json!({"cam_K": cam_k, "depth_scale": depth_scale, "cam_R_w2c": flat(&r_w2c), "cam_t_w2c": mm(t_w2c)}),
        );

        let (mut gt, mut gt_info) = (Vec::new(), Vec::new());
        let mut inst_count: BTreeMap<u32, usize> = BTreeMap::new();
        for (gt_id, instance) in frame.instances.iter().enumerate() {
            let obj = obj_id(&ids, instance)?;
            let box_pose = &instance.camera_box;
            let rotation = isometry(box_pose.quat_wxyz, box_pose.translation)
                .rotation
                .to_rotation_matrix();
            gt.push(json!({
                "cam_R_m2c": flat(&rotation),
                "cam_t_m2c": mm(box_pose.translation),
                "obj_id": obj,
            }));
            let intrinsics = [k.fx, k.fy, k.cx, k.cy];
            let sil = silhouette(
                intrinsics,
                frame.width,
                frame.height,
                &instance.corners_camera,
            );
            let label = instance.mask_label();
            let own = frame.instance_mask.iter().map(|&m| m == label);
            let mask_name = format!("{im_id:06}_{gt_id:06}.png");
            write_mask(&dir.join("mask_visib").join(&mask_name), own, &frame)?;
            write_mask(
                &dir.join("mask").join(&mask_name),
                sil.mask.iter().copied(),
                &frame,
            )?;
            let valid = sil
                .mask
                .iter()
                .zip(&frame.depth)
                .filter(|&(&m, &d)| m && d > 0.0)
                .count();
            let visib = instance.visible_pixels as u64;
            let visib_fract = if sil.count > 0 {
                (visib as f64 / sil.count as f64).min(1.0)
            } else {
                0.0
            };
            gt_info.push(json!({
                "bbox_obj": sil.bbox,
                "bbox_visib": xywh(instance.visible_bbox),
                "px_count_all": sil.count,
                "px_count_valid": valid,
                "px_count_visib": visib,
                "visib_fract": visib_fract,
            }));
            if visib_fract >= options.min_visib_fract {
                *inst_count.entry(obj).or_default() += 1;
            }
            annotations += 1;
        }
        for (obj, count) in inst_count {
            targets.push(json!({"im_id": im_id, "inst_count": count, "obj_id": obj, "scene_id": frame.scene_id}));
        }
        scene.gt.insert(im_id, Value::from(gt));
        scene.gt_info.insert(im_id, Value::from(gt_info));
        images += 1;
        on_frame();
    }

    for (scene_id, scene) in &scenes {
        let dir = out.join(split).join(format!("{scene_id:06}"));
        write_keyed(&dir.join("scene_camera.json"), &scene.camera)?;
        write_keyed(&dir.join("scene_gt.json"), &scene.gt)?;
        write_keyed(&dir.join("scene_gt_info.json"), &scene.gt_info)?;
    }
    if let Some(camera) = &camera {
        write_json(&out.join("camera.json"), camera)?;
    }
    let targets_text = if targets.is_empty() {
        "[]\n".to_string()
    } else {
        let lines: Vec<String> = targets.iter().map(|t| format!("  {t}")).collect();
        format!("[\n{}\n]\n", lines.join(",\n"))
    };
    write_text(&out.join("test_targets_bop19.json"), &targets_text)?;
    let summary = BopSummary {
        scenes: scenes.len(),
        images,
        instances: annotations,
        models: ids.len(),
    };
    write_dataset_info(&ids, options, &summary, out)?;
    let scene_ids: Vec<i64> = scenes.keys().copied().collect();
    let image_size = camera
        .as_ref()
        .map(|c| (c["width"].clone(), c["height"].clone()));
    write_bop_toolkit_entry(&options.name, &ids, &scene_ids, image_size, out)?;
    Ok(summary)
}

/// The bop_toolkit commit whose `dataset_params.py` the entry was written for (and that
/// third_party/bop_toolkit holds).
pub const BOP_TOOLKIT_COMMIT: &str = "cea62d651c7e395b2e1962b9749e4e89693c6ac4";

/// bop_toolkit_dataset_params.txt: the three entries that register the export with bop_toolkit,
/// which knows its datasets by name in `bop_toolkit_lib/dataset_params.py` (the object ids, the
/// symmetric ones: every box, and the split's scenes and image size). Each `# N.` line says where
/// its entry goes; `scripts/register_bop_toolkit.py` pastes them.
fn write_bop_toolkit_entry(
    name: &str,
    ids: &BTreeMap<crate::objects::SizeKey, u32>,
    scene_ids: &[i64],
    image_size: Option<(Value, Value)>,
    out: &Path,
) -> Result<()> {
    let obj_ids: Vec<u32> = ids.values().copied().collect();
    let (width, height) = image_size.unwrap_or((json!(0), json!(0)));
    let text = format!(
        "# boxpose export: the entries of bop_toolkit_lib/dataset_params.py (bop_toolkit {BOP_TOOLKIT_COMMIT})\n\
         # that register this export as the BOP dataset {name:?}: the export folder's name, under the\n\
         # folder bop_toolkit reads datasets from (BOP_PATH). bop_toolkit takes a results file's dataset\n\
         # from its name, METHOD_DATASET-SPLIT.csv, so DATASET must hold no '_' or '-'.\n\
         # Each entry goes where its `# N.` line says; scripts/register_bop_toolkit.py pastes them.\n\
         # 1. get_model_params, in the obj_ids dict:\n\
         {name:?}: {obj_ids:?},\n\
         # 2. get_model_params, in the symmetric_obj_ids dict (every box has discrete symmetries):\n\
         {name:?}: {obj_ids:?},\n\
         # 3. get_split_params, before the final `else:` that raises \"Unknown BOP dataset\":\n\
         \x20   elif dataset_name == {name:?}:\n\
         \x20       p[\"scene_ids\"] = {scene_ids:?}\n\
         \x20       p[\"im_size\"] = ({width}, {height})\n"
    );
    write_text(&out.join("bop_toolkit_dataset_params.txt"), &text)
}

/// dataset_info.json and dataset_info.md: where the export came from, its units and its objects.
fn write_dataset_info(
    ids: &BTreeMap<crate::objects::SizeKey, u32>,
    options: &BopOptions,
    summary: &BopSummary,
    out: &Path,
) -> Result<()> {
    let objects: BTreeMap<String, Value> = ids
        .iter()
        .map(|(&key, &id)| {
            (
                id.to_string(),
                json!({"size_mm": key_mm(key), "size_m": key.map(|k| k as f64 / 1e4)}),
            )
        })
        .collect();
    write_json(
        &out.join("dataset_info.json"),
        &json!({
            "source": options.source,
            "split": options.split,
            "scenes": summary.scenes, "images": summary.images, "instances": summary.instances,
            "min_visib_fract": options.min_visib_fract,
            "objects": objects,
        }),
    )?;
    let mut md = format!(
        "# boxpose dataset in BOP format\n\n\
         Exported by `boxpose export bop` from `{}`: {} scenes, {} images, {} annotated instances in `{}/`.\n\n\
         - Units: millimetres for models and translations; depth PNGs are uint16 with value × depth_scale = mm \
         (depth_scale per image in scene_camera.json: 0.1 unless the frame is deeper than 6.5 m).\n\
         - Every box of every frame is annotated in scene_gt.json, hidden or not; gt_id is the rank of its \
         boxpose object_id in the frame (the object_id itself when the frame lists every box).\n\
         - mask_visib/ is the exact instance mask; mask/ is the projected box silhouette (no occluders).\n\
         - test_targets_bop19.json lists the instances with visib_fract >= {}.\n\n\
         | obj_id | size_x (mm) | size_y (mm) | size_z (mm) | discrete symmetries |\n|---|---|---|---|---|\n",
        options.source,
        summary.scenes,
        summary.images,
        summary.instances,
        options.split,
        options.min_visib_fract
    );
    for (&key, &id) in ids {
        let s = key_mm(key);
        let symmetries = box_symmetries(key)?.len();
        writeln!(
            md,
            "| {id} | {} | {} | {} | {symmetries} |",
            s[0], s[1], s[2]
        )
        .expect("writing to a String");
    }
    write_text(&out.join("dataset_info.md"), &md)
}
