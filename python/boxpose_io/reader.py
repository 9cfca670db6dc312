"""Reading a boxpose dataset from Python without the Rust reader: every table of a dataset folder
as a pyarrow table (or a pandas frame), each shard checked against the contract on the way.

The Rust reader (`boxpose inspect`) checks more (value ranges, joins between tables, images);
this reader checks what a training job needs to trust the tables it reads: that every shard is a
boxpose shard of this schema version and of this table, with the contract's columns and types,
that the shards of a table come from one run (one shard count, none missing) and that no key
appears twice.

Which files are shards is one rule for both readers (`Dataset::shards` in rust/data/src/reader.rs):
every `*.parquet` file of a table folder (writers publish them whole; `*.tmp` leftovers are not
shards). Files named `part-IIIII-of-NNNNN.parquet` are the generators' N shards of one run, so
shards of two shard counts are refused, and so is a missing index. Other writers name their
files otherwise (the search's counterexamples: `iter-KKKK-batch-BBBBB.parquet`, one per batch);
a copy under any name is caught by the key check."""

import re
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from boxpose_io.schema import SCHEMA_VERSION, TABLE_KEY, TABLES, VERSION_KEY, arrow_schema

_SHARD_NAME = re.compile(r"part-(\d{5,})-of-(\d{5,})\.parquet")


class DatasetError(ValueError):
    """A dataset that does not hold to the contract; the message names the file."""


def _same_type(found: pa.DataType, expected: pa.DataType) -> bool:
    """Equal types, list item names aside (as the Rust reader compares them)."""
    if pa.types.is_list(found) and pa.types.is_list(expected):
        return _same_type(found.value_type, expected.value_type)
    return found == expected


def _parquet(path: Path, read):
    """`read(path)`, with pyarrow's error on a file that is not whole Parquet (a zero-byte or
    truncated shard, whose message names no file) turned into one that names it."""
    try:
        return read(path)
    except (pa.ArrowInvalid, OSError) as e:
        raise DatasetError(
            f"{path}: not a readable Parquet file, probably truncated or corrupt ({e}); "
            "delete it and regenerate the shard"
        ) from e


def read_table(root: str | Path, table: str) -> pa.Table:
    """The rows of `table` over every shard of the dataset folder `root`, in the contract's
    schema."""
    folder = Path(root) / table
    if table not in TABLES:
        raise DatasetError(f"{table!r} is not a table of the contract ({', '.join(TABLES)})")
    if not folder.is_dir():
        raise DatasetError(f"{folder}: no `{table}` shards in this dataset folder")
    shards = sorted(p for p in folder.glob("*.parquet"))  # *.tmp leftovers are not shards
    positions = {}
    for path in shards:
        match = _SHARD_NAME.fullmatch(path.name)
        if match is not None:
            positions[path] = (int(match[1]), int(match[2]))
    counts = {count for _, count in positions.values()}
    if len(counts) > 1:
        raise DatasetError(
            f"{folder}: shards of {len(counts)} shard counts ({sorted(counts)}) side by side: "
            "runs with different --num-shards wrote into one folder"
        )
    if counts:
        (count,) = counts
        missing = sorted(set(range(count)) - {i for i, _ in positions.values()})
        if missing:
            raise DatasetError(
                f"{folder}: shards {missing} of {count} are missing (resume the generation)"
            )
    expected = arrow_schema(table)
    parts = []
    for path in shards:
        metadata = _parquet(path, pq.read_schema).metadata or {}
        version = metadata.get(VERSION_KEY.encode())
        if version != str(SCHEMA_VERSION).encode():
            raise DatasetError(
                f"{path}: schema version {version.decode() if version else 'missing'}, "
                f"this reader reads version {SCHEMA_VERSION}"
            )
        found = metadata.get(TABLE_KEY.encode(), b"").decode()
        if found != table:
            raise DatasetError(f"{path}: a shard of table `{found}` among `{table}` shards")
        data = _parquet(path, pq.read_table)
        for field in expected:
            if field.name not in data.column_names:
                raise DatasetError(f"{path}: missing column `{field.name}` of table `{table}`")
            found = data.schema.field(field.name).type
            if not _same_type(found, field.type):
                raise DatasetError(
                    f"{path}: column `{field.name}` has type {found}, "
                    f"the contract says {field.type}"
                )
        # Only renames list items (Parquet writers name them differently): the types matched.
        parts.append(data.select(expected.names).cast(expected))
    rows = pa.concat_tables(parts) if parts else expected.empty_table()
    key = TABLES[table]["key"]
    counts_by_key = rows.group_by(key).aggregate([([], "count_all")])
    repeated = counts_by_key.filter(pa.compute.greater(counts_by_key["count_all"], 1))
    if repeated.num_rows:
        first = {k: repeated[k][0].as_py() for k in key}
        raise DatasetError(f"{folder}: key {first} appears more than once (a copied shard?)")
    return rows


def read_dataset(root: str | Path, tables=tuple(TABLES), *, pandas: bool = False) -> dict:
    """Every table of the dataset folder `root` (by default all four) as pyarrow tables, or pandas
    frames with `pandas=True`, keyed by table name. Raises `DatasetError` naming the file."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(
            f"dataset folder {root} does not exist (generate one with `make scenes`)"
        )
    read = {name: read_table(root, name) for name in tables}
    return {name: t.to_pandas() for name, t in read.items()} if pandas else read
