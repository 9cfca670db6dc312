//! Shards written by the Rust writer read back through the validating reader.

use std::sync::Arc;

use arrow::array::{ArrayRef, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array, ListArray};
use arrow::datatypes::{Float32Type, Float64Type};
use arrow::record_batch::RecordBatch;
use boxpose_data::schema::OBJECTS;
use boxpose_data::{Dataset, DataError, shard_file_name, write_shard};

fn list_f64(rows: &[Vec<f64>]) -> ArrayRef {
    Arc::new(ListArray::from_iter_primitive::<Float64Type, _, _>(rows.iter().map(|r| Some(r.iter().map(|&v| Some(v))))))
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
        Arc::new(ListArray::from_iter_primitive::<Float32Type, _, _>([Some([Some(0.6f32), Some(0.45), Some(0.3)])])),
        Arc::new(Float32Array::from(vec![0.8])),
        Arc::new(Int64Array::from(vec![42])),
        Arc::new(BooleanArray::from(vec![true])),
        Arc::new(BooleanArray::from(vec![false])),
    ];
    RecordBatch::try_new(Arc::new(OBJECTS.arrow_schema()), columns).expect("batch matches the schema")
}

#[test]
fn rust_written_shard_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_shard(dir.path(), &OBJECTS, &shard_file_name(0, 1), &[objects_batch(0.025)]).unwrap();
    assert!(!path.with_extension("parquet.tmp").exists());
    let objects = Dataset::open(dir.path()).unwrap().objects().unwrap();
    assert_eq!(objects.len(), 1);
    let object = &objects[0];
    assert_eq!((object.scene_id, object.object_id, object.texture_seed), (3, 0, 42));
    assert_eq!(object.size, [0.2, 0.1, 0.05]);
    assert_eq!(object.world_box.translation, [0.1, -0.2, 0.025]);
    assert_eq!(object.initial_world_box.quat_wxyz, [0.0, 1.0, 0.0, 0.0]);
    assert_eq!(object.base_color_rgb, [0.6, 0.45, 0.3]);
    assert!(object.has_tape && !object.has_label);
}

#[test]
fn nan_written_by_rust_is_caught_on_read() {
    let dir = tempfile::tempdir().unwrap();
    write_shard(dir.path(), &OBJECTS, &shard_file_name(0, 1), &[objects_batch(f64::NAN)]).unwrap();
    let error = Dataset::open(dir.path()).unwrap().objects().unwrap_err();
    assert!(matches!(error, DataError::BadValue { column: "world_box_translation_m", row: 0, .. }), "{error}");
}
