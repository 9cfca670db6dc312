"""Scale-out of `make scenes` and `boxpose search` over a Ray cluster (docs/scale-out.md).

Ray only schedules: the unit of work is an idempotent, deterministic call of the project's own
command on one key — `scripts/make_scenes.py --shards i` for shard i of a dataset,
`boxpose search … --batch K:B` for batch B of search iteration K — which publishes its output
atomically in the output folder, so a retried task rewrites identical rows and a finished key is
skipped. Durable state lives in that folder, never only in Ray's object store: killing the
driver, a worker or the whole cluster and running the same command again resumes, and the tables
equal a single-process run's with the same seed.

Every node needs the repository at the same path with `make setup` run, and the output folder on
a filesystem every node sees.
"""

from __future__ import annotations

import ctypes
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import ray

REPO = Path(__file__).resolve().parent.parent.parent
BOXPOSE = REPO / "target" / "release" / "boxpose"
MAKE_SCENES = REPO / "scripts" / "make_scenes.py"

__all__ = [
    "StageFailed",
    "StageInterrupted",
    "TaskResources",
    "check_search_args",
    "connect",
    "generate_scenes",
    "search",
]


class StageFailed(RuntimeError):
    """A stage exited with an error (a bad recipe, a missing tool…): retrying would fail again."""


class StageInterrupted(RuntimeError):
    """A stage was killed by a signal (out of memory, a stopped node): Ray retries the task."""


# Progress: (what, done, total) — e.g. ("shards", 3, 8) or ("mc 0", 150, 200); the CLI draws it.
Progress = Callable[[str, int, int], None]


def connect(address: str) -> None:
    """`local`: a private Ray instance on this machine, bound to the loopback address;
    `auto`: the cluster this machine belongs to (`ray start`); otherwise `HOST:PORT` of a head."""
    if address == "local":
        # Ray binds the machine's network address unless told that this is no cluster.
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
    else:
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        except ConnectionError as e:
            raise StageFailed(
                f"no Ray cluster answered at {address} ({e}). Start one with `ray start --head`; "
                "a cluster with token authentication needs RAY_AUTH_MODE=token (and its token) "
                "here as on the head (docs/scale-out.md)"
            ) from e


# Looked up here, not in the forked child: between fork and exec the child may not take the
# dynamic loader's lock, which another thread of the Ray worker could hold.
_prctl = ctypes.CDLL(None, use_errno=True).prctl
PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the stage process: SIGTERM when the Ray worker that started it dies (a killed worker
    must not leave its stage writing beside the retried one; SIGTERM lets make_scenes stop its
    Blender workers)."""
    _prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _tail(text: str, lines: int = 20) -> str:
    return "\n".join("    " + line for line in text.strip().splitlines()[-lines:])


def _run(command: list[str], where: str, **popen) -> str:
    """`command` run in the repository; its stdout, or StageInterrupted (killed by a signal) or
    StageFailed (an error exit) with the end of its stderr, naming `where` it ran."""
    r = subprocess.run(command, cwd=REPO, capture_output=True, text=True, **popen)
    if r.returncode < 0:
        raise StageInterrupted(
            f"`{shlex.join(command)}` {where} was killed by "
            f"{signal.Signals(-r.returncode).name}:\n{_tail(r.stderr)}"
        )
    if r.returncode != 0:
        raise StageFailed(
            f"`{shlex.join(command)}` failed {where} (exit {r.returncode}):\n{_tail(r.stderr)}"
        )
    return r.stdout


@ray.remote(max_retries=3, retry_exceptions=[StageInterrupted])
def run_stage(command: list[str]) -> str:
    """One unit of work on a node: `command` run in the repository; its stdout."""
    node = socket.gethostname()
    if not Path(command[0]).is_file():
        raise StageFailed(
            f"{node} has no {command[0]}: every node needs the repository at {REPO} with "
            "`make setup` run (docs/scale-out.md)"
        )
    return _run(command, f"on {node}", preexec_fn=_die_with_parent)


def _local(command: list[str]) -> str:
    """A step of the driver itself (planning, merging): run here, its errors are the driver's."""
    return _run(command, "on the driver's machine")


@dataclass(frozen=True)
class TaskResources:
    """What Ray reserves for each task: CPUs (also each task's Cycles threads) and GPUs (for a
    search with `--backend cuda` or `wgpu`; Ray sets CUDA_VISIBLE_DEVICES to the task's)."""

    cpus: float = 1
    gpus: float = 0

    def threads(self) -> int:
        return max(1, int(self.cpus))


def _run_all(
    commands: Iterable[tuple[list[str], int]],
    resources: TaskResources,
    advance: Callable[[int], None],
) -> None:
    """Runs every (command, weight) as a task with `resources`, at most twice as many queued as
    the cluster runs at once (`ray.wait` as backpressure, enough that no CPU waits for the
    driver); `advance(weight)` as each finishes. The first failure cancels the rest and is
    raised (what finished is kept in the output folder)."""
    queue = list(commands)
    cpus = ray.cluster_resources().get("CPU", 1)
    max_in_flight = max(1, int(2 * cpus // max(resources.cpus, 1e-9)))
    task = run_stage.options(num_cpus=resources.cpus, num_gpus=resources.gpus)
    in_flight: dict[ray.ObjectRef, int] = {}
    try:
        while queue or in_flight:
            while queue and len(in_flight) < max_in_flight:
                command, weight = queue.pop(0)
                in_flight[task.remote(command)] = weight
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                weight = in_flight.pop(ref)
                ray.get(ref)
                advance(weight)
    finally:
        for ref in in_flight:
            ray.cancel(ref, force=True)


def generate_scenes(
    recipe: str,
    dataset: Path,
    num_shards: int,
    *,
    num_scenes: int | None = None,
    resources: TaskResources = TaskResources(),
    progress: Progress = lambda *_: None,
) -> None:
    """`make scenes` with one Ray task per shard (Drake scenes, then Blender renders), then
    `make_scenes.py` over the whole dataset here: it finds every shard complete, removes the
    unfinished-chunk folder and validates the dataset with `boxpose inspect`."""
    dataset = Path(dataset).resolve()
    base = [sys.executable, str(MAKE_SCENES), "--recipe", recipe, "--dataset", str(dataset)]
    base += ["--num-shards", str(num_shards)]
    if num_scenes is not None:
        base += ["--num-scenes", str(num_scenes)]
    # A retried shard may start while its killed predecessor still stops its Blender workers.
    task = [*base, "--no-inspect", "--threads", str(resources.threads()), "--lock-wait", "60"]
    commands = [([*task, "--shards", str(shard)], 1) for shard in range(num_shards)]
    done = 0

    def advance(weight: int) -> None:
        nonlocal done
        done += weight
        progress("shards", done, num_shards)

    progress("shards", 0, num_shards)
    _run_all(commands, resources, advance)
    _local([*base, "--boxpose", str(BOXPOSE)])


@dataclass(frozen=True)
class PendingWork:
    """`boxpose search … --pending`: the current iteration's uncommitted batches."""

    iteration: int
    stage: str
    samples: int
    batch_size: int
    batches: list[int]
    complete: bool

    def batch_samples(self, batch: int) -> int:
        return min(self.batch_size, self.samples - batch * self.batch_size)


REFUSED_SEARCH_OPTIONS = ("--shard", "--num-shards", "--batch", "--pending")


def _option(args: list[str], name: str) -> str | None:
    """The value of `--name V` or `--name=V` in `args`, or None."""
    for i, a in enumerate(args):
        if a.startswith(name + "="):
            return a.split("=", 1)[1]
        if a == name and i + 1 < len(args):
            return args[i + 1]
    return None


def check_search_args(search_args: list[str]) -> None:
    """Refuses, before any cluster starts, what the driver must set itself or cannot do without."""
    for option in REFUSED_SEARCH_OPTIONS:
        if any(a == option or a.startswith(option + "=") for a in search_args):
            raise StageFailed(f"{option} is the driver's to set: leave it out")
    if _option(search_args, "--out") is None:
        raise StageFailed("give the run folder with --out (on a filesystem every node sees)")


def search(
    search_args: list[str],
    *,
    resources: TaskResources = TaskResources(),
    progress: Progress = lambda *_: None,
) -> str:
    """`boxpose search SEARCH_ARGS` (which must hold `--out RUN`) with one Ray task per batch.
    The driver asks `--pending` for the current iteration's batches, runs them as tasks, and asks
    again: the cross-entropy proposal moves only at that barrier, from every batch of the
    iteration, as in one process. Then `search merge` and `search report`; returns the estimate
    that merge prints."""
    check_search_args(search_args)
    if _option(search_args, "--threads") is None:
        # one Cycles thread per CPU the task holds, not every core of the node
        search_args = [*search_args, "--threads", str(resources.threads())]
    command = [str(BOXPOSE), "search", *search_args]
    while True:
        pending = PendingWork(**json.loads(_local([*command, "--pending"])))
        if pending.complete:
            break
        what = f"{pending.stage} {pending.iteration}"
        done = pending.samples - sum(pending.batch_samples(b) for b in pending.batches)

        def advance(weight: int, what=what, total=pending.samples) -> None:
            nonlocal done
            done += weight
            progress(what, done, total)

        progress(what, done, pending.samples)
        tasks = [
            ([*command, "--batch", f"{pending.iteration}:{b}"], pending.batch_samples(b))
            for b in pending.batches
        ]
        _run_all(tasks, resources, advance)
    out = _option(search_args, "--out")
    estimate = _local([str(BOXPOSE), "search", "merge", out])
    _local([str(BOXPOSE), "search", "report", out])
    return estimate
