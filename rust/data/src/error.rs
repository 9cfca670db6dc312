use std::path::PathBuf;

/// Everything that can be wrong with a dataset on disk. Each message names the file and says
/// what to do, so a dataset builder never has to read a backtrace.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A writing command's output folder holds another command's output, or is in use.
    #[error("{0}")]
    OutputFolder(String),
    #[error("dataset folder {0} does not exist (generate one with `make scenes`)")]
    MissingFolder(PathBuf),
    #[error("{0}: no `{1}` shards in this dataset folder")]
    MissingTable(PathBuf, &'static str),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path}: not a readable Parquet file, probably truncated or corrupt ({source}); delete it and regenerate the shard"
    )]
    Parquet {
        path: PathBuf,
        source: parquet::errors::ParquetError,
    },
    #[error("{path}: reading Arrow data failed: {source}")]
    Arrow {
        path: PathBuf,
        source: crate::arrow::error::ArrowError,
    },
    #[error("{path}: not a boxpose shard (no `{key}` in its Parquet metadata)")]
    NotAShard { path: PathBuf, key: &'static str },
    #[error(
        "{path}: schema version {found}, but this boxpose reads version {expected}; regenerate the dataset with this boxpose"
    )]
    SchemaVersion {
        path: PathBuf,
        found: String,
        expected: u32,
    },
    #[error("{path}: shard of table `{found}` found among `{expected}` shards")]
    WrongTable {
        path: PathBuf,
        found: String,
        expected: &'static str,
    },
    #[error("{path}: missing column `{column}` of table `{table}`")]
    MissingColumn {
        path: PathBuf,
        table: &'static str,
        column: &'static str,
    },
    #[error("{path}: column `{column}` has type {found}, the schema says {expected}")]
    WrongType {
        path: PathBuf,
        column: &'static str,
        found: String,
        expected: String,
    },
    #[error(
        "{dir}: shards of runs with different shard counts are mixed ({first} is one of {first_count}, {second} one of {second_count}), so their rows would be read twice; delete the shards of one run"
    )]
    MixedShardCounts {
        dir: PathBuf,
        first: String,
        first_count: usize,
        second: String,
        second_count: usize,
    },
    #[error(
        "{path}: row {row}: {table} {key} is also at {first_path} row {first_row}; a shard was copied or written twice, delete the duplicate"
    )]
    DuplicateKey {
        path: PathBuf,
        row: usize,
        table: &'static str,
        key: String,
        first_path: PathBuf,
        first_row: usize,
    },
    #[error("{path}: row {row}: {what}")]
    BrokenJoin {
        path: PathBuf,
        row: usize,
        what: String,
    },
    #[error("{path}: row {row}, column `{column}`: {problem}")]
    BadValue {
        path: PathBuf,
        row: usize,
        column: &'static str,
        problem: String,
    },
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;
