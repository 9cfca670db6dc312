//! Typed, decoded rows of the `frames` and `instances` tables.

use std::path::Path;

use crate::arrow::array::{Array, AsArray};
use crate::arrow::datatypes::{
    ArrowPrimitiveType, Float32Type, Float64Type, Int8Type, Int32Type, Int64Type,
};
use crate::arrow::record_batch::RecordBatch;

use crate::error::{DataError, Result};

/// Pinhole intrinsics in pixels (top-left pixel centre at (0, 0)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// Projects a camera-frame point (OpenCV axes) to pixel coordinates.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        [
            self.fx * p[0] / p[2] + self.cx,
            self.fy * p[1] / p[2] + self.cy,
        ]
    }
}

/// A rigid transform `T_a_b`: unit quaternion (w, x, y, z) and translation in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub quat_wxyz: [f64; 4],
    pub translation: [f64; 3],
}

/// Why a corner is or is not seen in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    Visible = 0,
    OccludedByOther = 1,
    SelfOccluded = 2,
    OutsideImage = 3,
}

impl Visibility {
    fn from_code(code: i8) -> Option<Self> {
        Some(match code {
            0 => Self::Visible,
            1 => Self::OccludedByOther,
            2 => Self::SelfOccluded,
            3 => Self::OutsideImage,
            _ => return None,
        })
    }
}

/// One physically stable scene (a `scenes` row).
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub scene_id: i64,
    pub seed: i64,
    pub recipe: String,
    pub recipe_toml: String,
    pub tool_versions: String,
    pub physics_backend: String,
    pub support: String,
    pub num_objects: i32,
    pub solver: String,
    pub solver_status: String,
    pub solve_attempts: i32,
    pub settle_time_s: f64,
    pub max_linear_speed_mps: f64,
    pub max_angular_speed_radps: f64,
    pub min_signed_distance_m: f64,
    pub stable: bool,
}

/// One box of one scene (an `objects` row).
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    pub scene_id: i64,
    pub object_id: i32,
    pub size: [f64; 3],
    /// Settled pose.
    pub world_box: Pose,
    /// Pose before the drop, after the non-penetration projection.
    pub initial_world_box: Pose,
    pub mass_kg: f64,
    pub friction: f64,
    pub base_color_rgb: [f32; 3],
    pub roughness: f32,
    pub texture_seed: i64,
    pub has_tape: bool,
    pub has_label: bool,
}

/// One box as seen in one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    pub scene_id: i64,
    pub frame_id: i32,
    pub object_id: i32,
    pub size: [f64; 3],
    pub camera_box: Pose,
    pub corners_camera: [[f64; 3]; 8],
    pub corners_px: [[f64; 2]; 8],
    pub visibility: [Visibility; 8],
    pub label_keypoints_camera: Option<[[f64; 3]; 4]>,
    pub label_keypoints_px: Option<[[f64; 2]; 4]>,
    /// (x_min, y_min, x_max, y_max), max exclusive; `None` when no pixel is visible.
    pub visible_bbox: Option<[i32; 4]>,
    pub visible_pixels: i32,
    pub visible_fraction: f32,
}

impl Instance {
    /// This box's value in its frame's `instance_mask` (object_id + 1; 0 is no box).
    pub fn mask_label(&self) -> u16 {
        (self.object_id + 1) as u16
    }
}

/// One rendered view with decoded images and the instances seen in it.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub scene_id: i64,
    pub frame_id: i32,
    pub width: usize,
    pub height: usize,
    pub intrinsics: Intrinsics,
    pub world_camera: Pose,
    pub samples: i32,
    pub denoise: bool,
    pub render_seed: i64,
    pub blender_version: String,
    /// height × width × 3, sRGB, row-major.
    pub rgb: Vec<u8>,
    /// height × width, metres along the optical axis, 0 where no surface.
    pub depth: Vec<f32>,
    /// height × width, object_id + 1 of the visible box, 0 elsewhere.
    pub instance_mask: Vec<u16>,
    pub sensor_depth: Option<Vec<f32>>,
    /// Sorted by object_id.
    pub instances: Vec<Instance>,
}

/// Typed access to one row of a validated batch; failures name the file, row and column.
struct Row<'a> {
    path: &'a Path,
    batch: &'a RecordBatch,
    row: usize,
    /// The shard row of the batch's first row, for messages.
    first_row: usize,
}

impl Row<'_> {
    fn bad(&self, column: &'static str, problem: impl Into<String>) -> DataError {
        DataError::BadValue {
            path: self.path.to_path_buf(),
            row: self.first_row + self.row,
            column,
            problem: problem.into(),
        }
    }

    fn array(&self, column: &'static str) -> &dyn Array {
        self.batch
            .column_by_name(column)
            .expect("columns were validated on read")
            .as_ref()
    }

    fn scalar<T: ArrowPrimitiveType>(&self, column: &'static str) -> T::Native {
        self.array(column).as_primitive::<T>().value(self.row)
    }

    fn string(&self, column: &'static str) -> String {
        self.array(column)
            .as_string::<i32>()
            .value(self.row)
            .to_string()
    }

    fn bytes(&self, column: &'static str) -> Option<&[u8]> {
        let array = self.array(column).as_binary::<i32>();
        array.is_valid(self.row).then(|| array.value(self.row))
    }

    /// A list column's row as an array; lengths were validated on read.
    fn list<T: ArrowPrimitiveType, const N: usize>(
        &self,
        column: &'static str,
    ) -> Option<[T::Native; N]> {
        let list = self.array(column).as_list::<i32>();
        if list.is_null(self.row) {
            return None;
        }
        let values = list.value(self.row);
        let values = values.as_primitive::<T>().values();
        Some(std::array::from_fn(|i| values[i]))
    }

    fn required<T: ArrowPrimitiveType, const N: usize>(
        &self,
        column: &'static str,
    ) -> [T::Native; N] {
        self.list::<T, N>(column)
            .expect("non-nullable columns were validated on read")
    }

    fn pose(&self, quat: &'static str, translation: &'static str) -> Pose {
        Pose {
            quat_wxyz: self.required::<Float64Type, 4>(quat),
            translation: self.required::<Float64Type, 3>(translation),
        }
    }
}

fn chunks<const K: usize, const N: usize, const M: usize>(flat: [f64; N]) -> [[f64; K]; M] {
    std::array::from_fn(|i| std::array::from_fn(|k| flat[i * K + k]))
}

impl Scene {
    pub(crate) fn from_row(path: &Path, batch: &RecordBatch, row: usize) -> Result<Self> {
        let r = Row {
            path,
            batch,
            row,
            first_row: 0,
        };
        Ok(Self {
            scene_id: r.scalar::<Int64Type>("scene_id"),
            seed: r.scalar::<Int64Type>("seed"),
            recipe: r.string("recipe"),
            recipe_toml: r.string("recipe_toml"),
            tool_versions: r.string("tool_versions"),
            physics_backend: r.string("physics_backend"),
            support: r.string("support"),
            num_objects: r.scalar::<Int32Type>("num_objects"),
            solver: r.string("solver"),
            solver_status: r.string("solver_status"),
            solve_attempts: r.scalar::<Int32Type>("solve_attempts"),
            settle_time_s: r.scalar::<Float64Type>("settle_time_s"),
            max_linear_speed_mps: r.scalar::<Float64Type>("max_linear_speed_mps"),
            max_angular_speed_radps: r.scalar::<Float64Type>("max_angular_speed_radps"),
            min_signed_distance_m: r.scalar::<Float64Type>("min_signed_distance_m"),
            stable: r.array("stable").as_boolean().value(row),
        })
    }
}

impl Object {
    pub(crate) fn from_row(path: &Path, batch: &RecordBatch, row: usize) -> Result<Self> {
        let r = Row {
            path,
            batch,
            row,
            first_row: 0,
        };
        let size = r.required::<Float64Type, 3>("size_m");
        if size.iter().any(|&s| s <= 0.0) {
            return Err(r.bad("size_m", format!("box size {size:?} must be positive")));
        }
        Ok(Self {
            scene_id: r.scalar::<Int64Type>("scene_id"),
            object_id: r.scalar::<Int32Type>("object_id"),
            size,
            world_box: r.pose("world_box_quat_wxyz", "world_box_translation_m"),
            initial_world_box: r.pose(
                "initial_world_box_quat_wxyz",
                "initial_world_box_translation_m",
            ),
            mass_kg: r.scalar::<Float64Type>("mass_kg"),
            friction: r.scalar::<Float64Type>("friction"),
            base_color_rgb: r.required::<Float32Type, 3>("base_color_rgb"),
            roughness: r.scalar::<Float32Type>("roughness"),
            texture_seed: r.scalar::<Int64Type>("texture_seed"),
            has_tape: r.array("has_tape").as_boolean().value(row),
            has_label: r.array("has_label").as_boolean().value(row),
        })
    }
}

impl Instance {
    pub(crate) fn from_row(path: &Path, batch: &RecordBatch, row: usize) -> Result<Self> {
        let r = Row {
            path,
            batch,
            row,
            first_row: 0,
        };
        let codes = r.required::<Int8Type, 8>("corner_visibility");
        let mut visibility = [Visibility::Visible; 8];
        for (v, &code) in visibility.iter_mut().zip(&codes) {
            *v = Visibility::from_code(code).ok_or_else(|| {
                r.bad(
                    "corner_visibility",
                    format!("unknown visibility code {code} (0..=3)"),
                )
            })?;
        }
        Ok(Self {
            scene_id: r.scalar::<Int64Type>("scene_id"),
            frame_id: r.scalar::<Int32Type>("frame_id"),
            object_id: r.scalar::<Int32Type>("object_id"),
            size: r.required::<Float64Type, 3>("size_m"),
            camera_box: r.pose("camera_box_quat_wxyz", "camera_box_translation_m"),
            corners_camera: chunks(r.required::<Float64Type, 24>("corners_camera_m")),
            corners_px: chunks(r.required::<Float64Type, 16>("corners_px")),
            visibility,
            label_keypoints_camera: r
                .list::<Float64Type, 12>("label_keypoints_camera_m")
                .map(chunks),
            label_keypoints_px: r.list::<Float64Type, 8>("label_keypoints_px").map(chunks),
            visible_bbox: r.list::<Int32Type, 4>("visible_bbox_px"),
            visible_pixels: r.scalar::<Int32Type>("visible_pixels"),
            visible_fraction: r.scalar::<Float32Type>("visible_fraction"),
        })
    }
}

/// Largest frame the reader decodes, 2^26 pixels (8192 × 8192): about 450 MB of decoded images.
pub const MAX_FRAME_PIXELS: u64 = 1 << 26;

impl Frame {
    /// A frame of images alone — a camera's RGB-D picture that is no dataset's render (`boxpose
    /// predict` on PNG files, a frame sent to a system under test): scene id `scene_id`, frame 0,
    /// the camera at the world's origin, no render settings, no instance (`instance_mask` as
    /// given, or all background).
    pub fn from_images(
        scene_id: i64,
        (width, height): (usize, usize),
        intrinsics: Intrinsics,
        rgb: Vec<u8>,
        depth: Vec<f32>,
        instance_mask: Option<Vec<u16>>,
    ) -> Self {
        Self {
            scene_id,
            frame_id: 0,
            width,
            height,
            intrinsics,
            world_camera: Pose {
                quat_wxyz: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0; 3],
            },
            samples: 0,
            denoise: false,
            render_seed: 0,
            blender_version: String::new(),
            rgb,
            depth,
            instance_mask: instance_mask.unwrap_or_else(|| vec![0; width * height]),
            sensor_depth: None,
            instances: Vec::new(),
        }
    }

    /// Puts the simulated sensor's depth (`sensor_depth_m_f32le`: projector shadows, edge and
    /// grazing dropouts, disparity noise; 0 where it measures nothing) in place of the exact
    /// render depth, so that whatever perceives the frame reads what a camera would measure; the
    /// ground truth (instances, masks) is untouched. False, and the frame unchanged, when it has
    /// no sensor depth.
    pub fn use_sensor_depth(&mut self) -> bool {
        match self.sensor_depth.take() {
            Some(sensor) => {
                self.depth = sensor;
                true
            }
            None => false,
        }
    }

    /// Row `row` of `batch`, whose first row is row `first_row` of the shard at `path`.
    pub(crate) fn from_row(
        path: &Path,
        batch: &RecordBatch,
        row: usize,
        first_row: usize,
    ) -> Result<Self> {
        let r = Row {
            path,
            batch,
            row,
            first_row,
        };
        let (width, height) = (
            r.scalar::<Int32Type>("width"),
            r.scalar::<Int32Type>("height"),
        );
        if width <= 0 || height <= 0 {
            return Err(r.bad("width", format!("image size {width} × {height} is empty")));
        }
        // Refused before any PNG is inflated: a few kilobytes of PNG can claim gigabytes.
        if width as u64 * height as u64 > MAX_FRAME_PIXELS {
            return Err(r.bad(
                "width",
                format!(
                    "image size {width} × {height} is over the limit of {MAX_FRAME_PIXELS} pixels"
                ),
            ));
        }
        let (width, height) = (width as usize, height as usize);
        let rgb_png = r.bytes("rgb_png").unwrap_or_default();
        let mask_png = r.bytes("instance_mask_png").unwrap_or_default();
        let depth_bytes = r.bytes("depth_m_f32le").unwrap_or_default();
        Ok(Self {
            scene_id: r.scalar::<Int64Type>("scene_id"),
            frame_id: r.scalar::<Int32Type>("frame_id"),
            width,
            height,
            intrinsics: Intrinsics {
                fx: r.scalar::<Float64Type>("fx"),
                fy: r.scalar::<Float64Type>("fy"),
                cx: r.scalar::<Float64Type>("cx"),
                cy: r.scalar::<Float64Type>("cy"),
            },
            world_camera: r.pose("world_camera_quat_wxyz", "world_camera_translation_m"),
            samples: r.scalar::<Int32Type>("samples"),
            denoise: r.array("denoise").as_boolean().value(row),
            render_seed: r.scalar::<Int64Type>("render_seed"),
            blender_version: r.string("blender_version"),
            rgb: decode_png(
                &r,
                "rgb_png",
                rgb_png,
                width,
                height,
                png::ColorType::Rgb,
                png::BitDepth::Eight,
            )?,
            depth: decode_depth(&r, "depth_m_f32le", depth_bytes, width, height)?,
            instance_mask: decode_png(
                &r,
                "instance_mask_png",
                mask_png,
                width,
                height,
                png::ColorType::Grayscale,
                png::BitDepth::Sixteen,
            )?
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect(),
            sensor_depth: r
                .bytes("sensor_depth_m_f32le")
                .map(|bytes| decode_depth(&r, "sensor_depth_m_f32le", bytes, width, height))
                .transpose()?,
            instances: Vec::new(),
        })
    }
}

/// Decodes a PNG that must have exactly the given size, colour type and bit depth; returns the
/// raw bytes (16-bit samples big-endian, as PNG stores them).
fn decode_png(
    r: &Row,
    column: &'static str,
    bytes: &[u8],
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: png::BitDepth,
) -> Result<Vec<u8>> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(|e| r.bad(column, format!("not a decodable PNG: {e}")))?;
    let info = reader.info();
    let found = (
        info.width as usize,
        info.height as usize,
        info.color_type,
        info.bit_depth,
    );
    if found != (width, height, color, depth) {
        return Err(r.bad(
            column,
            format!(
                "PNG is {}×{} {:?} {:?}-bit, expected {width}×{height} {color:?} {depth:?}-bit",
                found.0, found.1, found.2, found.3
            ),
        ));
    }
    let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let frame = reader
        .next_frame(&mut buf)
        .map_err(|e| r.bad(column, format!("PNG decode failed: {e}")))?;
    buf.truncate(frame.buffer_size());
    Ok(buf)
}

fn decode_depth(
    r: &Row,
    column: &'static str,
    bytes: &[u8],
    width: usize,
    height: usize,
) -> Result<Vec<f32>> {
    if bytes.len() != width * height * 4 {
        return Err(r.bad(
            column,
            format!("{} bytes, expected {width}×{height}×4", bytes.len()),
        ));
    }
    let depth: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if let Some(i) = depth.iter().position(|d| !d.is_finite() || *d < 0.0) {
        return Err(r.bad(
            column,
            format!(
                "depth {} at pixel ({}, {}) is not a finite non-negative distance",
                depth[i],
                i % width,
                i / width
            ),
        ));
    }
    Ok(depth)
}

/// Builders of contract batches from typed rows, the inverse of the readers' `from_row`: a Rust
/// stage that makes scenes (the counterexample search) writes them with the same schema as the
/// Python stages.
mod to_batch {
    use std::sync::Arc;

    use crate::arrow::array::{
        ArrayRef, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array, ListArray,
        StringArray,
    };
    use crate::arrow::datatypes::{ArrowPrimitiveType, Float32Type, Float64Type};
    use crate::arrow::record_batch::RecordBatch;

    use super::{Object, Pose, Scene};
    use crate::schema::{self, Table};

    fn list<T: ArrowPrimitiveType, const N: usize>(
        rows: impl Iterator<Item = [T::Native; N]>,
    ) -> ArrayRef {
        Arc::new(ListArray::from_iter_primitive::<T, _, _>(
            rows.map(|r| Some(r.map(Some))),
        ))
    }

    fn batch(table: &Table, columns: Vec<ArrayRef>) -> RecordBatch {
        RecordBatch::try_new(Arc::new(table.arrow_schema()), columns)
            .expect("columns built in contract order and types")
    }

    fn quats<'a>(poses: impl Iterator<Item = &'a Pose>) -> ArrayRef {
        list::<Float64Type, 4>(poses.map(|p| p.quat_wxyz))
    }

    fn translations<'a>(poses: impl Iterator<Item = &'a Pose>) -> ArrayRef {
        list::<Float64Type, 3>(poses.map(|p| p.translation))
    }

    impl Scene {
        /// `rows` as one `scenes` batch with the contract schema.
        pub fn to_batch(rows: &[Scene]) -> RecordBatch {
            let text = |f: fn(&Scene) -> &str| {
                Arc::new(rows.iter().map(|r| Some(f(r))).collect::<StringArray>()) as ArrayRef
            };
            let float = |f: fn(&Scene) -> f64| {
                Arc::new(rows.iter().map(f).collect::<Float64Array>()) as ArrayRef
            };
            batch(
                &schema::SCENES,
                vec![
                    Arc::new(rows.iter().map(|r| r.scene_id).collect::<Int64Array>()),
                    Arc::new(rows.iter().map(|r| r.seed).collect::<Int64Array>()),
                    text(|r| &r.recipe),
                    text(|r| &r.recipe_toml),
                    text(|r| &r.tool_versions),
                    text(|r| &r.physics_backend),
                    text(|r| &r.support),
                    Arc::new(rows.iter().map(|r| r.num_objects).collect::<Int32Array>()),
                    text(|r| &r.solver),
                    text(|r| &r.solver_status),
                    Arc::new(
                        rows.iter()
                            .map(|r| r.solve_attempts)
                            .collect::<Int32Array>(),
                    ),
                    float(|r| r.settle_time_s),
                    float(|r| r.max_linear_speed_mps),
                    float(|r| r.max_angular_speed_radps),
                    float(|r| r.min_signed_distance_m),
                    Arc::new(
                        rows.iter()
                            .map(|r| Some(r.stable))
                            .collect::<BooleanArray>(),
                    ),
                ],
            )
        }
    }

    impl Object {
        /// `rows` as one `objects` batch with the contract schema.
        pub fn to_batch(rows: &[Object]) -> RecordBatch {
            batch(
                &schema::OBJECTS,
                vec![
                    Arc::new(rows.iter().map(|r| r.scene_id).collect::<Int64Array>()),
                    Arc::new(rows.iter().map(|r| r.object_id).collect::<Int32Array>()),
                    list::<Float64Type, 3>(rows.iter().map(|r| r.size)),
                    quats(rows.iter().map(|r| &r.world_box)),
                    translations(rows.iter().map(|r| &r.world_box)),
                    quats(rows.iter().map(|r| &r.initial_world_box)),
                    translations(rows.iter().map(|r| &r.initial_world_box)),
                    Arc::new(rows.iter().map(|r| r.mass_kg).collect::<Float64Array>()),
                    Arc::new(rows.iter().map(|r| r.friction).collect::<Float64Array>()),
                    list::<Float32Type, 3>(rows.iter().map(|r| r.base_color_rgb)),
                    Arc::new(rows.iter().map(|r| r.roughness).collect::<Float32Array>()),
                    Arc::new(rows.iter().map(|r| r.texture_seed).collect::<Int64Array>()),
                    Arc::new(
                        rows.iter()
                            .map(|r| Some(r.has_tape))
                            .collect::<BooleanArray>(),
                    ),
                    Arc::new(
                        rows.iter()
                            .map(|r| Some(r.has_label))
                            .collect::<BooleanArray>(),
                    ),
                ],
            )
        }
    }
}
