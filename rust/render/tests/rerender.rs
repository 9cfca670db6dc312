//! In-process rendering through the embedded Blender: full frames, crops, pose changes, errors.
//! Tiny renders (96 × 72, 1 sample). One Renderer per process, shared by the tests.

use std::sync::{Mutex, MutexGuard, OnceLock};

use arrow_pyarrow::FromPyArrow;
use boxpose_data::Pose;
use boxpose_data::arrow::array::{Array, AsArray, BinaryArray};
use boxpose_data::arrow::datatypes::{Float64Type, Int32Type};
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_render::{RenderError, RenderRequest, Rendered, Renderer};
use pyo3::prelude::*;

const W: u32 = 96;
const H: u32 = 72;

/// Synthetic scene rows (blender_scripts.synthetic) as contract batches.
fn scene_batches(scene_id: i64, boxes: usize) -> (RecordBatch, RecordBatch) {
    Python::attach(|py| {
        let code = format!(
            r#"
import pathlib, boxpose_io, blender_scripts
from blender_scripts.synthetic import synthetic_scene
root = pathlib.Path(blender_scripts.__file__).resolve().parents[2]  # python/blender_scripts/__init__.py
text = (root / "datasets/recipes/tiny.toml").read_text().replace("width = 64", "width = {W}").replace("height = 64", "height = {H}")
text = text.replace("frames_per_scene = 1", "frames_per_scene = 2")
scene, objects = synthetic_scene({scene_id}, text, {boxes}, seed=21, stack=True, spread_m=0.1)
result = (boxpose_io.table_from_rows("scenes", [scene]).to_batches()[0], boxpose_io.table_from_rows("objects", objects).to_batches()[0])
"#
        );
        let code = std::ffi::CString::new(code).unwrap();
        let globals = pyo3::types::PyDict::new(py);
        py.run(&code, Some(&globals), None)
            .expect("make scene rows");
        let result = globals.get_item("result").unwrap().unwrap();
        let scenes = RecordBatch::from_pyarrow_bound(&result.get_item(0).unwrap()).unwrap();
        let objects = RecordBatch::from_pyarrow_bound(&result.get_item(1).unwrap()).unwrap();
        (scenes, objects)
    })
}

fn renderer() -> MutexGuard<'static, Renderer> {
    static RENDERER: OnceLock<Mutex<Renderer>> = OnceLock::new();
    RENDERER
        .get_or_init(|| {
            let mut r = Renderer::new(0).expect("start the embedded Blender");
            let (scenes, objects) = scene_batches(7, 4);
            r.load_scene(&scenes, &objects, 7).expect("load");
            Mutex::new(r)
        })
        .lock()
        .unwrap_or_else(|e| e.into_inner())
}

fn bytes(batch: &RecordBatch, column: &str) -> Vec<u8> {
    let a: &BinaryArray = batch.column_by_name(column).unwrap().as_binary::<i32>();
    a.value(0).to_vec()
}

fn int(batch: &RecordBatch, column: &str) -> i32 {
    batch
        .column_by_name(column)
        .unwrap()
        .as_primitive::<Int32Type>()
        .value(0)
}

fn depth(batch: &RecordBatch) -> Vec<f32> {
    bytes(batch, "depth_m_f32le")
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

fn mask(batch: &RecordBatch) -> (usize, Vec<u16>) {
    let png = bytes(batch, "instance_mask_png");
    let mut reader = png::Decoder::new(std::io::Cursor::new(png))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Grayscale, png::BitDepth::Sixteen)
    );
    (
        info.width as usize,
        buf[..info.buffer_size()]
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect(),
    )
}

fn rgb(batch: &RecordBatch) -> Vec<u8> {
    let png = bytes(batch, "rgb_png");
    let mut reader = png::Decoder::new(std::io::Cursor::new(png))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    buf
}

fn list_f64(batch: &RecordBatch, column: &str, row: usize) -> Vec<f64> {
    let l = batch.column_by_name(column).unwrap().as_list::<i32>();
    l.value(row).as_primitive::<Float64Type>().values().to_vec()
}

fn render(r: &mut Renderer, request: RenderRequest) -> Rendered {
    r.render(&request).expect("render")
}

#[test]
fn renders_a_frame_with_contract_batches() {
    let mut r = renderer();
    let out = render(
        &mut r,
        RenderRequest {
            frame_id: 1,
            ..Default::default()
        },
    );
    assert_eq!(out.frames.num_rows(), 1);
    assert_eq!(out.instances.num_rows(), 4);
    assert_eq!(
        (int(&out.frames, "width"), int(&out.frames, "height")),
        (W as i32, H as i32)
    );
    assert_eq!(
        out.frames.schema().fields(),
        boxpose_data::schema::FRAMES.arrow_schema().fields()
    );
    assert_eq!(
        out.instances.schema().fields(),
        boxpose_data::schema::INSTANCES.arrow_schema().fields()
    );
    let d = depth(&out.frames);
    assert_eq!(d.len(), (W * H) as usize);
    assert!(d.iter().all(|v| v.is_finite() && *v >= 0.0));
    let (width, m) = mask(&out.frames);
    assert_eq!(width, W as usize);
    assert!(m.iter().any(|&v| v > 0), "no box visible");
    assert_eq!(rgb(&out.frames).len(), (W * H * 3) as usize);
}

#[test]
fn crop_matches_the_full_frame() {
    let mut r = renderer();
    let full = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            ..Default::default()
        },
    );
    let [x0, y0, x1, y1] = [20u32, 10, 84, 58];
    let crop = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            crop: Some([x0, y0, x1, y1]),
            ..Default::default()
        },
    );
    let (cw, ch) = ((x1 - x0) as usize, (y1 - y0) as usize);
    assert_eq!(
        (
            int(&crop.frames, "width") as usize,
            int(&crop.frames, "height") as usize
        ),
        (cw, ch)
    );
    let (full_d, (_, full_m)) = (depth(&full.frames), mask(&full.frames));
    let (crop_d, (_, crop_m)) = (depth(&crop.frames), mask(&crop.frames));
    for y in 0..ch {
        for x in 0..cw {
            let f = (y + y0 as usize) * W as usize + x + x0 as usize;
            assert_eq!(crop_m[y * cw + x], full_m[f], "mask at ({x}, {y})");
            assert!(
                (crop_d[y * cw + x] - full_d[f]).abs() < 1e-5,
                "depth at ({x}, {y})"
            );
        }
    }
    for row in 0..4 {
        let a = list_f64(&crop.instances, "corners_px", row);
        let b = list_f64(&full.instances, "corners_px", row);
        for k in 0..8 {
            assert!((a[2 * k] - (b[2 * k] - x0 as f64)).abs() < 1e-9);
            assert!((a[2 * k + 1] - (b[2 * k + 1] - y0 as f64)).abs() < 1e-9);
        }
    }
}

/// `crop_object` renders the box's projected bounding box grown by the margin: every corner of
/// that box lands inside the region, which is smaller than the frame, and the region is the one
/// `render_settings` records.
#[test]
fn crop_around_an_object_holds_its_corners() {
    let mut r = renderer();
    let full = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            ..Default::default()
        },
    );
    let around = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            crop_object: Some((0, 0.2)),
            ..Default::default()
        },
    );
    let (w, h) = (
        int(&around.frames, "width") as f64,
        int(&around.frames, "height") as f64,
    );
    assert!(w * h < (W * H) as f64, "{w}×{h} is the whole frame");
    let settings = around
        .frames
        .column_by_name("render_settings")
        .unwrap()
        .as_string::<i32>()
        .value(0)
        .to_string();
    let crop: Vec<f64> = serde_json_crop(&settings);
    assert_eq!((crop[2] - crop[0], crop[3] - crop[1]), (w, h));
    let (a, b) = (
        list_f64(&around.instances, "corners_px", 0),
        list_f64(&full.instances, "corners_px", 0),
    );
    for k in 0..8 {
        assert!((a[2 * k] - (b[2 * k] - crop[0])).abs() < 1e-9);
        let in_frame = (-0.5..W as f64 - 0.5).contains(&b[2 * k])
            && (-0.5..H as f64 - 0.5).contains(&b[2 * k + 1]);
        let in_crop =
            (-0.5..w - 0.5).contains(&a[2 * k]) && (-0.5..h - 0.5).contains(&a[2 * k + 1]);
        assert!(
            !in_frame || in_crop,
            "corner {k} at {:?} outside the {w}×{h} region",
            &a[2 * k..2 * k + 2]
        );
    }
}

/// The `crop` entry of a frame's `render_settings` JSON.
fn serde_json_crop(settings: &str) -> Vec<f64> {
    let start = settings
        .find("\"crop\": [")
        .expect("a crop in the settings")
        + 9;
    let end = start + settings[start..].find(']').unwrap();
    settings[start..end]
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect()
}

#[test]
fn rerender_is_identical_and_pose_changes_are_temporary() {
    let mut r = renderer();
    let first = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            ..Default::default()
        },
    );
    let t = list_f64(&first.instances, "camera_box_translation_m", 0);
    assert_eq!(t.len(), 3);
    // Lift box 2 by 3 cm for one render.
    let (_, objects) = scene_batches(7, 4);
    let (quat, trans) = (
        list_f64(&objects, "world_box_quat_wxyz", 2),
        list_f64(&objects, "world_box_translation_m", 2),
    );
    let pose = Pose {
        quat_wxyz: [quat[0], quat[1], quat[2], quat[3]],
        translation: [trans[0], trans[1], trans[2] + 0.03],
    };
    let moved = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            poses: vec![(2, pose)],
            ..Default::default()
        },
    );
    assert_ne!(
        list_f64(&moved.instances, "corners_camera_m", 2),
        list_f64(&first.instances, "corners_camera_m", 2)
    );
    assert_eq!(
        list_f64(&moved.instances, "corners_camera_m", 0),
        list_f64(&first.instances, "corners_camera_m", 0)
    );
    let again = render(
        &mut r,
        RenderRequest {
            frame_id: 0,
            ..Default::default()
        },
    );
    assert_eq!(again.instances, first.instances);
    assert_eq!(
        bytes(&again.frames, "depth_m_f32le"),
        bytes(&first.frames, "depth_m_f32le")
    );
    assert_eq!(
        bytes(&again.frames, "instance_mask_png"),
        bytes(&first.frames, "instance_mask_png")
    );
    let (a, b) = (rgb(&again.frames), rgb(&first.frames));
    let mean_diff = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum::<f64>()
        / a.len() as f64;
    assert!(
        mean_diff < 2.0,
        "re-render differs by {mean_diff} on average"
    );
}

#[test]
fn samples_and_sensor_depth_are_honoured() {
    let mut r = renderer();
    let out = render(
        &mut r,
        RenderRequest {
            frame_id: 1,
            samples: Some(2),
            sensor_depth: Some(true),
            ..Default::default()
        },
    );
    assert_eq!(int(&out.frames, "samples"), 2);
    let sensor = out.frames.column_by_name("sensor_depth_m_f32le").unwrap();
    assert!(sensor.is_valid(0));
}

#[test]
fn errors_are_clear() {
    let mut r = renderer();
    let e = r
        .render(&RenderRequest {
            crop: Some([0, 0, W + 1, 10]),
            ..Default::default()
        })
        .unwrap_err();
    assert!(e.to_string().contains("crop"), "{e}");
    let unknown = Pose {
        quat_wxyz: [1.0, 0.0, 0.0, 0.0],
        translation: [0.0; 3],
    };
    let e = r
        .render(&RenderRequest {
            poses: vec![(99, unknown)],
            ..Default::default()
        })
        .unwrap_err();
    assert!(
        matches!(e, RenderError::Input(_)) && e.to_string().contains("no object_id [99]"),
        "{e}"
    );
    let (scenes, objects) = scene_batches(7, 4);
    let e = r.load_scene(&scenes, &objects, 8).unwrap_err();
    assert!(
        e.to_string().contains("scene 8 is not in the scenes data"),
        "{e}"
    );
    assert_eq!(r.scene_id(), None);
    let e = r.render(&RenderRequest::default()).unwrap_err();
    assert!(e.to_string().contains("no scene loaded"), "{e}");
    r.load_scene(&scenes, &objects, 7).unwrap();
    // one Blender per process
    assert!(matches!(Renderer::new(0), Err(RenderError::Setup(_))));
}
