//! A dataset as COCO instances: annotations.json (one `box` category; per visible box a COCO RLE
//! of its visible mask, bbox, area, and the amodal silhouette as amodal_segmentation and
//! amodal_bbox; optionally the 8 corners as keypoints) and the images as PNG files under images/.

use std::path::Path;

use boxpose_data::{Dataset, Instance, Visibility};
use boxpose_geometry::silhouette::{box_edges, silhouette};
use serde_json::{Value, json};

use crate::bop::xywh;
use crate::error::Result;
use crate::files::{create_dir, write_json, write_rgb};
use crate::objects::{obj_id, object_ids};

/// What `write_coco` was asked for beyond the dataset and the folder.
#[derive(Debug, Clone)]
pub struct CocoOptions {
    /// Also the box's 8 corners per annotation as COCO `keypoints`, and the corner names and the
    /// 12-edge `skeleton` in the category.
    pub keypoints: bool,
    /// The dataset's name as the export records its source (the `info` description).
    pub source: String,
}

/// What an export wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CocoSummary {
    pub images: usize,
    pub annotations: usize,
}

/// Uncompressed COCO RLE of a row-major height × width mask: run lengths in column-major
/// (Fortran) order, starting with a (possibly empty) run of zeros.
pub fn rle(mask: &[bool], width: usize, height: usize) -> Value {
    let mut counts: Vec<u64> = Vec::new();
    let (mut current, mut run) = (false, 0u64);
    for x in 0..width {
        for y in 0..height {
            let m = mask[y * width + x];
            if m != current {
                counts.push(run);
                (current, run) = (m, 0);
            }
            run += 1;
        }
    }
    counts.push(run);
    json!({"size": [height, width], "counts": counts})
}

/// [x, y, w, h] of the set pixels of a row-major mask, or [-1; 4] when none is set.
fn mask_bbox(mask: &[bool], width: usize) -> [i64; 4] {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (i % width, i / width);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 == usize::MAX {
        [-1; 4]
    } else {
        [
            x0 as i64,
            y0 as i64,
            (x1 - x0 + 1) as i64,
            (y1 - y0 + 1) as i64,
        ]
    }
}

/// COCO's visibility flag of a corner. COCO labels a hidden joint with its position and v = 1, so
/// corners hidden by another box or by the box's own faces (whose exact positions the dataset
/// has) get 1; a corner outside the image (or behind the camera) has no position in it and is
/// not labelled (0).
pub fn coco_visibility(visibility: Visibility) -> u8 {
    match visibility {
        Visibility::Visible => 2,
        Visibility::OccludedByOther | Visibility::SelfOccluded => 1,
        Visibility::OutsideImage => 0,
    }
}

/// An instance's corners as COCO `keypoints` [x1, y1, v1, …] in corner order, unlabelled ones as
/// 0, 0, 0 (COCO's convention), and `num_keypoints`, the labelled ones. Pixel coordinates as in
/// the dataset (the top-left pixel's centre at (0, 0)), COCO's keypoint convention too; the
/// flags are integers, as in COCO's own files.
fn coco_keypoints(instance: &Instance) -> (Vec<Value>, usize) {
    let mut keypoints = Vec::with_capacity(3 * 8);
    let mut labelled = 0;
    for (&[x, y], &visibility) in instance.corners_px.iter().zip(&instance.visibility) {
        let v = coco_visibility(visibility);
        if v == 0 {
            keypoints.extend([json!(0), json!(0), json!(0)]);
        } else {
            keypoints.extend([json!(x), json!(y), json!(v)]);
            labelled += 1;
        }
    }
    (keypoints, labelled)
}

/// The `box` category; with keypoints, the corners' names and the box's edges as COCO's 1-based
/// `skeleton`.
fn coco_category(keypoints: bool) -> Value {
    let mut category = json!({"id": 1, "name": "box", "supercategory": "box"});
    if keypoints {
        let names: Vec<String> = (0..8).map(|i| format!("corner_{i}")).collect();
        let skeleton: Vec<[usize; 2]> = box_edges().map(|(i, j)| [i + 1, j + 1]).collect();
        category["keypoints"] = json!(names);
        category["skeleton"] = json!(skeleton);
    }
    category
}

/// Writes `dataset` into the empty folder `out` as COCO instances; `on_frame` is called after each
/// frame (a progress bar).
pub fn write_coco(
    dataset: &Dataset,
    options: &CocoOptions,
    out: &Path,
    on_frame: &mut dyn FnMut(),
) -> Result<CocoSummary> {
    let ids = object_ids(dataset)?;
    let images_dir = out.join("images");
    create_dir(&images_dir)?;
    let (mut images, mut annotations) = (Vec::new(), Vec::new());
    for frame in dataset.frames()? {
        let frame = frame?;
        let image_id = images.len() + 1;
        let file_name = format!("{:06}_{:06}.png", frame.scene_id, frame.frame_id);
        write_rgb(&images_dir.join(&file_name), &frame)?;
        images.push(json!({
            "id": image_id, "file_name": file_name, "width": frame.width, "height": frame.height,
            "scene_id": frame.scene_id, "frame_id": frame.frame_id,
        }));
        let k = frame.intrinsics;
        for instance in frame.instances.iter().filter(|i| i.visible_pixels > 0) {
            let label = instance.mask_label();
            let own: Vec<bool> = frame.instance_mask.iter().map(|&m| m == label).collect();
            let sil = silhouette(
                [k.fx, k.fy, k.cx, k.cy],
                frame.width,
                frame.height,
                &instance.corners_camera,
            );
            let mut annotation = json!({
                "id": annotations.len() + 1,
                "image_id": image_id,
                "category_id": 1,
                "segmentation": rle(&own, frame.width, frame.height),
                "area": instance.visible_pixels,
                "bbox": xywh(instance.visible_bbox),
                "iscrowd": 0,
                "amodal_segmentation": rle(&sil.mask, frame.width, frame.height),
                "amodal_area": sil.count,
                "amodal_bbox": mask_bbox(&sil.mask, frame.width),
                "visib_fract": instance.visible_fraction,
                "object_id": instance.object_id,
                "obj_id": obj_id(&ids, instance)?,
            });
            if options.keypoints {
                let (keypoints, num_keypoints) = coco_keypoints(instance);
                annotation["keypoints"] = json!(keypoints);
                annotation["num_keypoints"] = json!(num_keypoints);
            }
            annotations.push(annotation);
        }
        on_frame();
    }
    let summary = CocoSummary {
        images: images.len(),
        annotations: annotations.len(),
    };
    write_json(
        &out.join("annotations.json"),
        &json!({
            "info": {
                "description": format!("boxpose dataset {} (boxpose export coco)", options.source),
                "version": env!("CARGO_PKG_VERSION"),
            },
            "licenses": [],
            "images": images,
            "annotations": annotations,
            "categories": [coco_category(options.keypoints)],
        }),
    )?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_is_column_major() {
        // 2 × 3 mask, row-major [0 1 1; 0 0 1]; column by column 0 0 | 1 0 | 1 1:
        // runs of 2 zeros, 1 one, 1 zero, 2 ones
        let mask = [false, true, true, false, false, true];
        assert_eq!(rle(&mask, 3, 2)["counts"], json!([2, 1, 1, 2]));
        assert_eq!(rle(&[true; 4], 2, 2)["counts"], json!([0, 4]));
    }

    #[test]
    fn mask_bbox_bounds_the_set_pixels() {
        let mask = [false, true, true, false, false, true];
        assert_eq!(mask_bbox(&mask, 3), [1, 0, 2, 2]);
        assert_eq!(mask_bbox(&[false; 6], 3), [-1; 4]);
    }

    #[test]
    fn coco_visibility_flags_and_keypoint_category() {
        assert_eq!(coco_visibility(Visibility::Visible), 2);
        assert_eq!(coco_visibility(Visibility::OccludedByOther), 1);
        assert_eq!(coco_visibility(Visibility::SelfOccluded), 1);
        assert_eq!(coco_visibility(Visibility::OutsideImage), 0);
        let category = coco_category(true);
        assert_eq!(category["keypoints"][7], json!("corner_7"));
        assert_eq!(category["skeleton"][0], json!([1, 2]));
        assert_eq!(
            coco_category(false),
            json!({"id": 1, "name": "box", "supercategory": "box"})
        );
    }
}
