"""`python -m boxpose_ray` on a real Ray cluster that the tests start on the loopback address
(a head node with two worker processes; Ray refuses a second node on loopback) and stop: the
tables equal a single-process run's, a worker killed mid-task is retried to the same result,
and a killed driver resumes. Search at 96² and 1 sample, scenes with the `tiny` recipe."""

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

import boxpose_io
from conftest import REPO
from test_search import MC, SPACE, recipe, search

DRIVER = [sys.executable, "-m", "boxpose_ray"]
RAY_ENV = {
    # Ray binds the machine's network address unless told that this is no multi-node cluster
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    # token authentication, with a token of this test run's for the head and the driver alike
    "RAY_AUTH_MODE": "token",
    "RAY_AUTH_TOKEN": secrets.token_hex(32),
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster():
    """`ray start --head` on 127.0.0.1 with 2 CPUs (two worker processes); `ray stop` after."""
    env = {**os.environ, **RAY_ENV}
    port = free_port()
    # Ray's socket paths must stay short: not under pytest's long temporary folders
    temp = tempfile.mkdtemp(prefix="ray-", dir="/tmp")
    ray = str(Path(sys.executable).parent / "ray")
    start = [ray, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}"]
    start += ["--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats"]
    r = subprocess.run([*start, f"--temp-dir={temp}"], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([ray, "stop", "--force"], env=env, capture_output=True)
        shutil.rmtree(temp, ignore_errors=True)


def driver(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [*DRIVER, *map(str, args)],
        cwd=REPO,
        env={**os.environ, **RAY_ENV},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def finish(process: subprocess.Popen) -> str:
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, out + err
    return out


def processes() -> dict[int, tuple[int, str]]:
    """pid → (parent pid, command line) of every process."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError, ValueError):
            continue
        found[int(stat.parent.name)] = (parent, cmdline)
    return found


def batch_stage() -> tuple[int, int, str] | None:
    """A running `boxpose search … --batch` started by a Ray worker: (its pid, the worker's pid,
    the batch)."""
    for pid, (parent, cmdline) in processes().items():
        if " search " in cmdline and " --batch " in cmdline:
            return pid, parent, cmdline.split(" --batch ")[1].split()[0]
    return None


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def batch_file(batch: str) -> str:
    """Batch K:B's file name in the run folder (`Run::batch_name` in rust/search/src/run/mod.rs)."""
    iteration, index = batch.split(":")
    return f"iter-{int(iteration):04d}-batch-{int(index):05d}.parquet"


def run_args(space: Path, out: Path) -> list:
    return [space, "--out", out, "--fail-when", "mssd:0.05", *MC]


@pytest.fixture(scope="module")
def space(tmp_path_factory) -> Path:
    """test_search's single-box space at 96², 1 sample."""
    root = tmp_path_factory.mktemp("space")
    (root / "floor.toml").write_text(recipe("single_box"))
    (root / "single.toml").write_text(SPACE.format(recipe=root / "floor.toml"))
    return root / "single.toml"


@pytest.fixture(scope="module")
def single_process_run(space, boxpose_bin, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("single") / "run"
    search(boxpose_bin, *run_args(space, out))
    return out


def test_a_worker_killed_mid_batch_is_retried_to_the_single_process_table(
    cluster, space, single_process_run, tmp_path
):
    out = tmp_path / "run"
    run = driver("search", "--address", cluster, "--", *run_args(space, out))
    deadline = time.monotonic() + 120
    while (found := batch_stage()) is None:
        assert run.poll() is None, run.communicate()
        assert time.monotonic() < deadline, "no batch started"
        time.sleep(0.02)
    stage, worker, batch = found
    assert "ray::" in processes()[worker][1], processes()[worker]  # a Ray worker runs it
    committed = out / "batches" / "samples" / batch_file(batch)
    os.kill(worker, signal.SIGKILL)
    was_committed = committed.exists()
    finish(run)
    assert not was_committed, "the batch finished before the kill: the test tested nothing"
    assert not alive(stage), "the stage outlived its worker"
    assert (out / "samples.parquet").read_bytes() == (
        single_process_run / "samples.parquet"
    ).read_bytes()
    assert (out / "report" / "index.html").is_file()


def test_a_killed_driver_resumes_to_the_single_process_table(
    cluster, space, single_process_run, tmp_path
):
    out = tmp_path / "run"
    args = ["search", "--address", cluster, "--", *run_args(space, out)]
    first = driver(*args)
    batches = out / "batches" / "samples"
    deadline = time.monotonic() + 120
    while not (batches.is_dir() and any(batches.glob("*.parquet"))):
        assert first.poll() is None, first.communicate()
        assert time.monotonic() < deadline, "no batch committed"
        time.sleep(0.02)
    first.kill()
    first.communicate()
    kept = {p.name: p.stat().st_mtime_ns for p in batches.glob("*.parquet")}
    assert not (out / "samples.parquet").exists()
    finish(driver(*args))
    assert (out / "samples.parquet").read_bytes() == (
        single_process_run / "samples.parquet"
    ).read_bytes()
    # what the killed driver's tasks committed was kept, not recomputed
    assert all((batches / name).stat().st_mtime_ns == mtime for name, mtime in kept.items())


def test_cross_entropy_moves_its_proposal_only_at_the_barriers(
    cluster, space, boxpose_bin, tmp_path
):
    """Tuning iterations of 6 samples in 3 batches: the proposals and every sample equal the
    single process's, which sees each iteration whole."""
    ce = ["--sampler", "ce", "--samples", 4, "--batch-size", 2, "--ce-samples-per-iteration", 6]
    ce += ["--ce-max-iterations", 2, "--ce-rho", 0.5, "--fail-when", "mssd:0.02", "--threads", 1]
    alone, spread = tmp_path / "alone", tmp_path / "spread"
    search(boxpose_bin, space, "--out", alone, *ce)
    finish(driver("search", "--address", cluster, "--", space, "--out", spread, *ce))
    proposals = sorted(p.name for p in (alone / "proposals").iterdir())
    assert len(proposals) >= 1
    assert proposals == sorted(p.name for p in (spread / "proposals").iterdir())
    for name in proposals:
        assert (spread / "proposals" / name).read_bytes() == (
            alone / "proposals" / name
        ).read_bytes()
    assert (spread / "samples.parquet").read_bytes() == (alone / "samples.parquet").read_bytes()


def without_clock(tables: dict) -> dict:
    """Every table, less the frames' wall-clock render time."""
    frames = tables["frames"]
    return {**tables, "frames": frames.drop(["render_time_s"])}


def test_scenes_on_the_cluster_equal_the_single_process_dataset(cluster, tmp_path):
    spread, alone = tmp_path / "spread", tmp_path / "alone"
    out = finish(
        driver("scenes", "--address", cluster, "--recipe", "tiny", "--dataset", spread,
               "--num-shards", 2)
    )  # fmt: skip
    assert f"dataset: {spread}" in out
    r = subprocess.run(
        [sys.executable, "scripts/make_scenes.py", "--recipe", "tiny", "--dataset", alone,
         "--num-shards", "2", "--no-inspect"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    a, b = (without_clock(boxpose_io.read_dataset(d)) for d in (spread, alone))
    for table in boxpose_io.TABLES:
        assert a[table].num_rows > 0 and a[table].equals(b[table]), table
    # the final step cleaned up and validated: no unfinished chunks are left
    assert not (spread / ".partial").exists()


def test_bad_driver_arguments_are_refused_before_any_cluster_starts(tmp_path):
    for args, message in [
        (["--", "single_box", "--samples", "4"], "give the run folder with --out"),
        (["--", "single_box", "--out", tmp_path, "--shard", "1"], "--shard is the driver's"),
        (["--", "single_box", "--out", tmp_path, "--batch=0:1"], "--batch is the driver's"),
    ]:
        started = time.monotonic()
        r = driver("search", "--address", "127.0.0.1:1", *args)
        out, err = r.communicate(timeout=60)
        assert r.returncode == 1 and f"error: {message}" in err, err
        assert time.monotonic() - started < 20  # no connection attempt to the absent head
