#!/usr/bin/env python
"""`make scenes`: generate a dataset from a recipe — Drake scenes, then Blender renders — shard
by shard, resumable, and validate it with `boxpose inspect` at the end.

    python scripts/make_scenes.py --recipe clutter [--dataset DIR] [--num-shards N]

For each shard i of N:
  1. scene stage, unless `scenes/` and `objects/` already hold shard i:
     `python -m drake_scenes --recipe R --out DIR --shard i --num-shards N`;
  2. render stage, unless `frames/` and `instances/` already hold shard i: Blender worker
     processes (`python -m blender_scripts.worker`) render the shard's scenes in chunks of
     --scenes-per-worker scenes, a fresh process per chunk (Blender's memory never grows for
     long), into `DIR/.partial/shard-i-of-N/`; once every chunk is there the shard's
     `instances` and `frames` files are written (each atomically, frames last) and the chunks
     deleted.
--jobs workers render at once (chunks of one shard or of the next ones), each with its share of
the cores; the scene stage of the next shard runs beside the renders, so that Drake's one core
and Blender's single-threaded phases overlap.
Interrupted runs resume: complete shards and complete chunks are skipped (whatever --jobs or
--scenes-per-worker made them). A failure (bpy missing, scene/object rows that do not fit, a
crashed or failing render) stops with one error message and leaves no partial shard in the
dataset's tables; the workers already running finish their chunks first, so that the resume
keeps them. A worker that reports no progress for --worker-timeout seconds, or a scene stage
that runs past --scene-stage-timeout, is stopped as hung. Ctrl-C, SIGTERM and SIGHUP stop the
stage processes (each runs in its own process group) before the driver exits, so none is left
running.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

import boxpose_io
from blender_scripts.worker import PROGRESS  # no bpy needed

REPO = Path(__file__).resolve().parent.parent

PARTIAL = ".partial"


class DriverError(RuntimeError):
    pass


def resolve_recipe(recipe: str) -> Path:
    path = Path(recipe)
    if path.suffix != ".toml":
        path = REPO / "datasets" / "recipes" / f"{recipe}.toml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in (REPO / "datasets" / "recipes").glob("*.toml")))
        raise DriverError(f"recipe {recipe}: no file {path} (known recipes: {known})")
    return path


def check_bpy(python: str) -> None:
    """bpy must import in the worker interpreter; checked once, up front, in a subprocess."""
    r = subprocess.run([python, "-c", "import bpy"], capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise DriverError(
            f"bpy is not importable by {python}: {last}\n"
            "  install it with `make setup` (bpy==5.0.1 needs Python 3.11)"
        )


def _tail(path: Path, n: int = 15) -> str:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    lines = [line for line in lines if "CUEW initialization failed" not in line]
    return "\n".join("    " + line for line in lines[-n:])


def stop_group(proc: subprocess.Popen) -> None:
    """Stops a stage process and everything it started (its own session): SIGTERM, then SIGKILL
    after 5 s (a hung process may not act on SIGTERM)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
        os.killpg(proc.pid, signal.SIGCONT)  # a stopped process acts on SIGTERM once continued
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


# Stage processes start from several threads: once a stop has begun none may start (a thread
# between its check and its Popen would otherwise leave a process running after the stop).
SPAWN = threading.Lock()
STOPPING = threading.Event()


def spawn(cmd: list[str], **kwargs) -> subprocess.Popen:
    """Starts a stage process in its own process group, so that a stop reaches its children."""
    with SPAWN:
        if STOPPING.is_set():
            raise DriverError("stopped before this stage started")
        return subprocess.Popen(cmd, cwd=REPO, start_new_session=True, **kwargs)


def stop_all() -> None:
    """Stops every stage process, running or about to start."""
    with SPAWN:
        STOPPING.set()
    stop_children()


def stop_children() -> None:
    """Stops every stage process this driver started, with its process group: the fallback for a
    signal that lands between starting a stage and guarding it (found: a worker left stopped)."""
    me = str(os.getpid())
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError):
            # the parent pid is the second field after the parenthesised command name
            if stat.read_text().rsplit(")", 1)[1].split()[1] == me:
                children.append(int(stat.parent.name))
    for pid in children:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, signal.SIGTERM)
            os.killpg(pid, signal.SIGCONT)
    deadline = time.monotonic() + 5
    for pid in children:
        while time.monotonic() < deadline:
            with contextlib.suppress(ChildProcessError):
                if os.waitpid(pid, os.WNOHANG)[0]:
                    break
                time.sleep(0.05)
                continue
            break
        else:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pid, signal.SIGKILL)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP to the driver: unwinds like Ctrl-C, so that its workers are stopped."""


def raise_terminated(signum, _frame) -> None:
    raise Terminated(signal.Signals(signum))


def run_scene_stage(args, shard: int, log: Path) -> None:
    cmd = [
        args.python,
        "-m",
        "drake_scenes",
        "--recipe",
        str(args.recipe_path),
        "--out",
        str(args.dataset),
        "--shard",
        str(shard),
        "--num-shards",
        str(args.num_shards),
        "--no-progress",
        "--boxpose",
        str(args.boxpose),
    ]
    if args.num_scenes is not None:
        cmd += ["--num-scenes", str(args.num_scenes)]
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "ab") as out:
        # Its own process group, so that an interrupted driver can stop it and its children.
        proc = spawn(cmd, stdout=out, stderr=subprocess.STDOUT)
        try:
            returncode = proc.wait(timeout=args.scene_stage_timeout)
        except subprocess.TimeoutExpired:
            stop_group(proc)
            raise DriverError(
                f"scene stage on shard {shard} of {args.num_shards} ran past "
                f"--scene-stage-timeout {args.scene_stage_timeout:g} s and was stopped; "
                f"raise the limit or lower the recipe's settle.max_time_s. Log: {log}"
            ) from None
        except BaseException:
            stop_group(proc)
            raise
    if returncode != 0:
        raise DriverError(
            f"scene stage failed on shard {shard} of {args.num_shards} (exit {returncode}): "
            f"{' '.join(cmd)}\n{_tail(log)}"
        )
    for table in ("scenes", "objects"):
        if not boxpose_io.shard_path(args.dataset, table, shard, args.num_shards).is_file():
            raise DriverError(
                f"scene stage exited 0 but wrote no {table} shard {shard} of {args.num_shards} "
                f"under {args.dataset}"
            )


def cycles_threads(args) -> int:
    """Cycles threads of each worker: --threads, or else the cores shared out among the jobs (0,
    Cycles' own choice of every core, for one job)."""
    if args.threads > 0 or args.jobs == 1:
        return args.threads
    return max(1, len(os.sched_getaffinity(0)) // args.jobs)


def run_worker(args, shard: int, chunk: tuple[int, int], chunk_dir: Path, on_frame) -> None:
    """Renders the scenes at positions `chunk` of the shard into `chunk_dir` through one Blender
    worker process; `on_frame()` is called for each frame it finishes."""
    start, stop = chunk
    log = chunk_dir / "worker.log"
    cmd = [
        args.python, "-m", "blender_scripts.worker", "--dataset", str(args.dataset),
        "--shard", str(shard), "--num-shards", str(args.num_shards), "--scenes", f"{start}:{stop}",
        "--out", str(chunk_dir), "--threads", str(cycles_threads(args)),
    ]  # fmt: skip
    current_scene = None
    with open(log, "ab") as err:
        proc = spawn(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
        # A thread reads the worker's lines so that the watchdog can wait on them with a timeout.
        lines: queue.Queue[str | None] = queue.Queue()

        def pump() -> None:
            for line in proc.stdout:
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, daemon=True).start()
        recent = deque(maxlen=20)
        try:
            while True:
                try:
                    line = lines.get(timeout=args.worker_timeout)
                except queue.Empty:
                    stop_group(proc)
                    where = f"shard {shard} of {args.num_shards}" + (
                        f", scene {current_scene}" if current_scene is not None else ""
                    )
                    raise DriverError(
                        f"Blender worker made no progress for {args.worker_timeout:g} s "
                        f"(--worker-timeout) while rendering {where} and was stopped; "
                        f"run the same command again to resume. Log: {log}"
                    ) from None
                if line is None:
                    break
                if not line.startswith(PROGRESS):
                    recent.append(line.rstrip())
                    continue
                event = json.loads(line[len(PROGRESS) :])
                if event["event"] == "scene":
                    current_scene = event["scene_id"]
                elif event["event"] == "frame":
                    on_frame()
            proc.wait()
        except BaseException:
            stop_group(proc)
            raise
    if recent:
        with open(log, "a") as f:
            f.write("\n".join(recent) + "\n")
    if proc.returncode == 0:
        return
    where = f"shard {shard} of {args.num_shards}" + (
        f", scene {current_scene}" if current_scene is not None else ""
    )
    if proc.returncode < 0:
        name = signal.Signals(-proc.returncode).name
        raise DriverError(
            f"Blender worker crashed ({name}) while rendering {where}; no shard was written. "
            f"Log: {log}\n{_tail(log)}"
        )
    messages = [
        line for line in log.read_text(errors="replace").splitlines() if line.startswith("error:")
    ]
    message = messages[-1][len("error: ") :] if messages else f"exit status {proc.returncode}"
    raise DriverError(f"rendering {where} failed: {message}\n  log: {log}")


CHUNK_NAME = re.compile(r"frames-(\d{6})-(\d{6})\.parquet")


def plan_chunks(chunk_dir: Path, num_scenes: int, per: int) -> tuple[list, list]:
    """(chunks already rendered, chunks to render) of a shard of `num_scenes` scenes, each chunk
    a (start, stop) range of scene positions. A resume keeps every chunk an earlier run finished,
    whatever its --jobs or --scenes-per-worker, and splits only the scenes they leave into runs
    of at most `per`."""
    per = max(per, 1)
    done = []
    for path in sorted(chunk_dir.glob("frames-*.parquet")):
        match = CHUNK_NAME.fullmatch(path.name)
        if match and (chunk_dir / f"instances-{match[1]}-{match[2]}.parquet").is_file():
            done.append((int(match[1]), int(match[2])))
    covered = {position for start, stop in done for position in range(start, stop)}
    todo = []
    position = 0
    while position < num_scenes:
        if position in covered:
            position += 1
            continue
        stop = position
        while stop < num_scenes and stop not in covered and stop - position < per:
            stop += 1
        todo.append((position, stop))
        position = stop
    return done, todo


def chunk_path(chunk_dir: Path, table: str, chunk: tuple[int, int]) -> Path:
    return chunk_dir / f"{table}-{chunk[0]:06d}-{chunk[1]:06d}.parquet"


def finish_shard(args, shard: int, chunk_dir: Path, chunks: list) -> int:
    """Merges a shard's rendered chunks into its `instances` and `frames` files (each written
    atomically, frames last: its presence marks a complete shard) and deletes the chunks."""
    tables = {}
    for table in ("instances", "frames"):
        parts = [pq.read_table(chunk_path(chunk_dir, table, c)) for c in sorted(chunks)]
        schema = boxpose_io.arrow_schema(table)
        merged = (
            pa.concat_tables([p.cast(schema) for p in parts]) if parts else schema.empty_table()
        )
        tables[table] = merged.replace_schema_metadata(schema.metadata)
    for table in ("instances", "frames"):
        boxpose_io.write_shard(
            boxpose_io.shard_path(args.dataset, table, shard, args.num_shards), tables[table]
        )
    shutil.rmtree(chunk_dir)
    return tables["frames"].num_rows


def shard_complete(args, shard: int) -> bool:
    return all(
        boxpose_io.shard_path(args.dataset, t, shard, args.num_shards).is_file()
        for t in ("frames", "instances")
    )


class Generation:
    """Runs the stages of a driver's shards: up to `args.jobs` Blender workers at a time, and
    Drake's scene stage (one process, one core) in a lane of its own that works ahead of the
    renders by at most `args.jobs` shards, so that rendering one shard and settling the next
    overlap. A shard's tables are written as soon as its last chunk is rendered.

    On a failure nothing new starts, the workers already running finish their chunks (kept for
    the resume) and the first error is raised; an interrupt stops every stage at once."""

    def __init__(self, args, frames_per_scene: int, total: int):
        self.args = args
        self.frames_per_scene = frames_per_scene
        self.estimate = total / max(len(args.shard_list), 1)  # frames per shard until known
        # Complete shards are counted before the progress bar starts, so that its rate and ETA
        # are those of this run's renders.
        self.total, self.initial = total, 0
        self.waiting = deque()
        for shard in args.shard_list:
            if shard_complete(args, shard):
                frames = self.rows("frames", shard)
                self.total += frames - self.estimate
                self.initial += frames
            else:
                self.waiting.append(shard)
        self.total = round(self.total)
        self.pbar: tqdm | None = None
        self.pbar_lock = threading.Lock()  # workers' threads report frames
        # future → ("scenes", shard) or ("chunk", shard, chunk)
        self.running: dict[Future, tuple] = {}
        self.chunks_left: dict[int, int] = {}  # shard being rendered → chunks not yet rendered
        self.rendered = 0
        self.failure: Exception | None = None

    def rows(self, table: str, shard: int) -> int:
        return pq.ParquetFile(self.shard_file(table, shard)).metadata.num_rows

    def shard_file(self, table: str, shard: int) -> Path:
        return boxpose_io.shard_path(self.args.dataset, table, shard, self.args.num_shards)

    def chunk_dir(self, shard: int) -> Path:
        return self.args.dataset / PARTIAL / f"shard-{shard:05d}-of-{self.args.num_shards:05d}"

    def frame_done(self, frames: int = 1) -> None:
        with self.pbar_lock:
            self.pbar.update(frames)

    def scenes_known(self, shard: int) -> None:
        """A shard's scenes are written: the frames it will hold replace its estimate in the
        progress bar's total."""
        frames = self.rows("scenes", shard) * self.frames_per_scene
        with self.pbar_lock:
            self.pbar.total = max(round(self.pbar.total - self.estimate + frames), self.pbar.n)
            self.pbar.refresh()

    def run(self, pbar: tqdm) -> int:
        """Generates the shards not yet complete; returns the number of frames rendered."""
        args, waiting, self.pbar = self.args, self.waiting, pbar
        scene_lane_busy = False
        with ThreadPoolExecutor(1) as scene_lane, ThreadPoolExecutor(args.jobs) as render_pool:
            try:
                while True:
                    while (
                        self.failure is None
                        and not scene_lane_busy
                        and waiting
                        and len(self.chunks_left) <= args.jobs
                    ):
                        shard = waiting.popleft()
                        if all(self.shard_file(t, shard).is_file() for t in ("scenes", "objects")):
                            self.open_shard(shard, render_pool)
                            continue
                        log = (
                            args.dataset
                            / PARTIAL
                            / f"drake-{shard:05d}-of-{args.num_shards:05d}.log"
                        )
                        future = scene_lane.submit(run_scene_stage, args, shard, log)
                        self.running[future] = ("scenes", shard)
                        scene_lane_busy = True
                    self.show_running()
                    if not self.running:
                        break
                    done, _ = wait(self.running, return_when=FIRST_COMPLETED)
                    for future in done:
                        kind, shard, *_ = self.running.pop(future)
                        scene_lane_busy = scene_lane_busy and kind != "scenes"
                        try:
                            future.result()
                        except Exception as e:  # kept, and raised once the running stages drain
                            self.fail(e)
                            continue
                        if kind == "scenes":
                            self.open_shard(shard, render_pool)
                        else:
                            self.chunk_done(shard)
            except BaseException:
                for future in self.running:
                    future.cancel()
                stop_all()
                raise
        if self.failure is not None:
            raise self.failure
        return self.rendered

    def open_shard(self, shard: int, render_pool: ThreadPoolExecutor) -> None:
        """Queues the chunks of a shard whose scenes exist (chunks rendered earlier are kept)."""
        self.scenes_known(shard)
        scenes = self.rows("scenes", shard)
        chunk_dir = self.chunk_dir(shard)
        chunk_dir.mkdir(parents=True, exist_ok=True)
        done, todo = plan_chunks(chunk_dir, scenes, max(self.args.scenes_per_worker, 1))
        for chunk in done:
            self.frame_done(
                pq.ParquetFile(chunk_path(chunk_dir, "frames", chunk)).metadata.num_rows
            )
        self.chunks_left[shard] = len(todo)
        if not todo:
            self.finish(shard)
        for chunk in todo:
            future = render_pool.submit(
                run_worker, self.args, shard, chunk, chunk_dir, self.frame_done
            )
            self.running[future] = ("chunk", shard, chunk)

    def chunk_done(self, shard: int) -> None:
        self.chunks_left[shard] -= 1
        if self.chunks_left[shard] == 0:
            self.finish(shard)

    def finish(self, shard: int) -> None:
        chunk_dir = self.chunk_dir(shard)
        scenes = self.rows("scenes", shard)
        chunks, missing = plan_chunks(chunk_dir, scenes, scenes)
        if missing:
            raise DriverError(
                f"{chunk_dir}: the rendered chunks do not cover scene positions {missing}; "
                "run the same command again to render them"
            )
        self.rendered += finish_shard(self.args, shard, chunk_dir, chunks)
        del self.chunks_left[shard]

    def fail(self, error: Exception) -> None:
        """Keeps the first error; nothing queued starts any more."""
        if self.failure is None:
            self.failure = error
        for future in list(self.running):
            if future.cancel():
                del self.running[future]

    def show_running(self) -> None:
        n = self.args.num_shards
        parts = []
        for kind, shard, *_ in self.running.values():
            what = f"scenes ({self.args.engine})" if kind == "scenes" else "render"
            part = f"shard {shard + 1}/{n}: {what}"
            if part not in parts:
                parts.append(part)
        with self.pbar_lock:
            self.pbar.set_postfix_str(", ".join(parts[: self.args.jobs + 1]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    ap.add_argument(
        "--recipe",
        default=os.environ.get("RECIPE", "clutter"),
        help="recipe name (datasets/recipes/NAME.toml) or path (default: $RECIPE or clutter)",
    )
    ap.add_argument(
        "--dataset", type=Path, help="output folder (default: datasets/generated/<recipe>)"
    )
    ap.add_argument(
        "--num-shards",
        type=int,
        default=int(os.environ.get("SHARDS", "1")),
        help="shards (default: $SHARDS or 1)",
    )
    ap.add_argument(
        "--num-scenes",
        type=int,
        help="override the recipe's num_scenes (passed to the scene stage)",
    )
    ap.add_argument("--shards", help="only these shard indices, e.g. 0,2 (default: all)")
    ap.add_argument(
        "--scenes-per-worker",
        type=int,
        default=25,
        help="scenes a Blender worker process renders before it is replaced (default 25)",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="Blender workers rendering at once, on chunks of one or several shards "
        "(default 1); Drake's scene stage of the next shard runs beside them either way",
    )
    ap.add_argument(
        "--threads",
        type=int,
        default=0,
        help="Cycles threads per worker (default 0 = the cores shared out among the --jobs)",
    )
    ap.add_argument(
        "--python",
        default=sys.executable,
        help="interpreter of the stage processes (default: this one)",
    )
    ap.add_argument(
        "--boxpose",
        type=Path,
        default=REPO / "target" / "release" / "boxpose",
        help="boxpose binary: the final `inspect`, and the settle of a recipe whose settle.engine "
        'is "mujoco"',
    )
    ap.add_argument("--no-inspect", action="store_true", help="skip `boxpose inspect` at the end")
    ap.add_argument(
        "--lock-wait",
        type=float,
        default=0.0,
        help="seconds to wait for another driver's lock on the dataset or a shard before "
        "refusing (default 0: refuse at once)",
    )
    ap.add_argument(
        "--regenerate",
        action="store_true",
        help="when the dataset folder was generated from another recipe text, scene count or "
        "shard count, delete its outputs and start again (default: refuse)",
    )
    ap.add_argument(
        "--worker-timeout",
        type=float,
        default=600.0,
        help="seconds a Blender worker may go without rendering a frame or starting a scene "
        "before it is stopped as hung (default 600)",
    )
    ap.add_argument(
        "--scene-stage-timeout",
        type=float,
        default=3600.0,
        help="seconds the Drake scene stage may take per shard (default 3600)",
    )
    args = ap.parse_args(argv)
    for name in ("worker_timeout", "scene_stage_timeout"):
        if not getattr(args, name) > 0:
            ap.error(f"--{name.replace('_', '-')} must be positive")
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    if not args.lock_wait >= 0:
        ap.error("--lock-wait must not be negative")
    # SIGTERM (a scheduler, `kill`) and SIGHUP (a closed terminal) stop the workers too.
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, raise_terminated)
    try:
        return run(args)
    except DriverError as e:
        tqdm.write(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as e:
        stop_children()
        signum = e.args[0] if isinstance(e, Terminated) else signal.SIGINT
        tqdm.write(
            f"stopped by {signum.name}: run the same command again to resume "
            "(complete shards and chunks are kept)",
            file=sys.stderr,
        )
        return 128 + signum


MANIFEST = "manifest.json"
LOCK = ".lock"  # and .lock-* beside it: one per shard, one around the manifest
# What --regenerate deletes: the dataset's tables, its unfinished chunks and its manifest.
GENERATED = ("scenes", "objects", "frames", "instances", PARTIAL, MANIFEST)


def flock(path: Path, mode: int, what: str, wait_s: float):
    """`path` opened and locked (fcntl `mode`), held until the process ends however it ends;
    waits up to `wait_s` for another holder (a retried task whose predecessor is still shutting
    down), then refuses with the holder's name."""
    lock = open(path, "a+")
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(lock, mode | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            lock.seek(0)
            holder = lock.read().strip() or "another process"
            lock.close()
            raise DriverError(
                f"{what} is being generated by {holder}; wait for it to finish, or stop it "
                "(its complete shards are kept and the next run resumes)"
            ) from None
    if mode == fcntl.LOCK_EX:
        lock.seek(0)
        lock.truncate()
        lock.write(f"make scenes (pid {os.getpid()})\n")
        lock.flush()
    return lock


def lock_dataset(args, shards) -> list:
    """Locks for this driver's lifetime (two drivers writing one shard would race on it): a
    driver of every shard holds DIR/.lock alone; drivers of some shards (--shards, as the Ray
    tasks of `python -m boxpose_ray scenes` are) share it and each holds its shards' locks."""
    dataset = args.dataset
    dataset.mkdir(parents=True, exist_ok=True)
    foreign = sorted(
        p.name for p in dataset.iterdir() if p.name not in GENERATED and not p.name.startswith(LOCK)
    )
    if foreign:
        raise DriverError(
            f"{dataset} holds files that are not a dataset's ({', '.join(foreign[:5])}): "
            "choose an empty or new --dataset folder"
        )
    if args.shards is None:
        return [flock(dataset / LOCK, fcntl.LOCK_EX, str(dataset), args.lock_wait)]
    locks = [flock(dataset / LOCK, fcntl.LOCK_SH, str(dataset), args.lock_wait)]
    for shard in shards:
        name = f"{LOCK}-shard-{shard:05d}-of-{args.num_shards:05d}"
        what = f"shard {shard} of {args.num_shards} of {dataset}"
        locks.append(flock(dataset / name, fcntl.LOCK_EX, what, args.lock_wait))
    return locks


def claim_dataset(args, manifest: dict) -> None:
    """A dataset folder remembers what it is being generated from (DIR/manifest.json, written
    atomically on the first run). A resume with another recipe text, scene count or shard count
    would mix two datasets: it is refused, or with --regenerate the old outputs are deleted."""
    # drivers of some shards run side by side: one at a time reads and writes the manifest
    with flock(args.dataset / f"{LOCK}-manifest", fcntl.LOCK_EX, str(args.dataset), 60.0):
        _claim_under_lock(args, manifest)


def settings_differ(args, manifest: dict) -> bool:
    """Whether the folder's manifest (if any) records other settings than `manifest`, which
    only --regenerate may replace: without it, refused."""
    path = args.dataset / MANIFEST
    if not path.is_file():
        # rendered tables without a manifest were written by another command (`boxpose render`,
        # an export, an older boxpose): adopting them would mix two datasets. A folder holding
        # only a scene stage's tables (scenes/, objects/) is one this driver renders.
        foreign = [name for name in ("frames", "instances") if any((args.dataset / name).glob("*"))]
        if foreign and not args.regenerate:
            raise DriverError(
                f"{args.dataset} holds rendered tables ({', '.join(foreign)}/) without the "
                f"{MANIFEST} that make scenes writes: it is another command's dataset. Use "
                "another --dataset folder, or --regenerate to delete its tables and start again"
            )
        return bool(foreign)
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise DriverError(
            f"{path}: unreadable manifest ({e}); delete it to adopt the folder"
        ) from e
    differ = [k for k in manifest if found.get(k) != manifest[k]]
    if differ and not args.regenerate:
        what = "; ".join(f"{k} {found.get(k)!r} then, {manifest[k]!r} now" for k in differ)
        raise DriverError(
            f"{args.dataset} was generated from other settings ({what}): resuming would mix "
            "two datasets. Use another --dataset folder, or --regenerate to delete this "
            "one's outputs and start again"
        )
    return bool(differ)


def _claim_under_lock(args, manifest: dict) -> None:
    path = args.dataset / MANIFEST
    if settings_differ(args, manifest):
        for name in GENERATED:
            target = args.dataset / name
            if target.is_dir():
                shutil.rmtree(target)
            elif target.exists():
                target.unlink()
        print(f"--regenerate: deleted the outputs of the previous settings in {args.dataset}")
    elif path.is_file():
        return
    args.dataset.mkdir(parents=True, exist_ok=True)
    boxpose_io.publish_atomically(path, lambda tmp: tmp.write_text(json.dumps(manifest, indent=2)))


def run(args) -> int:
    from blender_scripts.recipe import parse_render_recipe
    from drake_scenes.recipe import Recipe, RecipeError

    args.recipe_path = resolve_recipe(args.recipe)
    text = args.recipe_path.read_text()
    try:
        # Both stages' readers, up front: a bad recipe fails before any process starts.
        recipe = parse_render_recipe(text, str(args.recipe_path))
        scene_recipe = Recipe.from_toml(text, str(args.recipe_path))
    except RecipeError as e:
        raise DriverError(str(e)) from e
    args.engine = {"drake": "Drake", "mujoco": "MuJoCo"}[scene_recipe.settle.engine]
    if scene_recipe.settle.engine == "mujoco" and not args.boxpose.is_file():
        raise DriverError(
            f'recipe {args.recipe_path}: settle.engine = "mujoco" settles with {args.boxpose}, '
            "which is missing: build it with `make rust` (or pass --boxpose PATH)"
        )
    num_scenes = scene_recipe.num_scenes if args.num_scenes is None else args.num_scenes
    args.dataset = (
        args.dataset or REPO / "datasets" / "generated" / args.recipe_path.stem
    ).resolve()
    if args.num_shards < 1:
        raise DriverError("--num-shards must be >= 1")
    shards = (
        list(range(args.num_shards))
        if args.shards is None
        else [int(s) for s in args.shards.split(",")]
    )
    args.shard_list = shards
    if any(not 0 <= s < args.num_shards for s in shards):
        raise DriverError(f"--shards {args.shards}: indices must lie in 0..{args.num_shards - 1}")
    if args.regenerate and args.shards is not None:
        raise DriverError("--regenerate deletes every shard: run it without --shards")
    check_bpy(args.python)
    manifest = {
        "recipe": recipe.name,
        "recipe_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "num_scenes": num_scenes,
        "num_shards": args.num_shards,
    }
    # before the lock files are created: a refused command leaves another dataset as it was
    settings_differ(args, manifest)
    args.locks = lock_dataset(args, shards)
    claim_dataset(args, manifest)

    frames_per_scene = recipe.camera.frames_per_scene
    total = num_scenes * frames_per_scene * len(shards) // args.num_shards
    print(f"recipe {recipe.name}: {num_scenes} scenes × {frames_per_scene} views at "
          f"{recipe.camera.width}×{recipe.camera.height}, "
          f"{recipe.render.samples} samples{' + denoise' if recipe.render.denoise else ''}; "
          f"{args.num_shards} shard(s) → {args.dataset}")  # fmt: skip
    start = time.perf_counter()
    generation = Generation(args, frames_per_scene, total)
    with tqdm(
        total=generation.total,
        initial=generation.initial,
        unit="img",
        desc=recipe.name,
        dynamic_ncols=True,
        smoothing=0.1,
    ) as pbar:
        rendered = generation.run(pbar)
    partial = args.dataset / PARTIAL
    # only a driver of every shard: drivers of other shards may be writing chunks in there
    if (
        args.shards is None
        and partial.is_dir()
        and not any(p.suffix == ".parquet" for p in partial.rglob("*"))
    ):
        shutil.rmtree(partial)
    elapsed = time.perf_counter() - start
    print(f"dataset: {args.dataset} ({rendered} new frames in {elapsed:.0f} s)")
    if args.no_inspect:
        return 0
    if not args.boxpose.is_file():
        raise DriverError(
            f"{args.boxpose} is missing: build it with `cargo build --release -p boxpose-cli` "
            "(or pass --no-inspect)"
        )
    r = subprocess.run([str(args.boxpose), "inspect", str(args.dataset)])
    if r.returncode != 0:
        raise DriverError(f"`boxpose inspect {args.dataset}` found problems (exit {r.returncode})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
