//! The dataset contract: every table, column, type, unit and frame, written once.
//!
//! Everything else derives from [`TABLES`] (and [`crate::support`], the geometries the `support`
//! column names): the Arrow schemas used by the Rust reader and writers, the JSON definition the
//! Python stages load (`python/boxpose_io/schema.json`), and the column reference in
//! `docs/dataset.md`. Tests fail when either generated file drifts.
//!
//! Conventions (docs/dataset.md, docs/design.md): metres, radians, seconds; poses `T_a_b` map points in frame b
//! into frame a and are stored as a unit quaternion (w, x, y, z) plus a translation; camera
//! frames follow OpenCV (x right, y down, z forward); pixel coordinates put the centre of the
//! top-left pixel at (0, 0); box corner i has sign pattern bit0 → x, bit1 → y, bit2 → z
//! (0 = −, 1 = +).

use crate::arrow::datatypes::{DataType, Field, Schema};

/// Version of the contract. Bump it on any change to [`TABLES`]; readers refuse other versions.
pub const SCHEMA_VERSION: u32 = 1;

/// Parquet key-value metadata key holding [`SCHEMA_VERSION`].
pub const VERSION_KEY: &str = "boxpose.schema_version";
/// Parquet key-value metadata key holding the table name, so a misplaced shard is caught.
pub const TABLE_KEY: &str = "boxpose.table";

/// Element types a column can hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scalar {
    Bool,
    Int8,
    Int32,
    Int64,
    Float32,
    Float64,
    Utf8,
    Binary,
}

impl Scalar {
    fn arrow(self) -> DataType {
        match self {
            Scalar::Bool => DataType::Boolean,
            Scalar::Int8 => DataType::Int8,
            Scalar::Int32 => DataType::Int32,
            Scalar::Int64 => DataType::Int64,
            Scalar::Float32 => DataType::Float32,
            Scalar::Float64 => DataType::Float64,
            Scalar::Utf8 => DataType::Utf8,
            Scalar::Binary => DataType::Binary,
        }
    }

    /// The type's name in the JSON definition; Python maps it with `getattr(pyarrow, name)()`.
    fn name(self) -> &'static str {
        match self {
            Scalar::Bool => "bool_",
            Scalar::Int8 => "int8",
            Scalar::Int32 => "int32",
            Scalar::Int64 => "int64",
            Scalar::Float32 => "float32",
            Scalar::Float64 => "float64",
            Scalar::Utf8 => "string",
            Scalar::Binary => "binary",
        }
    }
}

/// One column of one table.
#[derive(Debug, Clone, Copy)]
pub struct Column {
    pub name: &'static str,
    pub scalar: Scalar,
    /// `Some(n)`: a list of exactly n elements (a vector, quaternion or flattened matrix);
    /// `Some(`[`ANY_LENGTH`]`)`: a list of any length (a search's parameter vector).
    pub list_size: Option<i32>,
    pub nullable: bool,
    /// Unit and frame, e.g. "m, camera frame"; empty where none applies.
    pub unit: &'static str,
    pub doc: &'static str,
    /// Closed interval every value (every element, for a list) must lie in, where the column has
    /// one: ids that index masks, visibility codes, fractions.
    pub range: Option<(f64, f64)>,
}

impl Column {
    /// Vectors are variable-length Arrow lists holding exactly `list_size` elements: Parquet has no
    /// fixed-size list, and pyarrow cannot write a null fixed-size list. The reader checks lengths.
    pub fn arrow_type(&self) -> DataType {
        match self.list_size {
            None => self.scalar.arrow(),
            Some(_) => DataType::new_list(self.scalar.arrow(), true),
        }
    }

    pub fn field(&self) -> Field {
        Field::new(self.name, self.arrow_type(), self.nullable)
    }
}

/// One table of the dataset: a folder of Parquet shards named after it.
#[derive(Debug, Clone, Copy)]
pub struct Table {
    pub name: &'static str,
    pub doc: &'static str,
    /// Columns that identify a row; rows of other tables join on them.
    pub key: &'static [&'static str],
    /// Rows per Parquet row group where it must be small: a reader holds a whole row group in
    /// memory, and a frame is about a megabyte of images. None: the writer's default.
    pub row_group_rows: Option<usize>,
    pub columns: &'static [Column],
}

impl Table {
    pub fn column(&self, name: &str) -> Option<&'static Column> {
        self.columns.iter().find(|c| c.name == name)
    }

    /// The Arrow schema of this table's shards, with the version and table name in its metadata.
    pub fn arrow_schema(&self) -> Schema {
        let metadata: std::collections::HashMap<String, String> = [
            (VERSION_KEY.to_string(), SCHEMA_VERSION.to_string()),
            (TABLE_KEY.to_string(), self.name.to_string()),
        ]
        .into();
        Schema::new(self.columns.iter().map(Column::field).collect::<Vec<_>>())
            .with_metadata(metadata)
    }
}

const fn col(name: &'static str, scalar: Scalar, unit: &'static str, doc: &'static str) -> Column {
    Column {
        name,
        scalar,
        list_size: None,
        nullable: false,
        unit,
        doc,
        range: None,
    }
}

/// `column` whose values must lie in [min, max].
const fn within(column: Column, min: f64, max: f64) -> Column {
    Column {
        range: Some((min, max)),
        ..column
    }
}

/// Largest object id: the instance mask stores object_id + 1 in 16 bits, 0 being the background.
pub const MAX_OBJECT_ID: i32 = u16::MAX as i32 - 1;

const fn list(
    name: &'static str,
    scalar: Scalar,
    n: i32,
    unit: &'static str,
    doc: &'static str,
) -> Column {
    Column {
        name,
        scalar,
        list_size: Some(n),
        nullable: false,
        unit,
        doc,
        range: None,
    }
}

/// The `list_size` of a list column whose rows may hold any number of elements.
pub const ANY_LENGTH: i32 = 0;

const fn nullable(c: Column) -> Column {
    Column {
        nullable: true,
        ..c
    }
}

use Scalar::*;

const SCENE_ID: Column = within(
    col(
        "scene_id",
        Int64,
        "",
        "Scene index within the dataset (0-based, unique across shards).",
    ),
    0.0,
    1e12, // far above any dataset; short enough that every JSON parser reads it exactly
);
const FRAME_ID: Column = within(
    col(
        "frame_id",
        Int32,
        "",
        "View index within the scene (0-based).",
    ),
    0.0,
    i32::MAX as f64,
);
const OBJECT_ID: Column = within(
    col(
        "object_id",
        Int32,
        "",
        "Box index within the scene (0-based). Its pixels in `instance_mask_png` hold object_id + 1.",
    ),
    0.0,
    MAX_OBJECT_ID as f64,
);
const SIZE: Column = list(
    "size_m",
    Float64,
    3,
    "m, box frame",
    "Edge lengths (dx, dy, dz) along the box axes.",
);

pub const SCENES: Table = Table {
    name: "scenes",
    doc: "One row per physically stable scene, with everything needed to regenerate it.",
    key: &["scene_id"],
    row_group_rows: None,
    columns: &[
        SCENE_ID,
        col(
            "seed",
            Int64,
            "",
            "Seed of this scene, derived from the recipe seed and scene_id.",
        ),
        col(
            "recipe",
            Utf8,
            "",
            "Recipe name (file stem under datasets/recipes/).",
        ),
        col(
            "recipe_toml",
            Utf8,
            "",
            "Full text of the recipe the scene was generated from.",
        ),
        col(
            "tool_versions",
            Utf8,
            "",
            "JSON object of tool versions, e.g. {\"drake\": \"1.51.1\", \"python\": \"3.11.7\"}.",
        ),
        col(
            "physics_backend",
            Utf8,
            "",
            "Simulator that settled the scene: \"drake\" or \"mujoco\".",
        ),
        col(
            "support",
            Utf8,
            "",
            "Support surface: \"floor\", \"bin\" or \"pallet\".",
        ),
        col(
            "num_objects",
            Int32,
            "",
            "Number of boxes in the scene (rows in `objects`).",
        ),
        col(
            "solver",
            Utf8,
            "",
            "Solver of the non-penetration projection: \"SNOPT\" or \"IPOPT\".",
        ),
        col(
            "solver_status",
            Utf8,
            "",
            "Solver result of the accepted projection.",
        ),
        col(
            "solve_attempts",
            Int32,
            "",
            "Projection attempts used (jittered retries after a failure).",
        ),
        col(
            "settle_time_s",
            Float64,
            "s",
            "Simulated time until the scene was certified at rest.",
        ),
        col(
            "max_linear_speed_mps",
            Float64,
            "m/s",
            "Largest body linear speed over the final rest window.",
        ),
        col(
            "max_angular_speed_radps",
            Float64,
            "rad/s",
            "Largest body angular speed over the final rest window.",
        ),
        col(
            "min_signed_distance_m",
            Float64,
            "m",
            "Smallest signed distance between any two bodies (support included) in the settled scene; negative = penetration.",
        ),
        col(
            "stable",
            Bool,
            "",
            "True when every stability check passed. Only stable scenes are written.",
        ),
    ],
};

pub const OBJECTS: Table = Table {
    name: "objects",
    doc: "One row per box per scene: its size, settled pose, physical and material parameters.",
    key: &["scene_id", "object_id"],
    row_group_rows: None,
    columns: &[
        SCENE_ID,
        OBJECT_ID,
        SIZE,
        list(
            "world_box_quat_wxyz",
            Float64,
            4,
            "world frame",
            "Rotation of T_world_box (settled pose), unit quaternion.",
        ),
        list(
            "world_box_translation_m",
            Float64,
            3,
            "m, world frame",
            "Translation of T_world_box: the box centre.",
        ),
        list(
            "initial_world_box_quat_wxyz",
            Float64,
            4,
            "world frame",
            "Rotation of T_world_box before the drop (after the non-penetration projection).",
        ),
        list(
            "initial_world_box_translation_m",
            Float64,
            3,
            "m, world frame",
            "Translation of T_world_box before the drop.",
        ),
        col("mass_kg", Float64, "kg", "Mass (uniform density)."),
        col(
            "friction",
            Float64,
            "",
            "Coulomb friction coefficient (static = dynamic).",
        ),
        list(
            "base_color_rgb",
            Float32,
            3,
            "linear RGB in [0, 1]",
            "Cardboard base colour.",
        ),
        col(
            "roughness",
            Float32,
            "",
            "Principled BSDF roughness in [0, 1].",
        ),
        col(
            "texture_seed",
            Int64,
            "",
            "Seed of the procedural cardboard texture, tape and label placement.",
        ),
        col(
            "has_tape",
            Bool,
            "",
            "Whether tape strips are drawn on the box.",
        ),
        col(
            "has_label",
            Bool,
            "",
            "Whether a printed label is drawn on the box's +z face.",
        ),
    ],
};

pub const FRAMES: Table = Table {
    name: "frames",
    doc: "One row per rendered view: camera, render settings and the images themselves.",
    key: &["scene_id", "frame_id"],
    row_group_rows: Some(16),
    columns: &[
        SCENE_ID,
        FRAME_ID,
        within(col("width", Int32, "px", "Image width."), 1.0, 65535.0),
        within(col("height", Int32, "px", "Image height."), 1.0, 65535.0),
        col(
            "fx",
            Float64,
            "px",
            "Focal length along x (pinhole, no distortion).",
        ),
        col("fy", Float64, "px", "Focal length along y."),
        col(
            "cx",
            Float64,
            "px",
            "Principal point x (top-left pixel centre = 0).",
        ),
        col("cy", Float64, "px", "Principal point y."),
        list(
            "world_camera_quat_wxyz",
            Float64,
            4,
            "world frame",
            "Rotation of T_world_camera (OpenCV camera axes).",
        ),
        list(
            "world_camera_translation_m",
            Float64,
            3,
            "m, world frame",
            "Camera centre in the world.",
        ),
        col(
            "render_seed",
            Int64,
            "",
            "Seed of the Cycles sampler and of the lighting draw.",
        ),
        col("samples", Int32, "", "Cycles samples per pixel."),
        col("denoise", Bool, "", "Whether OpenImageDenoise was applied."),
        col(
            "blender_version",
            Utf8,
            "",
            "Blender (bpy) version that rendered the frame.",
        ),
        col(
            "render_settings",
            Utf8,
            "",
            "JSON object of everything else the render depends on (lights, world colour, exposure), for exact re-rendering.",
        ),
        col(
            "render_time_s",
            Float64,
            "s",
            "Wall time of the render on the generating machine.",
        ),
        col("rgb_png", Binary, "", "8-bit sRGB PNG, height × width × 3."),
        col(
            "depth_m_f32le",
            Binary,
            "m, camera frame",
            "Depth along the optical axis (planar z, not ray length): little-endian float32, height × width, row-major; 0 where no surface.",
        ),
        col(
            "instance_mask_png",
            Binary,
            "",
            "16-bit grayscale PNG, height × width: object_id + 1 of the box seen at each pixel, 0 for support and background.",
        ),
        nullable(col(
            "sensor_depth_m_f32le",
            Binary,
            "m, camera frame",
            "Optional simulated structured-light depth, same layout as depth_m_f32le; 0 where the sensor returns nothing.",
        )),
    ],
};

pub const INSTANCES: Table = Table {
    name: "instances",
    doc: "One row per box per frame, including boxes that are fully hidden or outside the image.",
    key: &["scene_id", "frame_id", "object_id"],
    row_group_rows: None,
    columns: &[
        SCENE_ID,
        FRAME_ID,
        OBJECT_ID,
        SIZE,
        list(
            "camera_box_quat_wxyz",
            Float64,
            4,
            "camera frame",
            "Rotation of T_camera_box.",
        ),
        list(
            "camera_box_translation_m",
            Float64,
            3,
            "m, camera frame",
            "Box centre in the camera frame.",
        ),
        list(
            "corners_camera_m",
            Float64,
            24,
            "m, camera frame",
            "The 8 corners, 8 × 3 row-major, in corner order.",
        ),
        list(
            "corners_px",
            Float64,
            16,
            "px",
            "The 8 corners projected, 8 × (u, v) row-major.",
        ),
        within(
            list(
                "corner_visibility",
                Int8,
                8,
                "",
                "Per corner: 0 visible, 1 occluded by another object, 2 self-occluded, 3 outside the image (or behind the camera).",
            ),
            0.0,
            3.0,
        ),
        nullable(list(
            "label_keypoints_camera_m",
            Float64,
            12,
            "m, camera frame",
            "Corners of the printed label (4 × 3), null when the box has no label.",
        )),
        nullable(list(
            "label_keypoints_px",
            Float64,
            8,
            "px",
            "Label corners projected, 4 × (u, v).",
        )),
        nullable(list(
            "visible_bbox_px",
            Int32,
            4,
            "px",
            "Bounding box of the visible mask: (x_min, y_min, x_max, y_max), max exclusive; null when no pixel is visible.",
        )),
        col(
            "visible_pixels",
            Int32,
            "px",
            "Pixels of this box in the instance mask.",
        ),
        within(
            col(
                "visible_fraction",
                Float32,
                "",
                "visible_pixels / pixels the box would cover in the image were nothing in front of it.",
            ),
            0.0,
            1.0,
        ),
    ],
};

const SAMPLE_ID: Column = col(
    "sample_id",
    Int64,
    "",
    "Sample index within the search run (0-based, unique; tuning iterations first).",
);

/// One row per sample of a counterexample search (`boxpose search`): its inputs, weights,
/// outcome and metrics. The metric columns are null when the sample was not scored.
pub const SEARCH_SAMPLES: Table = Table {
    name: "samples",
    doc: "One row per sample of a `boxpose search` run, in sample_id order (the run folder's `samples.parquet`).",
    key: &["sample_id"],
    row_group_rows: None,
    columns: &[
        SAMPLE_ID,
        col(
            "sampler",
            Utf8,
            "",
            "`mc` (Monte Carlo) or `ce` (cross-entropy importance sampling).",
        ),
        col(
            "stage",
            Utf8,
            "",
            "`mc`; for `ce`: `tune` (an iteration that moves the proposal) or `final` (the frozen proposal the estimate is formed from).",
        ),
        col(
            "iteration",
            Int32,
            "",
            "Sampler iteration (0 for `mc`; the final stage comes after the last tuning iteration).",
        ),
        col(
            "stratum",
            Int32,
            "",
            "The discrete parameter's value: the number of neighbouring boxes.",
        ),
        col(
            "seed",
            Int64,
            "",
            "Seed of the sample's nuisance draws (box masses, frictions, appearance, lights' other draws, Cycles sampler).",
        ),
        list(
            "z",
            Float64,
            ANY_LENGTH,
            "",
            "The standard normals the scene is a deterministic function of, in the space's dimension order (run.json `dimensions`).",
        ),
        list(
            "params",
            Float64,
            ANY_LENGTH,
            "m, deg",
            "The parameter values z maps to, same order (orientation: the raw normals).",
        ),
        col(
            "log_nominal",
            Float64,
            "",
            "log p(z), the nominal density N(0, I).",
        ),
        col(
            "log_proposal",
            Float64,
            "",
            "log q(z), the density z was drawn from (equals log_nominal for Monte Carlo).",
        ),
        col(
            "log_weight",
            Float64,
            "",
            "log p(z) − log q(z), the importance weight's log.",
        ),
        col(
            "valid",
            Bool,
            "",
            "The scene settled stably and the target is visible enough to be scored.",
        ),
        nullable(col(
            "invalid_reason",
            Utf8,
            "",
            "Why the sample was not scored (not stable: …, target N% visible).",
        )),
        nullable(col(
            "target_visible_fraction",
            Float32,
            "",
            "Visible fraction of the target box in the rendered frame.",
        )),
        nullable(col(
            "detected",
            Bool,
            "",
            "The target was found (always true with ground-truth crops).",
        )),
        nullable(col(
            "fit_error",
            Utf8,
            "",
            "Why the pose fit failed, when it did.",
        )),
        nullable(col(
            "paper_error",
            Float64,
            "m²",
            "The paper's error: mean squared distance of the fitted corners to the true ones.",
        )),
        nullable(col(
            "paper_error_normalized",
            Float64,
            "",
            "paper_error / (diag² / 3): the paper's unit-box threshold 0.005 applies to any box.",
        )),
        nullable(col(
            "mssd_over_diameter",
            Float64,
            "",
            "MSSD (BOP) of the fit over the box's diameter: the orientation-aware error.",
        )),
        nullable(col(
            "cube_mssd_over_diameter",
            Float64,
            "",
            "Corner MSSD modulo the cube's 24 rotations over the box's diameter: how far the fitted corners really are from the true ones.",
        )),
        nullable(col("add_s_m", Float64, "m", "ADD-S of the fit.")),
        nullable(col(
            "rotation_error_deg",
            Float64,
            "deg",
            "Rotation error modulo the box's symmetries.",
        )),
        nullable(col(
            "translation_error_m",
            Float64,
            "m",
            "Distance between fitted and true centres.",
        )),
        nullable(col(
            "score",
            Float64,
            "",
            "The failure score log10(metric / threshold): > 0 is a failure; null when not scored or when nothing was fitted.",
        )),
        nullable(col(
            "fit_confidence",
            Float64,
            "",
            "The fit's own confidence in [0, 1) (geometry `FitConfidence`): how much better its pose explains the peaks than the best different pose.",
        )),
        col(
            "failed",
            Bool,
            "",
            "Valid and the failure predicate holds (metric above threshold, not detected, or fit failed).",
        ),
        nullable(list(
            "peaks_camera_m",
            Float64,
            ANY_LENGTH,
            "m, camera frame",
            "The target's NMS peaks back-projected, x y z per peak, best first.",
        )),
        nullable(list(
            "fitted_corners_camera_m",
            Float64,
            24,
            "m, camera frame",
            "The fitted box's 8 corners, x y z each, in corner order.",
        )),
    ],
};

/// Wall-clock seconds per stage of each search sample, apart from [`SEARCH_SAMPLES`] so that a
/// resumed run's samples table is byte-identical to an uninterrupted one's.
pub const SEARCH_TIMINGS: Table = Table {
    name: "timings",
    doc: "Seconds per stage of each `boxpose search` sample (the run folder's `timings.parquet`).",
    key: &["sample_id"],
    row_group_rows: None,
    columns: &[
        SAMPLE_ID,
        col(
            "settle_s",
            Float64,
            "s",
            "Scene building and MuJoCo drop-and-settle.",
        ),
        col(
            "render_s",
            Float64,
            "s",
            "Embedded Blender: scene load and Cycles render.",
        ),
        col(
            "inference_s",
            Float64,
            "s",
            "Segmenter (predicted crops), crop, keypoint network, NMS.",
        ),
        col("fit_s", Float64, "s", "Every pose fit and its metrics."),
    ],
};

/// Result tables: written by boxpose's commands, not part of a dataset.
// The fit confidence columns that the fit tables and the predictions share.
const CONFIDENCE: Column = nullable(col(
    "confidence",
    Float64,
    "",
    "The fit's confidence in [0, 1]: the robust fits' own, the noise-adaptive assessment of the fitted pose for the others.",
));

const MARGIN_NATS: Column = nullable(col(
    "margin_nats",
    Float64,
    "nats",
    "Log-likelihood margin over the best different box hypothesis; null when there is none (an infinite margin).",
));

const NOISE_SCALE_M: Column = nullable(col(
    "noise_scale_m",
    Float64,
    "m",
    "Noise scale the adaptive cost estimated from the inliers.",
));

const MIRROR_AMBIGUOUS: Column = nullable(col(
    "mirror_ambiguous",
    Bool,
    "",
    "Whether a mirror-image box explains the peaks almost as well.",
));

/// One row per instance and pose fit: the columns that `eval-geometry` writes, and `eval` too.
const FIT_COLUMNS: [Column; 19] = [
    SCENE_ID,
    FRAME_ID,
    OBJECT_ID,
    col(
        "method",
        Utf8,
        "",
        "The fit: paper_exact, fast_exact, robust, size_and_pose, robust_fixed or size_and_pose_ls; external for another system's answer (`eval --sut`, whose rows leave null what it does not report: margin, noise scale, inliers, mirror ambiguity, heatmap).",
    ),
    col(
        "diameter_m",
        Float64,
        "m",
        "The true box's diagonal (MSSD thresholds are fractions of it).",
    ),
    nullable(col(
        "paper_error",
        Float64,
        "m²",
        "The paper's error (mean squared distance of each fitted corner to the nearest true corner); null where the fit failed, as every metric.",
    )),
    nullable(col(
        "mssd_m",
        Float64,
        "m",
        "Maximum symmetry-aware surface distance (BOP's MSSD, over the box's corners): the orientation-aware error, which also asks for the right quarter turn of a box with two nearly equal sides.",
    )),
    nullable(col(
        "cube_mssd_m",
        Float64,
        "m",
        "Corner MSSD modulo the cube's 24 rotations: the largest distance between fitted and true corners under the corner labelling that matches them best (the primary correctness metric; never above mssd_m for a fit of known size).",
    )),
    nullable(col(
        "iou_3d",
        Float64,
        "",
        "3D IoU of the fitted box (its own size for a size fit) and the true box.",
    )),
    nullable(col(
        "add_s_m",
        Float64,
        "m",
        "ADD-S (BOP's adi) over a uniform grid of the box surface.",
    )),
    nullable(col(
        "rotation_error_deg",
        Float64,
        "deg",
        "Angle of the rotation between fitted and true pose, over the box's symmetries.",
    )),
    nullable(col(
        "translation_error_m",
        Float64,
        "m",
        "Distance between fitted and true box centres.",
    )),
    nullable(col(
        "fit_time_us",
        Float64,
        "µs",
        "Wall time of the fit (for `eval --sut`, of the whole call to the system).",
    )),
    CONFIDENCE,
    MARGIN_NATS,
    NOISE_SCALE_M,
    nullable(col(
        "inliers",
        Int32,
        "",
        "Peaks the fit counts as inliers.",
    )),
    MIRROR_AMBIGUOUS,
    nullable(col(
        "fit_error",
        Utf8,
        "",
        "Why the fit failed (the geometry error, or \"not found by the segmenter\"); null where it returned a pose.",
    )),
];

/// [`FIT_COLUMNS`], then what `eval` adds per instance.
const EVAL_COLUMNS: [Column; FIT_COLUMNS.len() + 2] = {
    let mut columns = [FIT_COLUMNS[0]; FIT_COLUMNS.len() + 2];
    let mut i = 0;
    while i < FIT_COLUMNS.len() {
        columns[i] = FIT_COLUMNS[i];
        i += 1;
    }
    columns[FIT_COLUMNS.len()] = nullable(col(
        "heatmap_mse",
        Float64,
        "",
        "Mean squared error of the predicted heatmap against the target; null where the segmenter missed the box, and for another system (`eval --sut`).",
    ));
    columns[FIT_COLUMNS.len() + 1] = col(
        "corners_found",
        Int32,
        "",
        "True corners with an NMS peak (for `eval --sut`, a peak the system reported) within the recall radius.",
    );
    columns
};

pub const EVAL_GEOMETRY: Table = Table {
    name: "eval_geometry",
    doc: "One row per instance and pose fit on ground-truth heatmaps (`boxpose eval-geometry`'s Parquet).",
    key: &["scene_id", "frame_id", "object_id", "method"],
    row_group_rows: None,
    columns: &FIT_COLUMNS,
};

pub const EVAL: Table = Table {
    name: "eval",
    doc: "One row per instance and pose fit on the keypoint network's heatmaps (`boxpose eval`'s `eval.parquet`).",
    key: &["scene_id", "frame_id", "object_id", "method"],
    row_group_rows: None,
    columns: &EVAL_COLUMNS,
};

pub const PREDICTIONS: Table = Table {
    name: "predictions",
    doc: "One row per box `boxpose predict` found or was given in one frame (its `predictions.parquet`); the fit's columns are null where it failed.",
    key: &["scene_id", "frame_id", "bbox"],
    row_group_rows: None,
    columns: &[
        SCENE_ID,
        FRAME_ID,
        nullable(within(
            col(
                "object_id",
                Int32,
                "",
                "The dataset box this one is matched to; null for a box of an image file or one that matches none.",
            ),
            0.0,
            MAX_OBJECT_ID as f64,
        )),
        list(
            "bbox",
            Int32,
            4,
            "px",
            "The crop's box (x_min, y_min, x_max, y_max), max exclusive: given with --bbox, the ground truth's, or the segmenter's.",
        ),
        col(
            "reference_depth_m",
            Float64,
            "m",
            "The crop's reference depth, which the network's depth bins are relative to.",
        ),
        nullable(list(
            "pose_quat_wxyz",
            Float64,
            4,
            "",
            "Fitted rotation, camera frame (T_camera_box).",
        )),
        nullable(list(
            "pose_translation_m",
            Float64,
            3,
            "m, camera frame",
            "Fitted box centre.",
        )),
        nullable(list("size_m", Float64, 3, "m", "Fitted (dx, dy, dz).")),
        nullable(list(
            "corners_camera_m",
            Float64,
            24,
            "m, camera frame",
            "The fitted box's 8 corners, 8 × (x, y, z) row-major, in the contract's corner order.",
        )),
        list(
            "peaks_camera_m",
            Float64,
            ANY_LENGTH,
            "m, camera frame",
            "The NMS peaks back-projected, n × (x, y, z), best first.",
        ),
        list(
            "peak_scores",
            Float32,
            ANY_LENGTH,
            "",
            "The peaks' heatmap values, best first.",
        ),
        nullable(col(
            "inlier_count",
            Int32,
            "",
            "Peaks the fit used (least squares counts every peak).",
        )),
        nullable(col(
            "inlier_rms_m",
            Float64,
            "m",
            "RMS distance of the inlier peaks to their fitted corners.",
        )),
        col(
            "size_fit",
            Utf8,
            "",
            "The size-and-pose fit used: robust or least-squares.",
        ),
        CONFIDENCE,
        MARGIN_NATS,
        nullable(col(
            "confidence_inliers",
            Int32,
            "",
            "Peaks the noise-adaptive cost takes as inliers.",
        )),
        NOISE_SCALE_M,
        MIRROR_AMBIGUOUS,
        nullable(col(
            "fit_error",
            Utf8,
            "",
            "Why the fit failed; null where it returned a pose.",
        )),
    ],
};

pub const EVAL_RESULTS: Table = Table {
    name: "eval_results",
    doc: "One row per ground-truth instance of a dataset scored against another method's BOP results (`boxpose eval-results`' `eval_results.parquet`); the metrics are null where no estimate matched.",
    key: &["scene_id", "im_id", "gt_id"],
    row_group_rows: None,
    columns: &[
        SCENE_ID,
        within(
            col(
                "im_id",
                Int32,
                "",
                "The frame (BOP's image id, the dataset's frame_id).",
            ),
            0.0,
            i32::MAX as f64,
        ),
        col(
            "gt_id",
            Int32,
            "",
            "The instance's rank in its frame, as `export bop` orders them.",
        ),
        OBJECT_ID,
        col(
            "obj_id",
            Int32,
            "",
            "BOP object id (one per distinct box size, as `export bop` numbers them).",
        ),
        col(
            "visib_fract",
            Float32,
            "",
            "The instance's visible fraction.",
        ),
        nullable(col("diameter_m", Float64, "m", "The true box's diagonal.")),
        col(
            "matched",
            Bool,
            "",
            "Whether an estimate was matched to this instance (score order per frame and object, as bop_toolkit).",
        ),
        nullable(col(
            "csv_line",
            Int64,
            "",
            "The matched estimate's line in the results CSV.",
        )),
        nullable(col("score", Float64, "", "The matched estimate's score.")),
        nullable(col("mssd_m", Float64, "m", "MSSD of the matched estimate.")),
        nullable(col(
            "cube_mssd_m",
            Float64,
            "m",
            "Corner MSSD modulo the cube's rotations of the matched estimate (the primary metric).",
        )),
        nullable(col("add_s_m", Float64, "m", "ADD-S (BOP's adi).")),
        nullable(col(
            "mspd_px",
            Float64,
            "px",
            "MSPD of the matched estimate: the corners' largest shift in the image, modulo the box's symmetries.",
        )),
        nullable(col("paper_error_m2", Float64, "m²", "The paper's error.")),
        nullable(col(
            "paper_error_normalized",
            Float64,
            "",
            "The paper's error / (d²/3), d the box's diagonal.",
        )),
        nullable(col(
            "rotation_error_deg",
            Float64,
            "deg",
            "Rotation error modulo the box's symmetries.",
        )),
        nullable(col(
            "translation_error_m",
            Float64,
            "m",
            "Distance between the estimated and true centres.",
        )),
    ],
};

pub const RESULT_TABLES: [Table; 6] = [
    SEARCH_SAMPLES,
    SEARCH_TIMINGS,
    EVAL_GEOMETRY,
    EVAL,
    PREDICTIONS,
    EVAL_RESULTS,
];

/// Every table of the contract, in pipeline order.
pub const TABLES: [Table; 4] = [SCENES, OBJECTS, FRAMES, INSTANCES];

pub fn table(name: &str) -> Option<&'static Table> {
    TABLES.iter().find(|t| t.name == name)
}

/// The contract as JSON, the form the Python stages load: the tables, the support geometry
/// ([`crate::support`]) and what a recipe may hold ([`crate::recipe`]).
pub fn to_json() -> serde_json::Value {
    let tables = TABLES
        .iter()
        .map(|t| {
            let columns = t
                .columns
                .iter()
                .map(|c| {
                    serde_json::json!({
                        "name": c.name,
                        "type": c.scalar.name(),
                        "list_size": c.list_size,
                        "nullable": c.nullable,
                        "unit": c.unit,
                        "doc": c.doc,
                        "range": c.range.map(|(lo, hi)| [lo, hi]),
                    })
                })
                .collect::<Vec<_>>();
            serde_json::json!({
                "name": t.name,
                "doc": t.doc,
                "key": t.key,
                "row_group_rows": t.row_group_rows,
                "columns": columns,
            })
        })
        .collect::<Vec<_>>();
    serde_json::json!({
        "schema_version": SCHEMA_VERSION,
        "version_key": VERSION_KEY,
        "table_key": TABLE_KEY,
        "tables": tables,
        "support": crate::support::to_json(),
        "recipe": crate::recipe::to_json(),
    })
}

/// The column reference of `docs/dataset.md`, one Markdown table per dataset table, the support
/// geometries, then the result tables.
pub fn to_markdown() -> String {
    let mut out = format!("Schema version {SCHEMA_VERSION}.\n");
    for (i, t) in TABLES.iter().chain(&RESULT_TABLES).enumerate() {
        if i == TABLES.len() {
            out += "\n";
            out += &crate::support::to_markdown();
            out += "\n### Result tables\n\nWritten by boxpose commands into their output folders, with the same version key and table-name metadata as the dataset's shards.\n";
        }
        out += &format!(
            "\n### `{}`\n\n{} Key: {}.\n\n",
            t.name,
            t.doc,
            t.key.join(", ")
        );
        out += "| column | type | unit / frame | description |\n|---|---|---|---|\n";
        for c in t.columns {
            let ty = match c.list_size {
                None => c.scalar.name().trim_end_matches('_').to_string(),
                Some(ANY_LENGTH) => format!("{}[]", c.scalar.name().trim_end_matches('_')),
                Some(n) => format!("{}[{n}]", c.scalar.name().trim_end_matches('_')),
            };
            let ty = if c.nullable {
                format!("{ty}, nullable")
            } else {
                ty
            };
            let doc = match c.range {
                Some((lo, hi)) => format!("{} Within [{lo}, {hi}].", c.doc),
                None => c.doc.to_string(),
            };
            out += &format!(
                "| `{}` | {} | {} | {} |\n",
                c.name,
                ty,
                c.unit,
                doc.replace('|', "\\|")
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn column_names_are_unique_per_table_and_keys_exist() {
        for t in TABLES {
            let names: HashSet<_> = t.columns.iter().map(|c| c.name).collect();
            assert_eq!(
                names.len(),
                t.columns.len(),
                "duplicate column in {}",
                t.name
            );
            for k in t.key {
                assert!(t.column(k).is_some(), "key {k} missing from {}", t.name);
            }
        }
    }

    /// The Python writers load `python/boxpose_io/schema.json`; it must be this module, verbatim.
    #[test]
    fn python_schema_json_matches_this_module() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../python/boxpose_io/schema.json"
        );
        let on_disk: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).expect("read schema.json"))
                .expect("parse schema.json");
        assert!(
            on_disk == to_json(),
            "{path} is stale: regenerate it with `make schema`"
        );
    }

    /// `docs/dataset.md` embeds the column reference between two markers.
    #[test]
    fn dataset_doc_matches_this_module() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/dataset.md");
        let doc = std::fs::read_to_string(path).expect("read docs/dataset.md");
        let begin = doc.find(crate::DOC_BEGIN).expect("begin marker") + crate::DOC_BEGIN.len();
        let end = doc.find(crate::DOC_END).expect("end marker");
        assert!(
            doc[begin..end].trim() == to_markdown().trim(),
            "{path} is stale: regenerate it with `make schema`"
        );
    }
}
