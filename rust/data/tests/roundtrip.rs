//! Shards written by the Rust writer read back through the validating reader.

use std::sync::Arc;

use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array, ListArray,
};
use boxpose_data::arrow::datatypes::{Float32Type, Float64Type};
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::schema::OBJECTS;
use boxpose_data::{DataError, Dataset, read_shard, shard_file_name, write_shard};
use proptest::prelude::*;

fn list_f64(rows: &[Vec<f64>]) -> ArrayRef {
    Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(
        rows.iter().map(|r| Some(r.iter().map(|&v| Some(v)))),
    ))
}

fn objects_batch(translation_z: f64) -> RecordBatch {
    let columns: Vec<ArrayRef> = vec![
        Arc::new(Int64Array::from(vec![3])),
        Arc::new(Int32Array::from(vec![0])),
        list_f64(&[vec![0.2, 0.1, 0.05]]),
        list_f64(&[vec![1.0, 0.0, 0.0, 0.0]]),
        list_f64(&[vec![0.1, -0.2, translation_z]]),
        list_f64(&[vec![0.0, 1.0, 0.0, 0.0]]),
        list_f64(&[vec![0.1, -0.2, 0.3]]),
        Arc::new(Float64Array::from(vec![0.4])),
        Arc::new(Float64Array::from(vec![0.7])),
        Arc::new(ListArray::from_iter_primitive::<Float32Type, _, _>([Some(
            [Some(0.6f32), Some(0.45), Some(0.3)],
        )])),
        Arc::new(Float32Array::from(vec![0.8])),
        Arc::new(Int64Array::from(vec![42])),
        Arc::new(BooleanArray::from(vec![true])),
        Arc::new(BooleanArray::from(vec![false])),
    ];
    RecordBatch::try_new(Arc::new(OBJECTS.arrow_schema()), columns)
        .expect("batch matches the schema")
}

#[test]
fn rust_written_shard_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_shard(
        dir.path(),
        &OBJECTS,
        &shard_file_name(0, 1),
        &[objects_batch(0.025)],
    )
    .unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    let objects = Dataset::open(dir.path()).unwrap().objects().unwrap();
    assert_eq!(objects.len(), 1);
    let object = &objects[0];
    assert_eq!(
        (object.scene_id, object.object_id, object.texture_seed),
        (3, 0, 42)
    );
    assert_eq!(object.size, [0.2, 0.1, 0.05]);
    assert_eq!(object.world_box.translation, [0.1, -0.2, 0.025]);
    assert_eq!(object.initial_world_box.quat_wxyz, [0.0, 1.0, 0.0, 0.0]);
    assert_eq!(object.base_color_rgb, [0.6, 0.45, 0.3]);
    assert!(object.has_tape && !object.has_label);
}

/// A write that fails at the last step (the rename: here the final name is taken by a folder)
/// returns the error and leaves no temporary file behind.
#[test]
fn a_failed_write_leaves_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let blocked = dir.path().join("objects").join(shard_file_name(0, 1));
    std::fs::create_dir_all(blocked.join("occupied")).unwrap();
    let error = write_shard(
        dir.path(),
        &OBJECTS,
        &shard_file_name(0, 1),
        &[objects_batch(0.025)],
    )
    .unwrap_err();
    assert!(
        matches!(&error, DataError::Io { path, .. } if path == &blocked),
        "{error}"
    );
    let names: Vec<_> = std::fs::read_dir(dir.path().join("objects"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, [shard_file_name(0, 1)]);
}

#[test]
fn nan_written_by_rust_is_caught_on_read() {
    let dir = tempfile::tempdir().unwrap();
    write_shard(
        dir.path(),
        &OBJECTS,
        &shard_file_name(0, 1),
        &[objects_batch(f64::NAN)],
    )
    .unwrap();
    let error = Dataset::open(dir.path()).unwrap().objects().unwrap_err();
    assert!(
        matches!(
            error,
            DataError::BadValue {
                column: "world_box_translation_m",
                row: 0,
                ..
            }
        ),
        "{error}"
    );
}

/// `Scene::to_batch` and `Object::to_batch` write what the reader reads back, field for field.
#[test]
fn typed_rows_round_trip_through_a_shard() {
    use boxpose_data::{Object, Pose, Scene, schema};
    let scene = Scene {
        scene_id: 7,
        seed: -3,
        recipe: "single_box".into(),
        recipe_toml: "name = \"x\"".into(),
        tool_versions: "{}".into(),
        physics_backend: "mujoco".into(),
        support: "floor".into(),
        num_objects: 1,
        solver: "none".into(),
        solver_status: "ok".into(),
        solve_attempts: 0,
        settle_time_s: 0.5,
        max_linear_speed_mps: 0.001,
        max_angular_speed_radps: 0.01,
        min_signed_distance_m: -0.0005,
        stable: true,
    };
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let object = Object {
        scene_id: 7,
        object_id: 0,
        size: [0.1, 0.2, 0.3],
        world_box: Pose {
            quat_wxyz: [half, 0.0, half, 0.0],
            translation: [0.01, 0.02, 0.05],
        },
        initial_world_box: Pose {
            quat_wxyz: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0, 0.0, 0.3],
        },
        mass_kg: 1.5,
        friction: 0.7,
        base_color_rgb: [0.5, 0.4, 0.3],
        roughness: 0.6,
        texture_seed: 99,
        has_tape: true,
        has_label: false,
    };
    let dir = tempfile::tempdir().unwrap();
    boxpose_data::write_shard(
        dir.path(),
        &schema::SCENES,
        "part-00000-of-00001.parquet",
        &[Scene::to_batch(std::slice::from_ref(&scene))],
    )
    .unwrap();
    boxpose_data::write_shard(
        dir.path(),
        &schema::OBJECTS,
        "part-00000-of-00001.parquet",
        &[Object::to_batch(std::slice::from_ref(&object))],
    )
    .unwrap();
    let dataset = boxpose_data::Dataset::open(dir.path()).unwrap();
    assert_eq!(dataset.scenes().unwrap(), vec![scene]);
    assert_eq!(dataset.objects().unwrap(), vec![object]);
}

/// One damage done to a valid shard's bytes.
#[derive(Debug, Clone)]
enum Damage {
    /// Overwrite bytes at these fractions of the length with these values.
    Flip(Vec<(f64, u8)>),
    /// Keep only this fraction of the file.
    Truncate(f64),
    /// Append bytes (a second footer, garbage after the magic).
    Append(Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        prop::collection::vec((0.0f64..1.0, any::<u8>()), 1..16).prop_map(Damage::Flip),
        (0.0f64..1.0).prop_map(Damage::Truncate),
        prop::collection::vec(any::<u8>(), 1..64).prop_map(Damage::Append),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// The reader on a damaged shard returns rows or an error, and never panics: every byte of a
    /// dataset may be wrong, and a reader that aborts loses the message that names the file.
    #[test]
    fn a_damaged_shard_is_read_or_refused_never_a_panic(damage in damage()) {
        let dir = tempfile::tempdir().unwrap();
        let path = write_shard(dir.path(), &OBJECTS, &shard_file_name(0, 1), &[objects_batch(0.025)])
            .unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        match &damage {
            Damage::Flip(flips) => {
                for &(at, value) in flips {
                    let i = ((at * bytes.len() as f64) as usize).min(bytes.len() - 1);
                    bytes[i] = value;
                }
            }
            Damage::Truncate(keep) => bytes.truncate((keep * bytes.len() as f64) as usize),
            Damage::Append(extra) => bytes.extend_from_slice(extra),
        }
        std::fs::write(&path, &bytes).unwrap();
        let read = std::panic::catch_unwind(|| {
            let _ = read_shard(&path, &OBJECTS);
            let _ = Dataset::open(dir.path()).unwrap().objects();
        });
        prop_assert!(read.is_ok(), "the reader panicked on {damage:?}");
    }
}
