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
    // In small row groups (frames) each image starts a page and the offset index, written by
    // default, finds it: `FrameEntry::read` decompresses one row's pages, not its row group's.
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

/// Publishes the complete folder `staged` as `out`: renamed when `out` does not exist, else the
/// two swapped in one step (Linux `renameat2(RENAME_EXCHANGE)`) and the old contents, now at
/// `staged`, removed. Either way `out` is never missing and never half written: a reader (or a
/// kill) at any moment finds the old folder or the new one. `staged` must be beside `out` (one
/// file system). Where the file system cannot swap (EINVAL), the old folder is moved aside first,
/// and only then is there a moment without `out`.
pub fn publish_folder(staged: &Path, out: &Path) -> Result<()> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| DataError::Io { path, source }
    };
    if fs::symlink_metadata(out).is_err() {
        fs::rename(staged, out).map_err(io(out))?;
    } else {
        use std::os::unix::ffi::OsStrExt;
        let c_path = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes());
        let (from, to) = (
            c_path(staged).map_err(|e| io(staged)(e.into()))?,
            c_path(out).map_err(|e| io(out)(e.into()))?,
        );
        // SAFETY: two valid NUL-terminated paths, resolved against the working directory.
        let swapped = unsafe {
            libc::renameat2(
                libc::AT_FDCWD,
                from.as_ptr(),
                libc::AT_FDCWD,
                to.as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        if swapped != 0 {
            let error = std::io::Error::last_os_error();
            if error.raw_os_error() != Some(libc::EINVAL) {
                return Err(io(out)(error));
            }
            let aside = staged.with_extension("old");
            fs::rename(out, &aside).map_err(io(out))?;
            fs::rename(staged, out).map_err(io(out))?;
            fs::rename(&aside, staged).map_err(io(staged))?;
        }
        fs::remove_dir_all(staged).map_err(io(staged))?;
    }
    let folder = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::File::open(folder)
        .and_then(|dir| dir.sync_all())
        .map_err(io(folder))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_published_folder_replaces_the_old_one_in_one_step() {
        let root = tempfile::tempdir().unwrap();
        let (out, staged) = (root.path().join("report"), root.path().join("report.tmp"));
        for round in ["first", "second"] {
            fs::create_dir(&staged).unwrap();
            fs::write(staged.join("index.html"), round).unwrap();
            publish_folder(&staged, &out).unwrap();
            assert_eq!(fs::read_to_string(out.join("index.html")).unwrap(), round);
            assert!(!staged.exists(), "the old folder is removed");
        }
        let names: Vec<_> = fs::read_dir(root.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "nothing left beside it");
    }

    /// A table in small row groups (frames) puts each image in pages of its own and writes the
    /// offset index that finds them, so one row is read without decompressing its neighbours.
    #[test]
    fn rows_in_small_row_groups_start_their_own_pages_and_are_indexed() {
        use crate::arrow::array::{BinaryArray, Int64Array};
        use crate::arrow::datatypes::{DataType, Field, Schema};
        use parquet::arrow::arrow_reader::{ArrowReaderOptions, ParquetRecordBatchReaderBuilder};
        use parquet::file::metadata::PageIndexPolicy;
        use std::sync::Arc;

        let (rows, per_group, image_bytes) = (20, 16, 1_300_000); // a 640×480 depth image
        let schema = Arc::new(Schema::new(vec![
            Field::new("id", DataType::Int64, false),
            Field::new("image", DataType::Binary, false),
        ]));
        let images: Vec<Vec<u8>> = (0..rows).map(|r| vec![r as u8; image_bytes]).collect();
        let batch = RecordBatch::try_new(
            schema.clone(),
            vec![
                Arc::new(Int64Array::from_iter_values(0..rows as i64)),
                Arc::new(BinaryArray::from_iter_values(images.iter())),
            ],
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("part-00000-of-00001.parquet");
        write_parquet_in_row_groups(&path, schema, &[batch], Some(per_group)).unwrap();

        let options = ArrowReaderOptions::new().with_offset_index_policy(PageIndexPolicy::Required);
        let builder = ParquetRecordBatchReaderBuilder::try_new_with_options(
            fs::File::open(&path).unwrap(),
            options,
        )
        .unwrap();
        let metadata = builder.metadata();
        let pages_per_group: Vec<usize> = (0..metadata.num_row_groups())
            .map(|g| {
                let index = metadata.page_index_for_row_group(g);
                index.page_locations(1).expect("an offset index").len()
            })
            .collect();
        assert_eq!(pages_per_group, [16, 4], "one page per image");
    }
}
