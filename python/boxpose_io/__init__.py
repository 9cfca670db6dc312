"""The boxpose dataset contract for the Python stages (Drake, Blender).

The schema is defined once, in Rust (`rust/data/src/schema.rs`, and the support geometry in
`rust/data/src/support.rs`); `schema.json` beside this file is generated from it (`make schema`)
and a Rust test fails when the two disagree.
"""

from boxpose_io.reader import DatasetError, read_dataset, read_table
from boxpose_io.schema import (
    BIN_WALL_THICKNESS_M,
    PALLET_HEIGHT_M,
    SCHEMA_VERSION,
    SUPPORT,
    SUPPORT_FRICTION,
    TABLES,
    arrow_schema,
    column_names,
)
from boxpose_io.shards import (
    ShardError,
    publish_atomically,
    shard_file_name,
    shard_path,
    table_from_rows,
    write_shard,
)

__all__ = [
    "BIN_WALL_THICKNESS_M",
    "PALLET_HEIGHT_M",
    "SCHEMA_VERSION",
    "SUPPORT",
    "SUPPORT_FRICTION",
    "TABLES",
    "DatasetError",
    "ShardError",
    "arrow_schema",
    "column_names",
    "publish_atomically",
    "read_dataset",
    "read_table",
    "shard_file_name",
    "shard_path",
    "table_from_rows",
    "write_shard",
]
