"""Atomic shard writing: a shard appears under its final name only once it is complete."""

import math
import os
import secrets
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from boxpose_io.schema import TABLES, arrow_schema


class ShardError(ValueError):
    """A row that does not fit the contract; the message names the table, row and column."""


def shard_file_name(shard: int, num_shards: int) -> str:
    """Same naming as the Rust writer: shards of runs with other shard counts never collide."""
    return f"part-{shard:05d}-of-{num_shards:05d}.parquet"


def shard_path(dataset: Path, table: str, shard: int, num_shards: int) -> Path:
    return Path(dataset) / table / shard_file_name(shard, num_shards)


def _check_finite(table: str, rows: list[dict]) -> None:
    float_columns = [c["name"] for c in TABLES[table]["columns"] if c["type"].startswith("float")]
    for i, row in enumerate(rows):
        for name in float_columns:
            value = row.get(name)
            values = value if isinstance(value, (list, tuple)) else [value]
            if value is not None and not all(math.isfinite(v) for v in values):
                raise ShardError(f"table {table}, row {i}, column {name}: non-finite value {value}")


def _check_ranges(table: str, rows: list[dict]) -> None:
    """The schema's value ranges (ids that index masks, visibility codes, fractions), as the Rust
    reader checks them."""
    ranged = [(c["name"], c["range"]) for c in TABLES[table]["columns"] if c.get("range")]
    for i, row in enumerate(rows):
        for name, (lo, hi) in ranged:
            value = row.get(name)
            values = value if isinstance(value, (list, tuple)) else [value]
            if value is not None and not all(lo <= v <= hi for v in values):
                raise ShardError(
                    f"table {table}, row {i}, column {name}: {value} is outside [{lo:g}, {hi:g}]"
                )


def _check_lengths(table: str, rows: list[dict]) -> None:
    sized = [
        (c["name"], c["list_size"], c["nullable"])
        for c in TABLES[table]["columns"]
        if c["list_size"]
    ]
    for i, row in enumerate(rows):
        for name, size, nullable in sized:
            value = row[name]
            if value is None and nullable:
                continue
            if value is None or len(value) != size:
                raise ShardError(
                    f"table {table}, row {i}, column {name}: expected {size} values, got {value!r}"
                )


def table_from_rows(table: str, rows: list[dict]) -> pa.Table:
    """Builds a pyarrow Table of `table` from dicts keyed by column name, checking every column
    is present (no extras), every list has its length, every float is finite and every value
    lies in its column's range."""
    names = [c["name"] for c in TABLES[table]["columns"]]
    for i, row in enumerate(rows):
        missing, extra = set(names) - row.keys(), row.keys() - set(names)
        if missing or extra:
            raise ShardError(
                f"table {table}, row {i}: missing columns {sorted(missing)}, "
                f"unknown columns {sorted(extra)}"
            )
    _check_lengths(table, rows)
    _check_finite(table, rows)
    _check_ranges(table, rows)
    schema = arrow_schema(table)
    try:
        return pa.Table.from_pylist(rows, schema=schema)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as e:
        raise ShardError(f"table {table}: {e}") from e


def write_shard(path: Path, table: pa.Table) -> Path:
    """Writes `table` to `path` atomically ([`publish_atomically`])."""
    path = Path(path)
    expected = arrow_schema(path.parent.name)
    if not table.schema.equals(expected, check_metadata=True):
        raise ShardError(f"{path}: table schema differs from the contract of `{path.parent.name}`")
    # Small row groups where the schema asks for them (frames): a reader holds a whole row group.
    # There, too, each image starts a page (the page size is checked after every row) and the
    # page index is written, so that a reader of one frame (training's random access) decompresses
    # its pages alone, not its row group's: 16 ms against 100 ms for a 640×480 frame.
    row_group_rows = TABLES[path.parent.name].get("row_group_rows")
    per_row_pages = {"write_batch_size": 1, "write_page_index": True} if row_group_rows else {}
    return publish_atomically(
        path,
        lambda tmp: pq.write_table(
            table, tmp, compression="zstd", row_group_size=row_group_rows, **per_row_pages
        ),
    )


def publish_atomically(path: Path, write: Callable[[Path], object]) -> Path:
    """Makes `path` appear only when complete: `write` fills a temporary beside it, unique to
    this writer (two writers of one file never share one), which is synced and renamed over
    `path`, and the folder is synced (the rename survives a power cut). On any failure (a full
    disk, an I/O error, an interrupt) the temporary is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        write(tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    folder = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(folder)
    finally:
        os.close(folder)
    return path
