use std::fs;
use std::path::{Path, PathBuf};

use crate::arrow::array::ArrayRef;
use crate::arrow::datatypes::SchemaRef;
use crate::arrow::record_batch::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;

use crate::error::{DataError, Result};
use crate::schema::Table;

/// File name of shard `shard` of `num_shards`. Shards of a run with another shard count get
/// other names, so they never overwrite each other.
pub fn shard_file_name(shard: usize, num_shards: usize) -> String {
    format!("part-{shard:05}-of-{num_shards:05}.parquet")
}

/// Writes `batches` as `<dataset>/<table>/<file_name>`, atomically (see [`write_parquet`]).
/// The batches must carry the table's schema (see [`Table::arrow_schema`]).
pub fn write_shard(
    dataset: &Path,
    table: &Table,
    file_name: &str,
    batches: &[RecordBatch],
) -> Result<PathBuf> {
    let path = dataset.join(table.name).join(file_name);
    write_parquet_in_row_groups(
        &path,
        std::sync::Arc::new(table.arrow_schema()),
        batches,
        table.row_group_rows,
    )?;
    Ok(path)
}

/// Writes `batches` (zstd) first under a temporary name unique to this writer (`.<pid>-<n>.tmp`),
/// then renames the file once complete and
/// synced, so an interrupted job never leaves a half file that looks valid.
/// Writes `columns` as one file of the result table `table` (its schema, version and table
/// keys), atomically as [`write_parquet`]; columns that do not fit the schema are an error.
pub fn write_table(path: &Path, table: &Table, columns: Vec<ArrayRef>) -> Result<()> {
    let schema = std::sync::Arc::new(table.arrow_schema());
    let batch =
        RecordBatch::try_new(schema.clone(), columns).map_err(|source| DataError::Arrow {
            path: path.to_path_buf(),
            source,
        })?;
    write_parquet(path, schema, &[batch])
}

pub fn write_parquet(path: &Path, schema: SchemaRef, batches: &[RecordBatch]) -> Result<()> {
    write_parquet_in_row_groups(path, schema, batches, None)
}

/// [`write_parquet`] with at most `row_group_rows` rows per row group (None: the default).
fn write_parquet_in_row_groups(
    path: &Path,
    schema: SchemaRef,
    batches: &[RecordBatch],
    row_group_rows: Option<usize>,
) -> Result<()> {
    let tmp = temporary_beside(path)?;
    let io = |source| DataError::Io {
        path: tmp.clone(),
        source,
    };
    let parquet = |source| DataError::Parquet {
        path: tmp.clone(),
        source,
    };

    // The schema's metadata (schema version, table) goes into the footer's key-value pairs, where
    // every Parquet reader sees it; ArrowWriter alone keeps it only inside its encoded schema.
    let metadata = schema
        .metadata()
        .iter()
        .map(|(k, v)| KeyValue::new(k.clone(), v.clone()))
        .collect();
    let mut props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(ZstdLevel::try_new(3).map_err(parquet)?))
        .set_key_value_metadata(Some(metadata));
    if row_group_rows.is_some() {
        props = props.set_max_row_group_row_count(row_group_rows);
    }
    let props = props.build();
    let write = || -> Result<()> {
        let file = fs::File::create(&tmp).map_err(io)?;
        let mut writer =
            ArrowWriter::try_new(file, schema.clone(), Some(props)).map_err(parquet)?;
        for batch in batches {
            if batch.schema().fields() != schema.fields() {
                return Err(DataError::WrongType {
                    path: tmp.clone(),
                    column: "*",
                    found: format!("{:?}", batch.schema().fields()),
                    expected: format!("{:?}", schema.fields()),
                });
            }
            writer.write(batch).map_err(parquet)?;
        }
        let file = writer.into_inner().map_err(parquet)?;
        file.sync_all().map_err(io)
    };
    publish(write(), &tmp, path)
}

/// Renames a complete, synced temporary onto `path` and syncs the folder, so that the new name
/// survives a power cut; on any failure the temporary is removed (no leftovers on a full disk).
fn publish(written: Result<()>, tmp: &Path, path: &Path) -> Result<()> {
    let published = written.and_then(|()| {
        fs::rename(tmp, path).map_err(|source| DataError::Io {
            path: path.to_path_buf(),
            source,
        })
    });
    if published.is_err() {
        let _ = fs::remove_file(tmp);
        return published;
    }
    let folder = path.parent().unwrap_or(Path::new("."));
    fs::File::open(folder)
        .and_then(|dir| dir.sync_all())
        .map_err(|source| DataError::Io {
            path: folder.to_path_buf(),
            source,
        })
}

/// A temporary name beside `path`, unique to this writer (`<name>.<pid>-<n>.tmp`: two processes or
/// threads publishing one file never share a temporary), its folder created.
fn temporary_beside(path: &Path) -> Result<PathBuf> {
    static WRITES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir).map_err(|source| DataError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let n = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    Ok(path.with_file_name(format!(
        "{}.{}-{n}.tmp",
        path.file_name().unwrap_or_default().to_string_lossy(),
        std::process::id()
    )))
}

/// Writes `bytes` to `path` atomically, as [`write_parquet`] publishes a shard: under a temporary
/// name unique to this writer, synced, then renamed.
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let tmp = temporary_beside(path)?;
    let io = |source| DataError::Io {
        path: tmp.clone(),
        source,
    };
    let written = fs::File::create(&tmp)
        .and_then(|mut file| file.write_all(bytes).and_then(|_| file.sync_all()))
        .map_err(io);
    publish(written, &tmp, path)
}
