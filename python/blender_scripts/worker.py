"""Blender worker: renders the scenes of one dataset shard into `frames` and `instances` rows.

    python -m blender_scripts.worker --dataset DIR --shard I --num-shards N \
        [--scenes START:STOP --out PART_DIR] [--threads T]

Reads `DIR/scenes/part-I-of-N.parquet` and `DIR/objects/part-I-of-N.parquet`, checks that they
fit together (every object's scene exists, every scene has its num_objects objects), renders
every frame of every scene (or of the scenes at positions START:STOP of the shard, sorted by
scene_id) and writes

- without --out: the shard's `frames` and `instances` files (instances first, then frames; each
  written to a .tmp name and renamed, so a frames file means a complete shard);
- with --out: `PART_DIR/frames-START-STOP.parquet` and `instances-…` (the driver merges them).

Progress goes to stdout as JSON lines starting with `@progress `. Exit codes: 0 done, 2 bad
input (message on stderr), 3 bpy missing, 4 render failure.

Test hook: BOXPOSE_TEST_CRASH_SCENE=<scene_id> aborts the process (SIGABRT, like a Blender
crash) when that scene is reached.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

import pyarrow.parquet as pq

EXIT_BAD_INPUT, EXIT_NO_BPY, EXIT_RENDER = 2, 3, 4
PROGRESS = "@progress "


def _emit(**event) -> None:
    print(PROGRESS + json.dumps(event), flush=True)


def read_shard_rows(
    dataset: Path, shard: int, num_shards: int
) -> tuple[list[dict], list[dict], dict[int, list[dict]]]:
    """(scenes sorted by scene_id, objects, objects by scene) of one shard, checked."""
    from blender_scripts.session import RenderInputError, check_scene_objects
    from boxpose_io import shard_path

    paths = {t: shard_path(dataset, t, shard, num_shards) for t in ("scenes", "objects")}
    for path in paths.values():
        if not path.is_file():
            raise RenderInputError(
                f"{path} is missing: the scene stage has not written shard {shard} of {num_shards}"
            )
    scenes = sorted(pq.read_table(paths["scenes"]).to_pylist(), key=lambda s: int(s["scene_id"]))
    objects = pq.read_table(paths["objects"]).to_pylist()
    by_scene = check_scene_objects(
        scenes, objects, where=f"shard {shard} of {num_shards} ({paths['scenes'].name})"
    )
    return scenes, objects, by_scene


def render_scenes(
    scenes: list[dict], by_scene: dict[int, list[dict]], threads: int = 0
) -> tuple[list[dict], list[dict]]:
    from blender_scripts.session import Session

    session = Session(threads)
    crash_at = os.environ.get("BOXPOSE_TEST_CRASH_SCENE")
    frames, instances = [], []
    for scene in scenes:
        sid = int(scene["scene_id"])
        _emit(event="scene", scene_id=sid)
        if crash_at is not None and int(crash_at) == sid:
            os.abort()
        session.load(scene, by_scene[sid])
        for frame_id in range(session.recipe.camera.frames_per_scene):
            start = time.perf_counter()
            frame, rows = session.render(frame_id)
            frames.append(frame)
            instances.extend(rows)
            _emit(
                event="frame", scene_id=sid, frame_id=frame_id, seconds=time.perf_counter() - start
            )
    return frames, instances


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m blender_scripts.worker", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--dataset", type=Path, required=True)
    ap.add_argument("--shard", type=int, required=True)
    ap.add_argument("--num-shards", type=int, required=True)
    ap.add_argument(
        "--scenes", help="START:STOP positions of the shard's scenes (sorted by scene_id) to render"
    )
    ap.add_argument("--out", type=Path, help="folder for partial results (requires --scenes)")
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    args = ap.parse_args(argv)
    if (args.scenes is None) != (args.out is None):
        ap.error("--scenes and --out go together")

    try:
        import bpy  # noqa: F401
    except ImportError as e:
        print(
            f"error: bpy is not importable by {sys.executable} ({e}); "
            "install it with `make setup` (bpy==5.0.1, Python 3.11)",
            file=sys.stderr,
        )
        return EXIT_NO_BPY

    from blender_scripts.recipe import RecipeError
    from blender_scripts.session import RenderInputError
    from boxpose_io import (
        ShardError,
        publish_atomically,
        shard_path,
        table_from_rows,
        write_shard,
    )

    try:
        scenes, _objects, by_scene = read_shard_rows(args.dataset, args.shard, args.num_shards)
    except (RenderInputError, RecipeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.scenes is not None:
        start, stop = (int(v) for v in args.scenes.split(":"))
        scenes = scenes[start:stop]
    _emit(event="start", scenes=len(scenes))
    try:
        frames, instances = render_scenes(scenes, by_scene, args.threads)
        tables = {
            "instances": table_from_rows("instances", instances),
            "frames": table_from_rows("frames", frames),
        }
    except (RenderInputError, RecipeError, ShardError) as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as e:  # a render failure: report it with its traceback, write nothing
        traceback.print_exc()
        print(
            f"error: rendering shard {args.shard} of {args.num_shards} failed: {e}", file=sys.stderr
        )
        return EXIT_RENDER
    if args.out is None:
        for name in ("instances", "frames"):  # frames last: its presence marks a complete shard
            write_shard(shard_path(args.dataset, name, args.shard, args.num_shards), tables[name])
    else:
        args.out.mkdir(parents=True, exist_ok=True)
        for name in ("instances", "frames"):
            path = args.out / f"{name}-{start:06d}-{stop:06d}.parquet"
            table = tables[name]
            publish_atomically(
                path, lambda tmp, t=table: pq.write_table(t, tmp, compression="zstd")
            )
    _emit(event="done", frames=len(frames))
    return 0


if __name__ == "__main__":
    sys.exit(main())
