"""The Parquet contract across the Python/Rust boundary: Python writes with pyarrow through
boxpose_io, Rust reads back every field; pandas alone reads the same files; bad input gets one
clear error naming the file and the problem."""

import io
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image

import boxpose_io
from conftest import peak_rss_mb, run_boxpose

WIDTH, HEIGHT = 8, 6
NUM_SHARDS = 2


def unit_quaternion(rng) -> list[float]:
    q = rng.normal(size=4)
    return (q / np.linalg.norm(q)).tolist()


def png_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG")
    return buffer.getvalue()


def mask_png(mask: np.ndarray) -> bytes:
    """16-bit grayscale PNG, as the contract stores instance masks."""
    buffer = io.BytesIO()
    Image.fromarray(mask.astype(np.uint16)).save(buffer, format="PNG")
    return buffer.getvalue()


def synthetic_rows(rng) -> dict[str, list[dict]]:
    """Two scenes, two boxes each, two frames each: random but valid values in every column,
    including nulls where the contract allows them."""
    tables = {name: [] for name in boxpose_io.TABLES}
    for scene_id in range(2):
        tables["scenes"].append(
            dict(
                scene_id=scene_id,
                seed=int(rng.integers(1 << 40)),
                recipe="synthetic",
                recipe_toml='name = "synthetic"\n',
                tool_versions=json.dumps({"python": "3.11"}),
                physics_backend="drake",
                support="floor",
                num_objects=2,
                solver="SNOPT",
                solver_status="SolutionFound",
                solve_attempts=int(rng.integers(1, 4)),
                settle_time_s=float(rng.uniform(0.5, 2)),
                max_linear_speed_mps=float(rng.uniform(0, 1e-3)),
                max_angular_speed_radps=float(rng.uniform(0, 1e-2)),
                min_signed_distance_m=float(rng.uniform(-1e-4, 1e-2)),
                stable=True,
            )
        )
        for object_id in range(2):
            tables["objects"].append(
                dict(
                    scene_id=scene_id,
                    object_id=object_id,
                    size_m=rng.uniform(0.05, 0.2, 3).tolist(),
                    world_box_quat_wxyz=unit_quaternion(rng),
                    world_box_translation_m=rng.normal(size=3).tolist(),
                    initial_world_box_quat_wxyz=unit_quaternion(rng),
                    initial_world_box_translation_m=rng.normal(size=3).tolist(),
                    mass_kg=float(rng.uniform(0.1, 2)),
                    friction=float(rng.uniform(0.4, 1)),
                    base_color_rgb=rng.uniform(0, 1, 3).astype(np.float32).tolist(),
                    roughness=float(np.float32(rng.uniform(0, 1))),
                    texture_seed=int(rng.integers(1 << 40)),
                    has_tape=bool(object_id),
                    has_label=not object_id,
                )
            )
        for frame_id in range(2):
            tables["frames"].append(
                dict(
                    scene_id=scene_id,
                    frame_id=frame_id,
                    width=WIDTH,
                    height=HEIGHT,
                    fx=float(rng.uniform(50, 80)),
                    fy=float(rng.uniform(50, 80)),
                    cx=(WIDTH - 1) / 2,
                    cy=(HEIGHT - 1) / 2,
                    world_camera_quat_wxyz=unit_quaternion(rng),
                    world_camera_translation_m=rng.normal(size=3).tolist(),
                    render_seed=int(rng.integers(1 << 40)),
                    samples=1,
                    denoise=bool(frame_id),
                    blender_version="5.0.1",
                    render_settings=json.dumps({"world_strength": 0.5}),
                    render_time_s=float(rng.uniform(0.1, 1)),
                    rgb_png=png_bytes(rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)),
                    depth_m_f32le=rng.uniform(0.3, 2, (HEIGHT, WIDTH)).astype("<f4").tobytes(),
                    instance_mask_png=mask_png(rng.integers(0, 3, (HEIGHT, WIDTH))),
                    sensor_depth_m_f32le=(
                        rng.uniform(0.3, 2, (HEIGHT, WIDTH)).astype("<f4").tobytes()
                        if frame_id
                        else None
                    ),
                )
            )
            for object_id in range(2):
                labelled = object_id == 0
                tables["instances"].append(
                    dict(
                        scene_id=scene_id,
                        frame_id=frame_id,
                        object_id=object_id,
                        size_m=tables["objects"][2 * scene_id + object_id]["size_m"],
                        camera_box_quat_wxyz=unit_quaternion(rng),
                        camera_box_translation_m=rng.normal(size=3).tolist(),
                        corners_camera_m=rng.normal(size=24).tolist(),
                        corners_px=rng.uniform(0, WIDTH, 16).tolist(),
                        corner_visibility=rng.integers(0, 4, 8).tolist(),
                        label_keypoints_camera_m=rng.normal(size=12).tolist() if labelled else None,
                        label_keypoints_px=rng.uniform(0, WIDTH, 8).tolist() if labelled else None,
                        visible_bbox_px=[1, 1, 5, 4] if labelled else None,
                        visible_pixels=12 if labelled else 0,
                        visible_fraction=float(np.float32(rng.uniform(0, 1))),
                    )
                )
    return tables


def write_dataset(root, tables: dict[str, list[dict]]) -> None:
    """Splits every table into NUM_SHARDS shards by scene, as the generators do."""
    for name, rows in tables.items():
        for shard in range(NUM_SHARDS):
            part = [r for r in rows if r["scene_id"] % NUM_SHARDS == shard]
            path = boxpose_io.shard_path(root, name, shard, NUM_SHARDS)
            boxpose_io.write_shard(path, boxpose_io.table_from_rows(name, part))


@pytest.fixture()
def dataset(tmp_path):
    tables = synthetic_rows(np.random.default_rng(0))
    write_dataset(tmp_path / "ds", tables)
    return tmp_path / "ds", tables


def same(rust_value, python_value, path=""):
    """Exact equality, except that float32 values are compared after rounding to float32 (JSON
    prints the shortest float32 representation)."""
    if isinstance(python_value, (list, tuple)):
        flat = np.asarray(rust_value, dtype=float).ravel() if rust_value is not None else None
        assert flat is not None and len(flat) == len(python_value), path
        for i, (r, p) in enumerate(zip(flat, python_value, strict=True)):
            same(float(r), p, f"{path}[{i}]")
    elif isinstance(python_value, float):
        assert rust_value == python_value or np.float32(rust_value) == np.float32(python_value), (
            f"{path}: {rust_value} != {python_value}"
        )
    else:
        assert rust_value == python_value, f"{path}: {rust_value!r} != {python_value!r}"


def test_rust_reads_back_every_field(dataset, boxpose_bin):
    root, tables = dataset
    dumped = [
        json.loads(line) for line in run_boxpose(boxpose_bin, "dump", root).stdout.splitlines()
    ]
    by_table = {
        name: [d for d in dumped if d["table"] == name] for name in ("scenes", "objects", "frames")
    }
    assert (
        len(by_table["scenes"]) == 2
        and len(by_table["objects"]) == 4
        and len(by_table["frames"]) == 4
    )

    for written, read in zip(
        sorted(tables["scenes"], key=lambda r: r["scene_id"]), by_table["scenes"], strict=True
    ):
        for column, value in written.items():
            same(read[column], value, f"scenes.{column}")

    objects = {(o["scene_id"], o["object_id"]): o for o in by_table["objects"]}
    for written in tables["objects"]:
        read = objects[(written["scene_id"], written["object_id"])]
        for column, value in written.items():
            if column.endswith("_quat_wxyz") or column.endswith("_translation_m"):
                pose = read[column.rsplit("_", 2)[0]]  # "world_box_quat_wxyz" → "world_box"
                key = "quat_wxyz" if column.endswith("_quat_wxyz") else "translation_m"
                same(pose[key], value, f"objects.{column}")
            else:
                same(read[column], value, f"objects.{column}")

    frames = {(f["scene_id"], f["frame_id"]): f for f in by_table["frames"]}
    for written in tables["frames"]:
        read = frames[(written["scene_id"], written["frame_id"])]
        rgb = np.asarray(Image.open(io.BytesIO(written["rgb_png"])))
        assert np.array_equal(np.asarray(read["rgb"], np.uint8).reshape(rgb.shape), rgb)
        depth = np.frombuffer(written["depth_m_f32le"], "<f4")
        assert np.array_equal(np.asarray(read["depth_m"], np.float32), depth)
        mask = np.asarray(Image.open(io.BytesIO(written["instance_mask_png"]))).ravel()
        assert np.array_equal(np.asarray(read["instance_mask"]), mask)
        if written["sensor_depth_m_f32le"] is None:
            assert read["sensor_depth_m"] is None
        else:
            assert np.array_equal(
                np.asarray(read["sensor_depth_m"], np.float32),
                np.frombuffer(written["sensor_depth_m_f32le"], "<f4"),
            )
        same(
            read["intrinsics"], [written[k] for k in ("fx", "fy", "cx", "cy")], "frames.intrinsics"
        )
        same(
            read["world_camera"]["quat_wxyz"],
            written["world_camera_quat_wxyz"],
            "frames.world_camera_quat_wxyz",
        )
        same(
            read["world_camera"]["translation_m"],
            written["world_camera_translation_m"],
            "frames.world_camera_translation_m",
        )
        for column in ("width", "height", "samples", "denoise", "render_seed", "blender_version"):
            same(read[column], written[column], f"frames.{column}")

        written_instances = [
            i
            for i in tables["instances"]
            if (i["scene_id"], i["frame_id"]) == (written["scene_id"], written["frame_id"])
        ]
        assert [i["object_id"] for i in read["instances"]] == [
            i["object_id"] for i in written_instances
        ]
        for w, r in zip(written_instances, read["instances"], strict=True):
            same(
                r["camera_box"]["quat_wxyz"],
                w["camera_box_quat_wxyz"],
                "instances.camera_box_quat_wxyz",
            )
            same(
                r["camera_box"]["translation_m"],
                w["camera_box_translation_m"],
                "instances.camera_box_translation_m",
            )
            for column in (
                "size_m",
                "corners_camera_m",
                "corners_px",
                "corner_visibility",
                "visible_pixels",
                "visible_fraction",
            ):
                same(r[column], w[column], f"instances.{column}")
            for column in ("label_keypoints_camera_m", "label_keypoints_px", "visible_bbox_px"):
                if w[column] is None:
                    assert r[column] is None, column
                else:
                    same(r[column], w[column], f"instances.{column}")


def test_pandas_alone_reads_the_dataset(dataset):
    """What docs/dataset.md promises: pandas + numpy + Pillow, no boxpose import."""
    root, tables = dataset
    frames = pd.read_parquet(root / "frames")
    instances = pd.read_parquet(root / "instances")
    assert len(frames) == 4 and len(instances) == 8
    f = frames.sort_values(["scene_id", "frame_id"]).iloc[0]
    rgb = np.asarray(Image.open(io.BytesIO(f.rgb_png)))
    assert rgb.shape == (HEIGHT, WIDTH, 3) and rgb.dtype == np.uint8
    depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(f.height, f.width)
    assert np.array_equal(depth.ravel(), np.frombuffer(tables["frames"][0]["depth_m_f32le"], "<f4"))
    corners = np.stack(instances.corners_camera_m.to_numpy()).reshape(-1, 8, 3)
    assert corners.shape == (8, 8, 3)
    assert (
        pq.read_metadata(next((root / "frames").glob("*.parquet"))).metadata[
            b"boxpose.schema_version"
        ]
        == str(boxpose_io.SCHEMA_VERSION).encode()
    )


def test_duckdb_reads_the_dataset(dataset):
    import duckdb

    root, _ = dataset
    count = duckdb.sql(
        f"SELECT count(*) FROM '{root}/instances/*.parquet' WHERE len(corner_visibility) = 8"
    ).fetchall()[0][0]
    assert count == 8


def test_the_duckdb_queries_in_the_docs_run(dataset):
    """Every statement of docs/dataset.md's SQL block runs on a dataset (DuckDB 2 refused the
    old `v -> v = 0` lambda syntax that the doc used)."""
    import duckdb

    root, _ = dataset
    doc = (Path(__file__).parent.parent / "docs" / "dataset.md").read_text()
    block = doc.split("```sql\n", 1)[1].split("```", 1)[0]
    sql = block.replace("datasets/generated/clutter", str(root))
    statements = [s for s in sql.split(";") if s.strip()]
    assert len(statements) == 2
    for statement in statements:
        assert duckdb.sql(statement).fetchall(), statement


def test_inspect_accepts_a_valid_dataset(dataset, boxpose_bin):
    result = run_boxpose(boxpose_bin, "inspect", dataset[0])
    assert "4 frames, 8 instances" in result.stdout and "all shards valid" in result.stdout


# --- bad input: one clear error naming the file and the problem -----------------------------


def expect_error(boxpose_bin, root, *fragments):
    result = run_boxpose(boxpose_bin, "inspect", root, check=False)
    assert result.returncode != 0, result.stdout
    message = result.stderr
    for fragment in fragments:
        assert str(fragment) in message, f"{fragment!r} not in {message!r}"
    assert "panicked" not in message and "RUST_BACKTRACE" not in message
    return message


def rewrite(path, transform):
    """Rewrites a shard with pyarrow after `transform(table) -> table`, keeping its metadata
    unless the transform replaces it."""
    table = transform(pq.read_table(path))
    pq.write_table(table, path)


def test_missing_folder(tmp_path, boxpose_bin):
    expect_error(boxpose_bin, tmp_path / "nope", tmp_path / "nope", "does not exist")


def test_shard_of_another_schema_version(dataset, boxpose_bin):
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "objects", 1, NUM_SHARDS)
    rewrite(
        shard,
        lambda t: t.replace_schema_metadata(
            {**t.schema.metadata, b"boxpose.schema_version": b"999"}
        ),
    )
    expect_error(
        boxpose_bin, root, shard, "schema version 999", f"version {boxpose_io.SCHEMA_VERSION}"
    )


def test_missing_column(dataset, boxpose_bin):
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "scenes", 0, NUM_SHARDS)
    rewrite(shard, lambda t: t.drop(["settle_time_s"]))
    expect_error(boxpose_bin, root, shard, "missing column `settle_time_s`")


def test_truncated_file(dataset, boxpose_bin):
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "frames", 1, NUM_SHARDS)
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    expect_error(boxpose_bin, root, shard, "not a readable Parquet file")


def test_nan_in_a_pose(dataset, boxpose_bin):
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "objects", 0, NUM_SHARDS)

    def poison(table):
        column = table.column("world_box_translation_m").to_pylist()
        column[1] = [0.0, math.nan, 0.0]
        index = table.schema.get_field_index("world_box_translation_m")
        return table.set_column(
            index, table.schema.field(index), pa.array(column, table.schema.field(index).type)
        )

    rewrite(shard, poison)
    expect_error(boxpose_bin, root, shard, "row 1", "world_box_translation_m", "non-finite")


def test_leftover_tmp_file_is_not_a_shard(dataset, boxpose_bin):
    """A killed writer leaves `*.parquet.tmp`; readers must ignore it, not choke on it."""
    root, _ = dataset
    (root / "frames" / "part-00009-of-00010.parquet.tmp").write_bytes(b"PAR1 half a shard")
    assert "all shards valid" in run_boxpose(boxpose_bin, "inspect", root).stdout


def test_shards_of_two_shard_counts_are_refused(dataset, boxpose_bin):
    """`make scenes SHARDS=2` then `SHARDS=1` into one folder: every row would be read twice."""
    root, tables = dataset
    for name, rows in tables.items():
        path = boxpose_io.shard_path(root, name, 0, 1)
        boxpose_io.write_shard(path, boxpose_io.table_from_rows(name, rows))
    expect_error(
        boxpose_bin, root, "part-00000-of-00001.parquet", "part-00000-of-00002.parquet", "mixed"
    )


def test_a_copied_shard_is_a_duplicate_key(dataset, boxpose_bin):
    """A shard copied under another index of the same count: its scenes appear twice."""
    root, _ = dataset
    scenes = root / "scenes"
    extra = scenes / "part-00003-of-00004.parquet"
    for i in range(NUM_SHARDS):
        (scenes / f"part-{i:05d}-of-00002.parquet").rename(
            scenes / f"part-{i:05d}-of-00004.parquet"
        )
    extra.write_bytes((scenes / "part-00000-of-00004.parquet").read_bytes())
    expect_error(boxpose_bin, root, extra, "row 0", "scenes key", "also at", "part-00000-of-00004")


def test_an_instance_of_no_frame_is_refused(dataset, boxpose_bin):
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "instances", 1, NUM_SHARDS)
    frame_ids = pq.read_table(shard).column("frame_id").to_pylist()

    def move_to_a_missing_frame(table):
        index = table.schema.get_field_index("frame_id")
        moved = [f + 100 for f in frame_ids]
        return table.set_column(index, table.schema.field(index), pa.array(moved, pa.int32()))

    rewrite(shard, move_to_a_missing_frame)
    expect_error(boxpose_bin, root, shard, "row 0", "which is not in frames/")


def test_a_copy_under_a_foreign_name_is_a_duplicate_key(dataset, boxpose_bin):
    root, _ = dataset
    foreign = root / "objects" / "extra.parquet"
    foreign.write_bytes(boxpose_io.shard_path(root, "objects", 0, NUM_SHARDS).read_bytes())
    expect_error(boxpose_bin, root, foreign, "objects key", "also at")


def test_a_missing_shard_fails_inspect(dataset, boxpose_bin):
    root, _ = dataset
    boxpose_io.shard_path(root, "frames", 1, NUM_SHARDS).unlink()
    expect_error(boxpose_bin, root, "part-00001-of-00002.parquet is missing", "resume")


@pytest.mark.parametrize(
    "table, column, value, shown",
    [
        ("instances", "object_id", 65535, "65535 is outside [0, 65534]"),
        ("objects", "object_id", -1, "-1 is outside [0, 65534]"),
        ("instances", "visible_fraction", 1.5, "1.5 is outside [0, 1]"),
        ("instances", "corner_visibility", [0, 1, 2, 3, 4, 0, 0, 0], "element 4 is outside [0, 3]"),
    ],
)
def test_values_outside_their_range_are_refused(dataset, boxpose_bin, table, column, value, shown):
    """An object id of 65535 or -1 wrapped to the mask's background label; a visibility code or
    fraction outside its range was read as if it meant something. Written with pyarrow alone,
    as a foreign tool would; the Python writer refuses the same row."""
    root, tables = dataset
    shard = boxpose_io.shard_path(root, table, 0, NUM_SHARDS)

    def poison(t):
        values = t.column(column).to_pylist()
        values[0] = value
        index = t.schema.get_field_index(column)
        field = t.schema.field(index)
        return t.set_column(index, field, pa.array(values, field.type))

    rewrite(shard, poison)
    expect_error(boxpose_bin, root, shard, "row 0", column, shown)
    rows = [dict(r) for r in tables[table]]
    rows[0][column] = value
    with pytest.raises(boxpose_io.ShardError, match=f"row 0, column {column}"):
        boxpose_io.table_from_rows(table, rows)


def column_mutations():
    """(table, column, mutation) for every column of the contract: each a way a foreign writer
    could get the column wrong. "null" is legal where the column is nullable."""
    for table, spec in boxpose_io.TABLES.items():
        for column in spec["columns"]:
            name, kind = column["name"], column["type"]
            yield table, name, "null"
            yield table, name, "other type"
            if kind.startswith("float"):
                yield table, name, "nan"
                yield table, name, "inf"
            if column["list_size"]:
                yield table, name, "list too short"
            if column["range"]:
                yield table, name, "below range"
            if kind == "binary":
                yield table, name, "damaged bytes"


def mutated(value, mutation, column):
    if mutation == "null":
        return None
    if mutation in ("nan", "inf"):
        bad = math.nan if mutation == "nan" else math.inf
        return [bad, *value[1:]] if isinstance(value, list) else bad
    if mutation == "list too short":
        return value[:-1]
    if mutation == "below range":
        low = column["range"][0] - 1
        low = low if column["type"].startswith("float") else int(low)
        return [low, *value[1:]] if isinstance(value, list) else low
    if mutation == "damaged bytes":
        return value[: len(value) // 2] + b"\x00" if value else b"\x00"
    raise AssertionError(mutation)


@pytest.mark.parametrize("table, column, mutation", list(column_mutations()))
def test_every_column_mutated_is_read_or_refused_never_a_panic(
    dataset, boxpose_bin, table, column, mutation
):
    """Structure-aware mutations of row 0 of every column, written by pyarrow alone as a foreign
    tool would: `inspect` accepts the shard only where the contract allows the value (a null in a
    nullable column), and otherwise refuses it in one message naming the shard and the column."""
    root, _ = dataset
    shard = boxpose_io.shard_path(root, table, 0, NUM_SHARDS)
    spec = next(c for c in boxpose_io.TABLES[table]["columns"] if c["name"] == column)

    def mutate(t):
        index = t.schema.get_field_index(column)
        field = t.schema.field(index)
        values = t.column(column).to_pylist()
        if mutation == "other type":
            array = (
                pa.array([1] * len(values))
                if field.type == pa.string()
                else pa.array([str(v) for v in values])
            )
            return t.set_column(index, pa.field(column, array.type), array)
        values[0] = mutated(values[0], mutation, spec)
        return t.set_column(index, field.with_nullable(True), pa.array(values, field.type))

    rewrite(shard, mutate)
    result = run_boxpose(boxpose_bin, "inspect", root, check=False)
    assert "panicked" not in result.stderr and result.returncode in (0, 1), result.stderr
    if mutation == "null" and spec["nullable"]:
        assert result.returncode == 0, result.stderr
    else:
        assert result.returncode == 1, f"{mutation} in {table}.{column} was accepted"
        assert str(shard) in result.stderr and column in result.stderr, result.stderr


def test_a_frame_claiming_a_huge_image_is_refused_before_decoding(dataset, boxpose_bin):
    """A decompression bomb: a frame whose size claims 10000 × 10000 is refused from its
    `width` and `height` before any PNG is inflated."""
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "frames", 0, NUM_SHARDS)

    def enlarge(t):
        for name in ("width", "height"):
            index = t.schema.get_field_index(name)
            field = t.schema.field(index)
            t = t.set_column(index, field, pa.array([10000] * t.num_rows, field.type))
        return t

    rewrite(shard, enlarge)
    expect_error(boxpose_bin, root, shard, "10000 × 10000 is over the limit")


def test_a_bad_image_is_named_by_its_row_in_the_shard(tmp_path, boxpose_bin):
    """Frames are read in batches; the message names the row in the shard, not in its batch."""
    tables = synthetic_rows(np.random.default_rng(3))
    frame = tables["frames"][0]
    tables["frames"] = [{**frame, "scene_id": 0, "frame_id": k} for k in range(20)]
    tables["frames"][19]["rgb_png"] = b"\x89PNG broken"
    tables["instances"] = []
    root = tmp_path / "ds"
    for name, rows in tables.items():
        path = boxpose_io.shard_path(root, name, 0, 1)
        boxpose_io.write_shard(path, boxpose_io.table_from_rows(name, rows))
    expect_error(boxpose_bin, root, "part-00000-of-00001.parquet", "row 19", "rgb_png")


def test_readers_stream_frames_instead_of_holding_the_dataset(tmp_path, boxpose_bin):
    """200 frames of 640 × 480 with incompressible depth (~200 MB on disk): `inspect` holds one
    row group of frames at a time, not the whole table (it peaked at ~500 MB before; 89 MB now)."""
    rng = np.random.default_rng(7)
    tables = synthetic_rows(rng)
    width, height, count = 640, 480, 200
    frame, instances = tables["frames"][0], [i for i in tables["instances"] if i["frame_id"] == 0]
    instances = [i for i in instances if i["scene_id"] == 0]
    rgb = png_bytes(np.zeros((height, width, 3), np.uint8))
    mask = mask_png(np.zeros((height, width), np.int64))
    tables["frames"], tables["instances"] = [], []
    for frame_id in range(count):
        tables["frames"].append(
            {
                **frame,
                "scene_id": 0,
                "frame_id": frame_id,
                "width": width,
                "height": height,
                "cx": (width - 1) / 2,
                "cy": (height - 1) / 2,
                "rgb_png": rgb,
                "depth_m_f32le": rng.uniform(0.3, 2, (height, width)).astype("<f4").tobytes(),
                "instance_mask_png": mask,
                "sensor_depth_m_f32le": None,
            }
        )
        tables["instances"] += [{**i, "frame_id": frame_id} for i in instances]
    root = tmp_path / "big"
    for name, rows in tables.items():
        path = boxpose_io.shard_path(root, name, 0, 1)
        boxpose_io.write_shard(path, boxpose_io.table_from_rows(name, rows))
    on_disk_mb = (root / "frames" / "part-00000-of-00001.parquet").stat().st_size / 2**20
    assert on_disk_mb > 200
    inspect = peak_rss_mb(boxpose_bin, "inspect", root)
    print(f"frames {on_disk_mb:.0f} MB; peak RSS of inspect {inspect:.0f} MB")
    assert inspect < 150  # the frames alone are 200 MB


def test_python_writer_rejects_nan_and_unknown_columns(tmp_path):
    rows = synthetic_rows(np.random.default_rng(1))["objects"]
    rows[0]["mass_kg"] = math.nan
    with pytest.raises(boxpose_io.ShardError, match="row 0, column mass_kg"):
        boxpose_io.table_from_rows("objects", rows)
    rows[0]["mass_kg"] = 1.0
    rows[1]["colour"] = "red"
    with pytest.raises(boxpose_io.ShardError, match="unknown columns \\['colour'\\]"):
        boxpose_io.table_from_rows("objects", rows)
    assert not list(tmp_path.iterdir())


def test_frames_shards_carry_the_page_index_for_reading_one_frame(dataset):
    """The Python writer indexes the frames' pages (a reader of one frame, as training is, seeks
    its pages instead of decompressing its row group's); the other tables need no index."""
    root, _ = dataset
    for shard in sorted((root / "frames").glob("*.parquet")):
        metadata = pq.ParquetFile(shard).metadata
        chunks = [
            metadata.row_group(g).column(c)
            for g in range(metadata.num_row_groups)
            for c in range(metadata.num_columns)
        ]
        assert chunks and all(chunk.has_offset_index for chunk in chunks), shard


def test_read_dataset_returns_every_table_in_the_contract(dataset):
    """`boxpose_io.read_dataset`: the tables with pyarrow alone, checked against the contract."""
    root, tables = dataset
    read = boxpose_io.read_dataset(root)
    assert {name: t.num_rows for name, t in read.items()} == {
        name: len(rows) for name, rows in tables.items()
    }
    for name, table in read.items():
        assert table.schema.equals(boxpose_io.arrow_schema(name)), name
    frames = boxpose_io.read_dataset(root, ["frames"], pandas=True)["frames"]
    assert len(frames) == 4 and (frames.rgb_png.map(len) > 0).all()


def test_hugging_face_datasets_loads_every_table(dataset, tmp_path, monkeypatch):
    """A boxpose dataset opens in Hugging Face `datasets` (its Parquet loader, offline, no boxpose
    code involved): each table, the same rows and values as boxpose_io reads, PNG bytes
    intact."""
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    import datasets

    root, tables = dataset
    # one dataset per table: a DatasetDict's splits must share their columns
    loaded = {
        name: datasets.load_dataset(
            "parquet",
            data_files=str(root / name / "*.parquet"),
            split="train",
            cache_dir=str(tmp_path / "hf-cache"),
        )
        for name in boxpose_io.TABLES
    }
    expected = boxpose_io.read_dataset(root)
    for name in boxpose_io.TABLES:
        assert loaded[name].num_rows == len(tables[name]), name
        assert loaded[name].column_names == expected[name].column_names, name
        order = [(k, "ascending") for k in boxpose_io.TABLES[name]["key"]]
        # pyarrow underneath both: the rows compare exactly (the synthetic rows hold no NaN)
        hf_rows = loaded[name].data.table.sort_by(order).to_pylist()
        assert hf_rows == expected[name].sort_by(order).to_pylist(), name
    first = loaded["frames"].sort("frame_id")[0]
    assert Image.open(io.BytesIO(first["rgb_png"])).size == (WIDTH, HEIGHT)


@pytest.mark.parametrize(
    "damage, message",
    [
        ("copied under a foreign name", "appears more than once"),
        ("two shard counts", "shards of 2 shard counts"),
        ("copied over another", "appears more than once"),
        ("missing", "shards [1] of 2 are missing"),
        ("other version", "schema version 99"),
        ("other table", "a shard of table `scenes` among `objects` shards"),
    ],
)
def test_read_dataset_refuses_a_damaged_dataset_naming_the_file(dataset, damage, message):
    root, _ = dataset
    first, second = (boxpose_io.shard_path(root, "objects", i, NUM_SHARDS) for i in (0, 1))
    if damage == "copied under a foreign name":
        shutil.copy(first, first.with_name("copy.parquet"))
    elif damage == "two shard counts":
        shutil.copy(first, first.with_name("part-00000-of-00001.parquet"))
    elif damage == "copied over another":
        shutil.copy(first, second)
    elif damage == "missing":
        second.unlink()
    elif damage == "other version":
        rewrite(first, lambda t: t.replace_schema_metadata({
            **t.schema.metadata, b"boxpose.schema_version": b"99"
        }))  # fmt: skip
    else:
        shutil.copy(boxpose_io.shard_path(root, "scenes", 0, NUM_SHARDS), first)
    with pytest.raises(boxpose_io.DatasetError, match=re.escape(message)) as error:
        boxpose_io.read_dataset(root)
    assert "objects" in str(error.value)


def test_read_dataset_reads_the_files_of_other_writers_as_inspect_does(dataset, boxpose_bin):
    """The search writes its counterexamples dataset one file per batch
    (`iter-KKKK-batch-BBBBB.parquet`): both readers take every `*.parquet` file of a table folder
    as a shard (`Dataset::shards`, rust/data/src/reader.rs); the Python reader refused these as
    "not a shard name"."""
    root, tables = dataset
    for name in boxpose_io.TABLES:
        for i in range(NUM_SHARDS):
            shard = boxpose_io.shard_path(root, name, i, NUM_SHARDS)
            shard.rename(shard.with_name(f"iter-0000-batch-{i + 4:05d}.parquet"))
    read = boxpose_io.read_dataset(root)
    assert {name: t.num_rows for name, t in read.items()} == {
        name: len(rows) for name, rows in tables.items()
    }
    assert "all shards valid" in run_boxpose(boxpose_bin, "inspect", root).stdout


@pytest.mark.parametrize("damage", ["truncated", "zero bytes"])
def test_read_dataset_names_a_truncated_or_empty_shard(dataset, damage):
    """pyarrow's own errors ("Parquet magic bytes not found in footer", "Parquet file size is 0
    bytes") name no file: the reader's error names it and says what to do, as the Rust reader's
    does."""
    root, _ = dataset
    shard = boxpose_io.shard_path(root, "instances", 0, NUM_SHARDS)
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"")
    with pytest.raises(boxpose_io.DatasetError) as error:
        boxpose_io.read_dataset(root)
    message = str(error.value)
    assert str(shard) in message, message
    assert "probably truncated or corrupt" in message and "delete it and regenerate" in message
