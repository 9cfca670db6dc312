"""Crash consistency and I/O errors of the shard writers, Python's and Rust's.

A write that fails from some byte on (a file-size limit, as a full disk) is one error and leaves
no file (in `make test`). With strace (`make test-faults`, marker `faults`), a SIGKILL at the
k-th write, fsync or rename system call of the writing process, for every k until the write
completes: the shard is then absent or whole, never a torn file under its final name, and a
rerun writes it whole. The Rust writer (`boxpose_data::writer`, behind every Rust shard and
result table) is driven through `boxpose eval-geometry`, which writes one result table."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import render_synthetic_dataset

WRITER = """
import resource, signal, sys
from pathlib import Path
import boxpose_io

if len(sys.argv) > 3:  # a file-size limit: writes past it fail (EFBIG), as on a full disk
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limit = int(sys.argv[3])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

rows = [
    dict(
        scene_id=i, seed=1000 + i, recipe="faults", recipe_toml='name = "faults"\\n',
        tool_versions="{}", physics_backend="drake", support="floor", num_objects=1,
        solver="SNOPT", solver_status="SolutionFound", solve_attempts=1,
        settle_time_s=0.5 + i / 1000, max_linear_speed_mps=1e-4, max_angular_speed_radps=1e-3,
        min_signed_distance_m=1e-3, stable=True,
    )
    for i in range(int(sys.argv[2]))
]
path = boxpose_io.shard_path(Path(sys.argv[1]), "scenes", 0, 1)
boxpose_io.write_shard(path, boxpose_io.table_from_rows("scenes", rows))
"""

ROWS = 300


def strace() -> str:
    path = shutil.which("strace")
    assert path, "the fault tests need strace (apt-get install strace)"
    return path


def write(dataset: Path, *inject: str, size_limit: int | None = None):
    """The writer, under strace with the given fault injections (none: a plain run), with an
    optional file-size limit in bytes."""
    command = [sys.executable, "-c", WRITER, str(dataset), str(ROWS)]
    if size_limit is not None:
        command.append(str(size_limit))
    if inject:
        command = [strace(), "-f", "-qq", "-o", os.devnull, *inject, *command]
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=120)


def shard(dataset: Path) -> Path:
    return dataset / "scenes" / "part-00000-of-00001.parquet"


def leftovers(dataset: Path) -> list[str]:
    folder = dataset / "scenes"
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


@pytest.fixture(scope="module")
def expected(tmp_path_factory) -> pd.DataFrame:
    dataset = tmp_path_factory.mktemp("reference")
    assert write(dataset).returncode == 0
    return pd.read_parquet(shard(dataset))


@pytest.mark.faults
@pytest.mark.parametrize("syscall", ["write", "fsync", "rename"])
def test_a_kill_at_every_step_leaves_the_shard_absent_or_whole(tmp_path, expected, syscall):
    kills = 0
    for k in range(1, 200):
        dataset = tmp_path / f"{syscall}-{k}"
        r = write(dataset, "-e", f"inject={syscall}:signal=SIGKILL:when={k}")
        if r.returncode == 0:
            break  # the k-th call never came: the write completed
        kills += 1
        if shard(dataset).exists():
            pd.testing.assert_frame_equal(pd.read_parquet(shard(dataset)), expected)
        rerun = write(dataset)
        assert rerun.returncode == 0, rerun.stderr
        pd.testing.assert_frame_equal(pd.read_parquet(shard(dataset)), expected)
    else:
        pytest.fail(f"the writer still died after 200 injected {syscall} kills")
    assert kills >= 1, f"no {syscall} call was interrupted"
    print(f"{syscall}: {kills} kills injected, no data lost")


def test_a_failing_disk_is_one_error_and_leaves_nothing(tmp_path):
    """Writes fail from a byte offset on (a file-size limit: EFBIG, as ENOSPC on a full disk;
    strace cannot fail the shard's writes alone without failing the error message's too)."""
    failures = 0
    for limit in [0, 1, 100, 1000, 4000, 8000, 12000, 16000, 1 << 30]:
        dataset = tmp_path / f"limit-{limit}"
        (dataset / "scenes").mkdir(parents=True)
        r = write(dataset, size_limit=limit)
        if r.returncode == 0:
            continue
        failures += 1
        assert "File too large" in r.stderr, r.stderr
        assert not shard(dataset).exists()
        assert leftovers(dataset) == []
    assert failures >= 3
    print(f"EFBIG: {failures} failed writes injected, no leftovers")


def eval_geometry(boxpose_bin: Path, dataset: Path, out: Path, *inject: str):
    """`boxpose eval-geometry` writing `out`, under strace with the given fault injections."""
    command = [str(boxpose_bin), "eval-geometry", str(dataset), "--out", str(out)]
    command += ["--outliers", "2", "--seed", "3"]
    if inject:
        command = [strace(), "-f", "-qq", "-o", os.devnull, *inject, *command]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def without_timings(path: Path) -> pd.DataFrame:
    """The table without its measured times (which differ from run to run)."""
    return pd.read_parquet(path).drop(columns="fit_time_us")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    return render_synthetic_dataset(tmp_path_factory.mktemp("rendered") / "ds", 48, 36)


@pytest.mark.faults
@pytest.mark.parametrize("syscall", ["write", "fsync", "rename"])
def test_a_kill_at_every_step_of_the_rust_writer_leaves_the_table_absent_or_whole(
    tmp_path, rendered, boxpose_bin, syscall
):
    reference = tmp_path / "reference.parquet"
    assert eval_geometry(boxpose_bin, rendered, reference).returncode == 0
    expected = without_timings(reference)
    kills = 0
    for k in range(1, 200):
        out = tmp_path / f"{syscall}-{k}" / "eval_geometry.parquet"
        r = eval_geometry(
            boxpose_bin, rendered, out, "-e", f"inject={syscall}:signal=SIGKILL:when={k}"
        )
        if r.returncode == 0:
            break  # the k-th call never came: the write completed
        kills += 1
        if out.exists():
            pd.testing.assert_frame_equal(without_timings(out), expected)
        rerun = eval_geometry(boxpose_bin, rendered, out)
        assert rerun.returncode == 0, rerun.stderr
        pd.testing.assert_frame_equal(without_timings(out), expected)
    else:
        pytest.fail(f"the writer still died after 200 injected {syscall} kills")
    assert kills >= 1, f"no {syscall} call was interrupted"
    print(f"Rust writer, {syscall}: {kills} kills injected, no data lost")
