use std::collections::{HashMap, HashSet};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::arrow::array::{Array, AsArray, BooleanArray};
use crate::arrow::compute::{cast, concat_batches, filter_record_batch};
use crate::arrow::datatypes::{DataType, Float32Type, Float64Type, Int32Type, Int64Type};
use crate::arrow::record_batch::RecordBatch;
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderOptions, ParquetRecordBatchReaderBuilder, RowSelection, RowSelector,
};
use parquet::file::metadata::PageIndexPolicy;

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

    /// Complete shards of `table`, sorted by name: its `*.parquet` files (unfinished `.tmp` files
    /// are not shards). Files named `part-IIIII-of-NNNNN.parquet` of runs with different shard
    /// counts N side by side, whose rows would be read twice, are an error. (Other writers, like
    /// the search's per-batch counterexamples, use other names; a copy under any name is caught
    /// by the key checks of [`Dataset::frames`], [`Dataset::scenes`] and [`Dataset::objects`].)
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
        let mut first: Option<(&PathBuf, usize)> = None;
        for path in &shards {
            let Some((_, count)) = shard_position(path) else {
                continue;
            };
            match first {
                None => first = Some((path, count)),
                Some((first_path, first_count)) if first_count != count => {
                    let name =
                        |p: &Path| p.file_name().unwrap_or_default().to_string_lossy().into();
                    return Err(DataError::MixedShardCounts {
                        dir,
                        first: name(first_path),
                        first_count,
                        second: name(path),
                        second_count: count,
                    });
                }
                Some(_) => {}
            }
        }
        Ok(shards)
    }

    /// Indices i of the `part-i-of-N` shards of `table` that are not there yet, e.g. of an
    /// unfinished `make scenes`, and N.
    pub fn missing_shards(&self, table: &Table) -> Result<(Vec<usize>, usize)> {
        let mut present = Vec::new();
        let mut count = 0;
        for path in self.shards(table)? {
            if let Some((index, of)) = shard_position(&path) {
                present.push(index);
                count = of;
            }
        }
        Ok(((0..count).filter(|i| !present.contains(i)).collect(), count))
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

    /// Total number of rows of `table`, from the shards' footers (their version and table
    /// checked; the rows themselves are validated where they are read).
    pub fn count(&self, table: &'static Table) -> Result<usize> {
        let mut total = 0;
        for path in self.shards(table)? {
            total += shard_builder(&path, table)?
                .metadata()
                .file_metadata()
                .num_rows() as usize;
        }
        Ok(total)
    }

    /// Every scene, in shard order; a scene id twice is an error.
    pub fn scenes(&self) -> Result<Vec<Scene>> {
        let mut keys = UniqueKeys::new(schema::SCENES.name);
        self.rows(&schema::SCENES, Scene::from_row, |scene, at| {
            keys.insert(scene.scene_id, at)
        })
    }

    /// Every object, in shard order; an object id twice in a scene, or (where the dataset has
    /// a `scenes` table) an object of a scene that it does not have, is an error.
    pub fn objects(&self) -> Result<Vec<Object>> {
        let scenes = self.scene_ids()?;
        let mut keys = UniqueKeys::new(schema::OBJECTS.name);
        self.rows(&schema::OBJECTS, Object::from_row, |object, at| {
            keys.insert((object.scene_id, object.object_id), at)?;
            if scenes
                .as_ref()
                .is_some_and(|s| !s.contains(&object.scene_id))
            {
                return Err(at.broken(format!(
                    "object {} of scene {}, which is not in scenes/",
                    object.object_id, object.scene_id
                )));
            }
            Ok(())
        })
    }

    /// Scene ids, or None when the dataset has no `scenes` table (e.g. frames alone).
    fn scene_ids(&self) -> Result<Option<HashSet<i64>>> {
        if !self.has_table(&schema::SCENES)? {
            return Ok(None);
        }
        Ok(Some(self.scenes()?.iter().map(|s| s.scene_id).collect()))
    }

    fn has_table(&self, table: &Table) -> Result<bool> {
        match self.shards(table) {
            Ok(_) => Ok(true),
            Err(DataError::MissingTable(..)) => Ok(false),
            Err(e) => Err(e),
        }
    }

    /// Rows of `table` decoded by `from_row`, each passed with its location to `check`.
    fn rows<T>(
        &self,
        table: &'static Table,
        from_row: fn(&Path, &RecordBatch, usize) -> Result<T>,
        mut check: impl FnMut(&T, RowAt) -> Result<()>,
    ) -> Result<Vec<T>> {
        let mut out = Vec::new();
        let mut offsets = ShardRowOffsets::default();
        for sb in self.read_table(table)? {
            let first = offsets.next(&sb);
            for row in 0..sb.batch.num_rows() {
                let value = from_row(&sb.path, &sb.batch, row)?;
                check(
                    &value,
                    RowAt {
                        path: &sb.path,
                        row: first + row,
                    },
                )?;
                out.push(value);
            }
        }
        Ok(out)
    }

    /// The `scenes` row of `scene_id` and its `objects` rows, as batches of the contract's schema
    /// ([`conform`]ed): what a renderer loads a scene from. None when there is no such scene.
    pub fn scene_batches(&self, scene_id: i64) -> Result<Option<(RecordBatch, RecordBatch)>> {
        let pick = |table: &'static Table| -> Result<RecordBatch> {
            let mut parts = Vec::new();
            for sb in self.read_table(table)? {
                let ids = key_column::<Int64Type>(&sb, "scene_id")?;
                let keep: BooleanArray = ids.iter().map(|&id| Some(id == scene_id)).collect();
                let arrow_error = |source| DataError::Arrow {
                    path: sb.path.clone(),
                    source,
                };
                let part = filter_record_batch(&sb.batch, &keep).map_err(arrow_error)?;
                if part.num_rows() > 0 {
                    parts.push(conform(&sb.path, &part, table)?);
                }
            }
            concat_batches(&Arc::new(table.arrow_schema()), &parts).map_err(|source| {
                DataError::Arrow {
                    path: self.root.join(table.name),
                    source,
                }
            })
        };
        let scenes = pick(&schema::SCENES)?;
        if scenes.num_rows() == 0 {
            return Ok(None);
        }
        Ok(Some((scenes, pick(&schema::OBJECTS)?)))
    }

    /// Decoded frames, each with its instances, shard by shard. Instances are loaded up front
    /// (they are small); images are decoded one frame at a time.
    ///
    /// The keys are checked first: a frame or an instance twice, an instance of no frame, and
    /// (where the dataset has those tables) a frame of no scene or an instance of no object are
    /// errors naming the row.
    pub fn frames(&self) -> Result<FrameIter> {
        let keys = self.frame_keys()?;
        Ok(FrameIter {
            shards: keys.shards.into_iter(),
            current: None,
            instances: keys.instances,
        })
    }

    /// Every frame's key, instances and place, checked as by [`Dataset::frames`], without reading
    /// an image: for random access to the frames of a dataset larger than memory
    /// ([`FrameEntry::read`]), in shard order.
    pub fn frame_index(&self) -> Result<Vec<FrameEntry>> {
        let mut keys = self.frame_keys()?;
        Ok(keys
            .rows
            .into_iter()
            .map(|(path, row, scene_id, frame_id)| FrameEntry {
                scene_id,
                frame_id,
                instances: keys
                    .instances
                    .remove(&(scene_id, frame_id))
                    .unwrap_or_default(),
                path,
                row,
            })
            .collect())
    }

    /// Frame `frame_id` of scene `scene_id`, decoded alone (the others' images are not read);
    /// None when the dataset has no such frame.
    pub fn frame(&self, scene_id: i64, frame_id: i32) -> Result<Option<Frame>> {
        self.frame_index()?
            .into_iter()
            .find(|entry| (entry.scene_id, entry.frame_id) == (scene_id, frame_id))
            .map(|entry| entry.read())
            .transpose()
    }

    /// The frames' keys (only the key columns are read) and instances, joins checked.
    fn frame_keys(&self) -> Result<FrameKeys> {
        let shards = self.shards(&schema::FRAMES)?;
        let mut frame_keys = UniqueKeys::new(schema::FRAMES.name);
        let mut offsets = ShardRowOffsets::default();
        let scenes = self.scene_ids()?;
        let mut key_batches = Vec::new();
        for path in &shards {
            for batch in read_columns(path, &schema::FRAMES, &["scene_id", "frame_id"])? {
                key_batches.push(ShardBatch {
                    path: path.clone(),
                    batch,
                });
            }
        }
        let mut rows = Vec::new();
        let mut shared_path: Option<Arc<Path>> = None;
        for sb in &key_batches {
            let first = offsets.next(sb);
            if shared_path.as_deref() != Some(sb.path.as_path()) {
                shared_path = Some(Arc::from(sb.path.as_path()));
            }
            let path = shared_path.clone().expect("set above");
            let scene_ids = key_column::<Int64Type>(sb, "scene_id")?;
            let frame_ids = key_column::<Int32Type>(sb, "frame_id")?;
            for (row, (scene, frame)) in scene_ids.iter().zip(frame_ids.iter()).enumerate() {
                let at = RowAt {
                    path: &sb.path,
                    row: first + row,
                };
                frame_keys.insert((*scene, *frame), at)?;
                if scenes.as_ref().is_some_and(|s| !s.contains(scene)) {
                    return Err(at.broken(format!(
                        "frame {frame} of scene {scene}, which is not in scenes/"
                    )));
                }
                rows.push((path.clone(), first + row, *scene, *frame));
            }
        }
        let objects: Option<HashSet<(i64, i32)>> = if self.has_table(&schema::OBJECTS)? {
            Some(
                self.objects()?
                    .iter()
                    .map(|o| (o.scene_id, o.object_id))
                    .collect(),
            )
        } else {
            None
        };
        let mut instance_keys = UniqueKeys::new(schema::INSTANCES.name);
        let instances = self.rows(&schema::INSTANCES, Instance::from_row, |i, at| {
            instance_keys.insert((i.scene_id, i.frame_id, i.object_id), at)?;
            if !frame_keys.contains(&(i.scene_id, i.frame_id)) {
                return Err(at.broken(format!(
                    "instance of object {} in frame {} of scene {}, which is not in frames/",
                    i.object_id, i.frame_id, i.scene_id
                )));
            }
            if objects
                .as_ref()
                .is_some_and(|o| !o.contains(&(i.scene_id, i.object_id)))
            {
                return Err(at.broken(format!(
                    "instance of object {} of scene {}, which is not in objects/",
                    i.object_id, i.scene_id
                )));
            }
            Ok(())
        })?;
        let mut by_frame: HashMap<(i64, i32), Vec<Instance>> = HashMap::new();
        for instance in instances {
            by_frame
                .entry((instance.scene_id, instance.frame_id))
                .or_default()
                .push(instance);
        }
        for list in by_frame.values_mut() {
            list.sort_by_key(|i| i.object_id);
        }
        Ok(FrameKeys {
            shards,
            rows,
            instances: by_frame,
        })
    }
}

/// What [`Dataset::frame_keys`] checked: the frame shards, each frame's (shard, row in it,
/// scene, frame), and the instances of each frame, sorted by object id.
struct FrameKeys {
    shards: Vec<PathBuf>,
    rows: Vec<(Arc<Path>, usize, i64, i32)>,
    instances: HashMap<(i64, i32), Vec<Instance>>,
}

/// A frame's key, instances and place in its shard, from [`Dataset::frame_index`]: what a job
/// needs to pick frames before reading any image.
#[derive(Debug, Clone)]
pub struct FrameEntry {
    pub scene_id: i64,
    pub frame_id: i32,
    /// Sorted by object_id.
    pub instances: Vec<Instance>,
    path: Arc<Path>,
    row: usize,
}

impl FrameEntry {
    /// Reads and decodes this frame alone: only its row of the shard is decoded, and validated
    /// as every row is. Shards written with a page index (every writer here since 2026-12-07)
    /// decompress only this row's pages; older ones decompress its row group's pages up to it.
    pub fn read(&self) -> Result<Frame> {
        let path: &Path = &self.path;
        let builder = shard_builder_with(
            path,
            &schema::FRAMES,
            ArrowReaderOptions::new().with_offset_index_policy(PageIndexPolicy::Optional),
        )?;
        check_columns(path, &schema::FRAMES, builder.schema())?;
        let only_this_row =
            RowSelection::from(vec![RowSelector::skip(self.row), RowSelector::select(1)]);
        let mut rows = builder
            .with_row_selection(only_this_row)
            .with_batch_size(1)
            .build()
            .map_err(|source| DataError::Parquet {
                path: path.to_path_buf(),
                source,
            })?;
        let changed = |problem: &str| DataError::BadValue {
            path: path.to_path_buf(),
            row: self.row,
            column: "*",
            problem: format!("{problem} since the dataset was indexed (was it rewritten?)"),
        };
        let batch = rows
            .next()
            .ok_or_else(|| changed("the shard has fewer rows"))?
            .map_err(|source| DataError::Arrow {
                path: path.to_path_buf(),
                source,
            })?;
        check_values(path, &schema::FRAMES, &batch, self.row)?;
        let mut frame = Frame::from_row(path, &batch, 0, self.row)?;
        if (frame.scene_id, frame.frame_id) != (self.scene_id, self.frame_id) {
            return Err(changed("another frame is in this row"));
        }
        frame.instances = self.instances.clone();
        Ok(frame)
    }
}

/// `part-IIIII-of-NNNNN.parquet` → (I, N); None for any other name.
fn shard_position(path: &Path) -> Option<(usize, usize)> {
    let numbers = path
        .file_name()?
        .to_str()?
        .strip_prefix("part-")?
        .strip_suffix(".parquet")?
        .split_once("-of-")?;
    let parse = |digits: &str| {
        (digits.len() >= 5 && digits.bytes().all(|b| b.is_ascii_digit()))
            .then(|| digits.parse::<usize>().ok())
            .flatten()
    };
    Some((parse(numbers.0)?, parse(numbers.1)?))
}

/// A row's place, for messages: the shard and the row within it.
#[derive(Debug, Clone, Copy)]
struct RowAt<'a> {
    path: &'a Path,
    row: usize,
}

impl RowAt<'_> {
    fn broken(self, what: String) -> DataError {
        DataError::BrokenJoin {
            path: self.path.to_path_buf(),
            row: self.row,
            what,
        }
    }
}

/// Keys seen so far in one table, with where each was first seen.
struct UniqueKeys<K> {
    table: &'static str,
    seen: HashMap<K, (PathBuf, usize)>,
}

impl<K: std::hash::Hash + Eq + std::fmt::Debug> UniqueKeys<K> {
    fn new(table: &'static str) -> Self {
        Self {
            table,
            seen: HashMap::new(),
        }
    }

    fn insert(&mut self, key: K, at: RowAt) -> Result<()> {
        if let Some((first_path, first_row)) = self.seen.get(&key) {
            return Err(DataError::DuplicateKey {
                path: at.path.to_path_buf(),
                row: at.row,
                table: self.table,
                key: format!("key {key:?}"),
                first_path: first_path.clone(),
                first_row: *first_row,
            });
        }
        self.seen.insert(key, (at.path.to_path_buf(), at.row));
        Ok(())
    }

    fn contains(&self, key: &K) -> bool {
        self.seen.contains_key(key)
    }
}

/// Row numbers within a shard across its record batches, which arrive in order.
#[derive(Default)]
struct ShardRowOffsets {
    path: PathBuf,
    next_row: usize,
}

impl ShardRowOffsets {
    /// The shard row of `sb`'s first row.
    fn next(&mut self, sb: &ShardBatch) -> usize {
        if sb.path != self.path {
            self.path = sb.path.clone();
            self.next_row = 0;
        }
        let first = self.next_row;
        self.next_row += sb.batch.num_rows();
        first
    }
}

/// A non-null key column of a validated batch.
fn key_column<'a, T: crate::arrow::datatypes::ArrowPrimitiveType>(
    sb: &'a ShardBatch,
    name: &'static str,
) -> Result<&'a [T::Native]> {
    let column = sb
        .batch
        .column_by_name(name)
        .and_then(|c| c.as_primitive_opt::<T>())
        .ok_or(DataError::MissingColumn {
            path: sb.path.clone(),
            table: schema::FRAMES.name,
            column: name,
        })?;
    Ok(column.values())
}

/// Iterator over decoded frames; see [`Dataset::frames`]. Streams: it holds one record batch
/// of [`FRAME_BATCH_ROWS`] frames at a time, so memory does not grow with the dataset.
pub struct FrameIter {
    shards: std::vec::IntoIter<PathBuf>,
    /// The open shard, its current batch, the next row in it and the batch's first shard row.
    current: Option<(ShardReader, RecordBatch, usize, usize)>,
    instances: HashMap<(i64, i32), Vec<Instance>>,
}

/// Frames per record batch read: a frame is about a megabyte of images.
pub const FRAME_BATCH_ROWS: usize = 8;

impl FrameIter {
    /// Instances of the frames not yet yielded whose scene passes `keep` (e.g. for a progress
    /// bar's total before streaming).
    pub fn instance_count(&self, keep: impl Fn(i64) -> bool) -> usize {
        self.instances
            .iter()
            .filter(|((scene, _), _)| keep(*scene))
            .map(|(_, list)| list.len())
            .sum()
    }

    /// Moves to the next frame row, opening shards and reading batches as needed: the shard,
    /// the batch, the row in it and the batch's first row in the shard.
    fn advance(&mut self) -> Result<Option<(&Path, &RecordBatch, usize, usize)>> {
        loop {
            let exhausted = match &mut self.current {
                Some((_, batch, row, _)) if *row < batch.num_rows() => break,
                Some((reader, batch, row, first)) => match reader.next_batch()? {
                    Some(next) => {
                        *first += batch.num_rows();
                        *batch = next;
                        *row = 0;
                        false
                    }
                    None => true,
                },
                None => true,
            };
            if exhausted {
                let Some(path) = self.shards.next() else {
                    self.current = None;
                    return Ok(None);
                };
                let mut reader = ShardReader::open(&path, &schema::FRAMES, FRAME_BATCH_ROWS)?;
                self.current = reader.next_batch()?.map(|batch| (reader, batch, 0, 0));
            }
        }
        let (reader, batch, row, first) = self.current.as_mut().expect("a batch with rows left");
        let at = *row;
        *row += 1;
        Ok(Some((&reader.path, batch, at, *first)))
    }
}

impl Iterator for FrameIter {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Self::Item> {
        let (path, batch, row, first) = match self.advance() {
            Ok(Some(at)) => at,
            Ok(None) => return None,
            Err(e) => {
                self.shards = Vec::new().into_iter();
                self.current = None;
                return Some(Err(e));
            }
        };
        let frame = Frame::from_row(path, batch, row, first);
        Some(frame.map(|mut frame| {
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
            let mut frame = Frame::from_row(source, frames, row, 0)?;
            let mut list = by_frame
                .remove(&(frame.scene_id, frame.frame_id))
                .unwrap_or_default();
            list.sort_by_key(|i| i.object_id);
            frame.instances = list;
            Ok(frame)
        })
        .collect()
}

/// `batch` (from `source`, for messages) with exactly the contract schema of `table`: columns in
/// contract order, cast to the contract types (Parquet writers name list items differently).
pub fn conform(source: &Path, batch: &RecordBatch, table: &Table) -> Result<RecordBatch> {
    let arrow_error = |source_error| DataError::Arrow {
        path: source.to_path_buf(),
        source: source_error,
    };
    let mut columns = Vec::with_capacity(table.columns.len());
    for column in table.columns {
        let array = batch
            .column_by_name(column.name)
            .ok_or_else(|| DataError::MissingColumn {
                path: source.to_path_buf(),
                table: table.name,
                column: column.name,
            })?;
        columns.push(cast(array, &column.arrow_type()).map_err(arrow_error)?);
    }
    RecordBatch::try_new(Arc::new(table.arrow_schema()), columns).map_err(arrow_error)
}

/// Reads and validates one shard of `table`.
pub fn read_shard(path: &Path, table: &'static Table) -> Result<Vec<RecordBatch>> {
    let mut reader = ShardReader::open(path, table, DEFAULT_BATCH_ROWS)?;
    let mut batches = Vec::new();
    while let Some(batch) = reader.next_batch()? {
        batches.push(batch);
    }
    Ok(batches)
}

/// Rows per record batch where nothing else is asked for (arrow-rs's default).
const DEFAULT_BATCH_ROWS: usize = 1024;

/// The validated record batches of one shard, read one at a time.
struct ShardReader {
    path: PathBuf,
    table: &'static Table,
    batches: parquet::arrow::arrow_reader::ParquetRecordBatchReader,
    next_row: usize,
    expected_rows: usize,
}

impl ShardReader {
    fn open(path: &Path, table: &'static Table, batch_rows: usize) -> Result<Self> {
        let builder = shard_builder(path, table)?;
        check_columns(path, table, builder.schema())?;
        let expected_rows = builder.metadata().file_metadata().num_rows() as usize;
        let batches = builder
            .with_batch_size(batch_rows)
            .build()
            .map_err(|source| DataError::Parquet {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(Self {
            path: path.to_path_buf(),
            table,
            batches,
            next_row: 0,
            expected_rows,
        })
    }

    /// The next batch, validated; None after the last, once the row count matched the footer.
    fn next_batch(&mut self) -> Result<Option<RecordBatch>> {
        match self.batches.next() {
            Some(batch) => {
                let batch = batch.map_err(|source| DataError::Arrow {
                    path: self.path.clone(),
                    source,
                })?;
                check_values(&self.path, self.table, &batch, self.next_row)?;
                self.next_row += batch.num_rows();
                Ok(Some(batch))
            }
            None if self.next_row != self.expected_rows => Err(DataError::BadValue {
                path: self.path.clone(),
                row: self.next_row,
                column: "*",
                problem: format!(
                    "read {} rows but the footer declares {}",
                    self.next_row, self.expected_rows
                ),
            }),
            None => Ok(None),
        }
    }
}

/// A shard's Parquet reader, after checking its version and table metadata.
fn shard_builder(
    path: &Path,
    table: &'static Table,
) -> Result<ParquetRecordBatchReaderBuilder<fs::File>> {
    shard_builder_with(path, table, ArrowReaderOptions::new())
}

/// [`shard_builder`] with reader options, e.g. the page index for reading one row.
fn shard_builder_with(
    path: &Path,
    table: &'static Table,
    options: ArrowReaderOptions,
) -> Result<ParquetRecordBatchReaderBuilder<fs::File>> {
    let file = fs::File::open(path).map_err(|source| DataError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let file_len = file.metadata().map(|m| m.len()).unwrap_or(0);
    let builder =
        ParquetRecordBatchReaderBuilder::try_new_with_options(file, options).map_err(|source| {
            DataError::Parquet {
                path: path.to_path_buf(),
                source,
            }
        })?;
    check_column_chunks(path, builder.metadata(), file_len)?;
    check_metadata(
        path,
        table,
        builder.metadata().file_metadata().key_value_metadata(),
    )?;
    Ok(builder)
}

/// Every column chunk the footer declares lies inside the file: the parquet crate panics on a
/// negative offset or length (found by the damaged-shard property test).
fn check_column_chunks(
    path: &Path,
    metadata: &parquet::file::metadata::ParquetMetaData,
    file_len: u64,
) -> Result<()> {
    for row_group in metadata.row_groups() {
        for chunk in row_group.columns() {
            let start = chunk
                .dictionary_page_offset()
                .unwrap_or(chunk.data_page_offset());
            let len = chunk.compressed_size();
            let inside =
                start >= 0 && len >= 0 && (start as u64).saturating_add(len as u64) <= file_len;
            if !inside {
                return Err(DataError::Parquet {
                    path: path.to_path_buf(),
                    source: parquet::errors::ParquetError::General(format!(
                        "column chunk of `{}` at offset {start}, {len} bytes, is not inside the {file_len}-byte file",
                        chunk.column_path()
                    )),
                });
            }
        }
    }
    Ok(())
}

/// Only `columns` (scalars) of a shard of `table`, with their types and values checked.
fn read_columns(
    path: &Path,
    table: &'static Table,
    columns: &[&'static str],
) -> Result<Vec<RecordBatch>> {
    let builder = shard_builder(path, table)?;
    let mask = ProjectionMask::columns(builder.parquet_schema(), columns.iter().copied());
    let parquet = |source| DataError::Parquet {
        path: path.to_path_buf(),
        source,
    };
    let reader = builder.with_projection(mask).build().map_err(parquet)?;
    let mut batches = Vec::new();
    for batch in reader {
        let batch = batch.map_err(|source| DataError::Arrow {
            path: path.to_path_buf(),
            source,
        })?;
        for &name in columns {
            let column = table.column(name).expect("a column of the table");
            let found = batch.column_by_name(name).ok_or(DataError::MissingColumn {
                path: path.to_path_buf(),
                table: table.name,
                column: column.name,
            })?;
            if !same_type(found.data_type(), &column.arrow_type()) {
                return Err(DataError::WrongType {
                    path: path.to_path_buf(),
                    column: column.name,
                    found: found.data_type().to_string(),
                    expected: column.arrow_type().to_string(),
                });
            }
        }
        let first_row = batches.iter().map(RecordBatch::num_rows).sum();
        for &name in columns {
            let column = table.column(name).expect("a column of the table");
            let array = batch.column_by_name(name).expect("checked above");
            check_scalar_values(path, column, array.as_ref(), first_row)?;
        }
        batches.push(batch);
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
    arrow_schema: &crate::arrow::datatypes::Schema,
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
        let Some(width) = column.list_size else {
            check_scalar_values(path, column, array.as_ref(), first_row)?;
            continue;
        };
        if !column.nullable && array.null_count() > 0 {
            let row = (0..array.len()).find(|&r| array.is_null(r)).unwrap_or(0);
            return Err(bad(
                row,
                column.name,
                "null in a column that must have a value".into(),
            ));
        }
        let list = array.as_list::<i32>();
        let width = width as usize;
        let elements = list.values();
        let offsets = list.value_offsets();
        let floats = floats(elements.as_ref());
        let ranged = column.range.zip(numbers(elements.as_ref()));
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
            if let Some(((lo, hi), values)) = &ranged
                && let Some(v) = values[start..end]
                    .iter()
                    .find(|v| !(*lo..=*hi).contains(*v))
            {
                return Err(bad(
                    row,
                    column.name,
                    format!("element {v} is outside [{lo}, {hi}]"),
                ));
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
/// A scalar column's values: no null where the schema says it must have a value, finite floats,
/// and values within the column's range.
fn check_scalar_values(
    path: &Path,
    column: &'static schema::Column,
    array: &dyn Array,
    first_row: usize,
) -> Result<()> {
    let bad = |row: usize, problem: String| DataError::BadValue {
        path: path.to_path_buf(),
        row: first_row + row,
        column: column.name,
        problem,
    };
    if !column.nullable && array.null_count() > 0 {
        let row = (0..array.len()).find(|&r| array.is_null(r)).unwrap_or(0);
        return Err(bad(row, "null in a column that must have a value".into()));
    }
    if let Some(values) = floats(array)
        && let Some(row) = values.iter().position(|v| !v.is_finite())
    {
        return Err(bad(row, format!("non-finite value {}", values[row])));
    }
    if let Some((lo, hi)) = column.range
        && let Some(values) = numbers(array)
        && let Some(row) =
            (0..values.len()).find(|&r| array.is_valid(r) && !(lo..=hi).contains(&values[r]))
    {
        return Err(bad(row, format!("{} is outside [{lo}, {hi}]", values[row])));
    }
    Ok(())
}

/// Any numeric array as float64 (exact for every integer the schema's ranges can hold).
fn numbers(array: &dyn Array) -> Option<Vec<f64>> {
    if !array.data_type().is_numeric() {
        return None;
    }
    let cast = crate::arrow::compute::cast(array, &DataType::Float64).ok()?;
    Some(cast.as_primitive::<Float64Type>().values().to_vec())
}

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
