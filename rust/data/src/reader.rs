use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

use arrow::array::{Array, AsArray};
use arrow::datatypes::{DataType, Float32Type, Float64Type};
use arrow::record_batch::RecordBatch;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use crate::error::{DataError, Result};
use crate::rows::{Frame, Instance, Object, Scene};
use crate::schema::{self, SCHEMA_VERSION, TABLE_KEY, Table, VERSION_KEY};

/// Largest deviation from 1 tolerated in a stored quaternion's norm.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// An opened dataset folder.
#[derive(Debug, Clone)]
pub struct Dataset {
    root: PathBuf,
}

/// One validated record batch and the shard it came from (for error messages).
#[derive(Debug, Clone)]
pub struct ShardBatch {
    pub path: PathBuf,
    pub batch: RecordBatch,
}

impl Dataset {
    pub fn open(root: impl AsRef<Path>) -> Result<Self> {
        let root = root.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(DataError::MissingFolder(root));
        }
        Ok(Self { root })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Complete shards of `table`, sorted by name. Unfinished `.tmp` files are not shards.
    pub fn shards(&self, table: &Table) -> Result<Vec<PathBuf>> {
        let dir = self.root.join(table.name);
        if !dir.is_dir() {
            return Err(DataError::MissingTable(self.root.clone(), table.name));
        }
        let entries = fs::read_dir(&dir).map_err(|source| DataError::Io {
            path: dir.clone(),
            source,
        })?;
        let mut shards = Vec::new();
        for entry in entries {
            let path = entry
                .map_err(|source| DataError::Io {
                    path: dir.clone(),
                    source,
                })?
                .path();
            if path.extension().is_some_and(|e| e == "parquet") {
                shards.push(path);
            }
        }
        if shards.is_empty() {
            return Err(DataError::MissingTable(self.root.clone(), table.name));
        }
        shards.sort();
        Ok(shards)
    }

    /// Every row of `table`, validated: schema version, table name, column types, finite
    /// numbers and unit quaternions.
    pub fn read_table(&self, table: &'static Table) -> Result<Vec<ShardBatch>> {
        let mut out = Vec::new();
        for path in self.shards(table)? {
            for batch in read_shard(&path, table)? {
                out.push(ShardBatch {
                    path: path.clone(),
                    batch,
                });
            }
        }
        Ok(out)
    }

    /// Total number of rows of `table`.
    pub fn count(&self, table: &'static Table) -> Result<usize> {
        Ok(self
            .read_table(table)?
            .iter()
            .map(|b| b.batch.num_rows())
            .sum())
    }

    /// Every scene, in shard order.
    pub fn scenes(&self) -> Result<Vec<Scene>> {
        self.rows(&schema::SCENES, Scene::from_row)
    }

    /// Every object, in shard order.
    pub fn objects(&self) -> Result<Vec<Object>> {
        self.rows(&schema::OBJECTS, Object::from_row)
    }

    fn rows<T>(
        &self,
        table: &'static Table,
        from_row: fn(&Path, &RecordBatch, usize) -> Result<T>,
    ) -> Result<Vec<T>> {
        let mut out = Vec::new();
        for sb in self.read_table(table)? {
            for row in 0..sb.batch.num_rows() {
                out.push(from_row(&sb.path, &sb.batch, row)?);
            }
        }
        Ok(out)
    }

    /// Decoded frames, each with its instances, shard by shard. Instances are loaded up front
    /// (they are small); images are decoded one frame at a time.
    pub fn frames(&self) -> Result<FrameIter> {
        let mut instances: HashMap<(i64, i32), Vec<Instance>> = HashMap::new();
        for instance in self.rows(&schema::INSTANCES, Instance::from_row)? {
            instances
                .entry((instance.scene_id, instance.frame_id))
                .or_default()
                .push(instance);
        }
        for list in instances.values_mut() {
            list.sort_by_key(|i| i.object_id);
        }
        Ok(FrameIter {
            batches: self.read_table(&schema::FRAMES)?,
            batch: 0,
            row: 0,
            instances,
        })
    }
}

/// Iterator over decoded frames; see [`Dataset::frames`].
pub struct FrameIter {
    batches: Vec<ShardBatch>,
    batch: usize,
    row: usize,
    instances: HashMap<(i64, i32), Vec<Instance>>,
}

impl Iterator for FrameIter {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Self::Item> {
        while self.batch < self.batches.len()
            && self.row >= self.batches[self.batch].batch.num_rows()
        {
            self.batch += 1;
            self.row = 0;
        }
        let sb = self.batches.get(self.batch)?;
        let row = self.row;
        self.row += 1;
        Some(Frame::from_row(&sb.path, &sb.batch, row).map(|mut frame| {
            frame.instances = self
                .instances
                .remove(&(frame.scene_id, frame.frame_id))
                .unwrap_or_default();
            frame
        }))
    }
}

/// Decodes in-memory `frames` and `instances` batches (e.g. a renderer's output) into frames
/// joined with their instances, validating both exactly as a shard is validated. `source` names
/// where the batches came from in error messages.
pub fn decode_frames(
    source: &Path,
    frames: &RecordBatch,
    instances: &RecordBatch,
) -> Result<Vec<Frame>> {
    check_columns(source, &schema::FRAMES, &frames.schema())?;
    check_values(source, &schema::FRAMES, frames, 0)?;
    check_columns(source, &schema::INSTANCES, &instances.schema())?;
    check_values(source, &schema::INSTANCES, instances, 0)?;
    let mut by_frame: HashMap<(i64, i32), Vec<Instance>> = HashMap::new();
    for row in 0..instances.num_rows() {
        let instance = Instance::from_row(source, instances, row)?;
        by_frame
            .entry((instance.scene_id, instance.frame_id))
            .or_default()
            .push(instance);
    }
    (0..frames.num_rows())
        .map(|row| {
            let mut frame = Frame::from_row(source, frames, row)?;
            let mut list = by_frame
                .remove(&(frame.scene_id, frame.frame_id))
                .unwrap_or_default();
            list.sort_by_key(|i| i.object_id);
            frame.instances = list;
            Ok(frame)
        })
        .collect()
}

/// Reads and validates one shard of `table`.
pub fn read_shard(path: &Path, table: &'static Table) -> Result<Vec<RecordBatch>> {
    let file = fs::File::open(path).map_err(|source| DataError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let parquet = |source| DataError::Parquet {
        path: path.to_path_buf(),
        source,
    };
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).map_err(parquet)?;
    check_metadata(
        path,
        table,
        builder.metadata().file_metadata().key_value_metadata(),
    )?;
    check_columns(path, table, builder.schema())?;
    let expected_rows = builder.metadata().file_metadata().num_rows() as usize;
    let reader = builder.build().map_err(parquet)?;
    let mut batches = Vec::new();
    let mut first_row = 0;
    for batch in reader {
        let batch = batch.map_err(|source| DataError::Arrow {
            path: path.to_path_buf(),
            source,
        })?;
        check_values(path, table, &batch, first_row)?;
        first_row += batch.num_rows();
        batches.push(batch);
    }
    if first_row != expected_rows {
        return Err(DataError::BadValue {
            path: path.to_path_buf(),
            row: first_row,
            column: "*",
            problem: format!("read {first_row} rows but the footer declares {expected_rows}"),
        });
    }
    Ok(batches)
}

fn check_metadata(
    path: &Path,
    table: &'static Table,
    kv: Option<&Vec<parquet::file::metadata::KeyValue>>,
) -> Result<()> {
    let get = |key: &str| {
        kv.and_then(|kv| kv.iter().find(|e| e.key == key))
            .and_then(|e| e.value.clone())
    };
    let version = get(VERSION_KEY).ok_or(DataError::NotAShard {
        path: path.to_path_buf(),
        key: VERSION_KEY,
    })?;
    if version != SCHEMA_VERSION.to_string() {
        return Err(DataError::SchemaVersion {
            path: path.to_path_buf(),
            found: version,
            expected: SCHEMA_VERSION,
        });
    }
    let found = get(TABLE_KEY).ok_or(DataError::NotAShard {
        path: path.to_path_buf(),
        key: TABLE_KEY,
    })?;
    if found != table.name {
        return Err(DataError::WrongTable {
            path: path.to_path_buf(),
            found,
            expected: table.name,
        });
    }
    Ok(())
}

/// Lists compare by element type only: writers name the list item differently ("item" in Rust
/// and pyarrow, "element" once read back from Parquet) and may mark it nullable.
fn same_type(found: &DataType, expected: &DataType) -> bool {
    match (found, expected) {
        (DataType::List(f), DataType::List(e)) => f.data_type() == e.data_type(),
        _ => found == expected,
    }
}

fn check_columns(
    path: &Path,
    table: &'static Table,
    arrow_schema: &arrow::datatypes::Schema,
) -> Result<()> {
    for column in table.columns {
        let field =
            arrow_schema
                .field_with_name(column.name)
                .map_err(|_| DataError::MissingColumn {
                    path: path.to_path_buf(),
                    table: table.name,
                    column: column.name,
                })?;
        let expected = column.arrow_type();
        if !same_type(field.data_type(), &expected) {
            return Err(DataError::WrongType {
                path: path.to_path_buf(),
                column: column.name,
                found: field.data_type().to_string(),
                expected: expected.to_string(),
            });
        }
    }
    Ok(())
}

/// Rejects nulls in non-nullable columns, non-finite floats anywhere, and quaternions that are
/// not of unit norm: a pose with NaN in it must never reach training or evaluation.
fn check_values(
    path: &Path,
    table: &'static Table,
    batch: &RecordBatch,
    first_row: usize,
) -> Result<()> {
    let bad = |row: usize, column: &'static str, problem: String| DataError::BadValue {
        path: path.to_path_buf(),
        row: first_row + row,
        column,
        problem,
    };
    for column in table.columns {
        let array = batch
            .column_by_name(column.name)
            .expect("columns were checked");
        if !column.nullable && array.null_count() > 0 {
            let row = (0..array.len()).find(|&r| array.is_null(r)).unwrap_or(0);
            return Err(bad(
                row,
                column.name,
                "null in a column that must have a value".into(),
            ));
        }
        let Some(width) = column.list_size else {
            if let Some(values) = floats(array.as_ref())
                && let Some(row) = values.iter().position(|v| !v.is_finite())
            {
                return Err(bad(
                    row,
                    column.name,
                    format!("non-finite value {}", values[row]),
                ));
            }
            continue;
        };
        let list = array.as_list::<i32>();
        let width = width as usize;
        let elements = list.values();
        let offsets = list.value_offsets();
        let floats = floats(elements.as_ref());
        for row in (0..list.len()).filter(|&r| list.is_valid(r)) {
            let (start, end) = (offsets[row] as usize, offsets[row + 1] as usize);
            if width != schema::ANY_LENGTH as usize && end - start != width {
                return Err(bad(
                    row,
                    column.name,
                    format!("{} values, the schema says {width}", end - start),
                ));
            }
            if (start..end).any(|i| elements.is_null(i)) {
                return Err(bad(row, column.name, "null element inside a list".into()));
            }
            let Some(values) = &floats else { continue };
            let item = &values[start..end];
            if let Some(v) = item.iter().find(|v| !v.is_finite()) {
                return Err(bad(
                    row,
                    column.name,
                    format!("non-finite value {v} in {item:?}"),
                ));
            }
            if column.name.ends_with("_quat_wxyz") {
                let norm = item.iter().map(|v| v * v).sum::<f64>().sqrt();
                if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                    return Err(bad(
                        row,
                        column.name,
                        format!("quaternion {item:?} has norm {norm}, not 1"),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The values of a float array widened to f64 (`None` for other types).
fn floats(array: &dyn Array) -> Option<Vec<f64>> {
    match array.data_type() {
        DataType::Float64 => Some(array.as_primitive::<Float64Type>().values().to_vec()),
        DataType::Float32 => Some(
            array
                .as_primitive::<Float32Type>()
                .values()
                .iter()
                .map(|&v| v as f64)
                .collect(),
        ),
        _ => None,
    }
}
