//! The boxpose dataset contract: a dataset is a folder with one sub-folder of Parquet shards per
//! table (`scenes/`, `objects/`, `frames/`, `instances/`). [`schema`] defines every column once,
//! [`support`] the geometry each `support` value means, [`recipe`] what a scene recipe may hold;
//! [`write_shard`] writes a shard atomically; [`Dataset`] opens a folder, validates every shard
//! against the schema and yields decoded frames joined with their instances; [`output_folder`]
//! is the check and lock every writing command takes of its output folder; [`shipped`] finds the
//! repository's shipped models, configs and recipes from any working folder.

pub mod arrow;
mod error;
pub mod output_folder;
mod reader;
pub mod recipe;
mod rows;
pub mod schema;
pub mod shipped;
pub mod support;
mod writer;

pub use error::{DataError, Result};
pub use reader::{Dataset, FrameEntry, FrameIter, ShardBatch, conform, decode_frames, read_shard};
pub use rows::{Frame, Instance, Intrinsics, Object, Pose, Scene, Visibility};
pub use writer::{
    publish_folder, shard_file_name, write_file_atomically, write_parquet, write_shard, write_table,
};

/// Markers around the generated column reference in `docs/dataset.md`.
pub const DOC_BEGIN: &str = "<!-- BEGIN GENERATED COLUMNS: `make schema` rewrites this part -->";
pub const DOC_END: &str = "<!-- END GENERATED COLUMNS -->";
