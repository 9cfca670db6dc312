"""The render stage as a dataset producer: the `make scenes` driver and its Blender workers.
Inputs are synthetic `scenes` / `objects` shards (no Drake needed); renders are 64², 1 sample."""

import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import bpy  # noqa: F401  (installed by `make setup`: a missing bpy fails, never skips)
import numpy as np
import pandas as pd
import pytest
from PIL import Image

import boxpose_io
from blender_scripts.synthetic import synthetic_scene

REPO = Path(__file__).resolve().parent.parent
DRIVER = [sys.executable, str(REPO / "scripts" / "make_scenes.py")]

spec = importlib.util.spec_from_file_location("make_scenes", REPO / "scripts" / "make_scenes.py")
make_scenes = importlib.util.module_from_spec(spec)
spec.loader.exec_module(make_scenes)


def write_inputs(
    dataset: Path,
    scenes_objects: list[tuple[dict, list[dict]]],
    shard: int = 0,
    num_shards: int = 1,
) -> None:
    scenes = [s for s, _ in scenes_objects]
    objects = [o for _, objs in scenes_objects for o in objs]
    boxpose_io.write_shard(
        boxpose_io.shard_path(dataset, "scenes", shard, num_shards),
        boxpose_io.table_from_rows("scenes", scenes),
    )
    boxpose_io.write_shard(
        boxpose_io.shard_path(dataset, "objects", shard, num_shards),
        boxpose_io.table_from_rows("objects", objects),
    )


def tiny_scenes(n: int = 2, first_id: int = 0) -> list[tuple[dict, list[dict]]]:
    text = (REPO / "datasets" / "recipes" / "tiny.toml").read_text()
    return [
        synthetic_scene(first_id + k, text, 1 + k % 3, seed=100 + first_id + k) for k in range(n)
    ]


def run_driver(dataset: Path, *extra: str, env: dict | None = None) -> subprocess.CompletedProcess:
    cmd = DRIVER + ["--recipe", "tiny", "--dataset", str(dataset), "--no-inspect", *extra]
    return subprocess.run(
        cmd,
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        cwd=REPO,
        timeout=600,
    )


def no_render_outputs(dataset: Path) -> bool:
    return not any(
        (dataset / t).glob("*") for t in ("frames", "instances") if (dataset / t).exists()
    )


def test_driver_renders_resumes_and_pandas_reads_it(tmp_path, boxpose_bin):
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(3))
    r = run_driver(dataset, "--scenes-per-worker", "2")
    assert r.returncode == 0, r.stderr
    assert f"dataset: {dataset}" in r.stdout
    assert not (dataset / ".partial").exists()

    # pandas alone (no boxpose) opens it, and the images decode
    frames = pd.read_parquet(dataset / "frames")
    instances = pd.read_parquet(dataset / "instances")
    assert len(frames) == 3 and sorted(frames.scene_id) == [0, 1, 2]
    assert len(instances) == 1 + 2 + 3
    f = frames.iloc[0]
    rgb = np.asarray(Image.open(io.BytesIO(f.rgb_png)))
    assert rgb.shape == (64, 64, 3) and rgb.dtype == np.uint8
    depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(f.height, f.width)
    assert (depth > 0).mean() > 0.5
    mask = np.asarray(Image.open(io.BytesIO(f.instance_mask_png)))
    assert mask.shape == (64, 64)
    corners = np.stack(instances.corners_camera_m.to_numpy()).reshape(-1, 8, 3)
    assert np.isfinite(corners).all()

    # resume: nothing left to do
    mtime = (dataset / "frames" / "part-00000-of-00001.parquet").stat().st_mtime_ns
    r = run_driver(dataset)
    assert r.returncode == 0, r.stderr
    assert "(0 new frames" in r.stdout
    assert (dataset / "frames" / "part-00000-of-00001.parquet").stat().st_mtime_ns == mtime

    r = subprocess.run([str(boxpose_bin), "inspect", str(dataset)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_render_crash_leaves_no_shard_and_resume_finishes(tmp_path, jobs):
    """With two jobs, scene 0's worker runs while scene 1's crashes: it finishes its chunk first."""
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(2))
    crash = {"BOXPOSE_TEST_CRASH_SCENE": "1"}
    r = run_driver(dataset, "--scenes-per-worker", "1", "--jobs", jobs, env=crash)
    assert r.returncode == 1
    assert "Blender worker crashed (SIGABRT) while rendering shard 0 of 1, scene 1" in r.stderr
    assert no_render_outputs(dataset)
    chunks = sorted(p.name for p in (dataset / ".partial").rglob("*.parquet"))
    assert chunks == [
        "frames-000000-000001.parquet",
        "instances-000000-000001.parquet",
    ]  # scene 0 is kept
    r = run_driver(dataset, "--scenes-per-worker", "1")
    assert r.returncode == 0, r.stderr
    assert sorted(pd.read_parquet(dataset / "frames").scene_id) == [0, 1]


def test_parallel_jobs_write_the_dataset_one_job_writes(tmp_path):
    """Two workers at once over two shards (chunks of one scene) write the tables, row for row
    and pixel for pixel, that one worker writes."""
    tables = {}
    for jobs in ("1", "2"):
        dataset = tmp_path / f"jobs-{jobs}"
        write_inputs(dataset, tiny_scenes(3)[:2], shard=0, num_shards=2)
        write_inputs(dataset, tiny_scenes(1, first_id=2), shard=1, num_shards=2)
        r = run_driver(
            dataset, "--num-shards", "2", "--num-scenes", "3", "--jobs", jobs,
            "--scenes-per-worker", "1",
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert not (dataset / ".partial").exists()
        tables[jobs] = {
            t: pd.read_parquet(dataset / t).drop(columns="render_time_s", errors="ignore")
            for t in ("frames", "instances")
        }
    for table in ("frames", "instances"):
        assert len(tables["2"][table]) > 0
        pd.testing.assert_frame_equal(tables["1"][table], tables["2"][table])


def test_a_resume_keeps_the_chunks_of_other_settings(tmp_path):
    """Chunks rendered under another --scenes-per-worker or --jobs are kept; only the scene
    positions they leave are split into new chunks."""
    chunk_dir = tmp_path / "shard"
    chunk_dir.mkdir()
    for start, stop in [(0, 2), (5, 6)]:
        for table in ("frames", "instances"):
            (chunk_dir / f"{table}-{start:06d}-{stop:06d}.parquet").touch()
    (chunk_dir / "frames-000003-000004.parquet").touch()  # its instances file never came
    done, todo = make_scenes.plan_chunks(chunk_dir, 10, 2)
    assert done == [(0, 2), (5, 6)]
    assert todo == [(2, 4), (4, 5), (6, 8), (8, 10)]
    assert make_scenes.plan_chunks(chunk_dir, 0, 5) == (done, [])
    assert make_scenes.plan_chunks(tmp_path / "empty", 3, 0) == ([], [(0, 1), (1, 2), (2, 3)])


def test_missing_object_is_one_clear_error(tmp_path):
    dataset = tmp_path / "tiny"
    (scene, objects), other = tiny_scenes(3)[2], tiny_scenes(1)[0]
    write_inputs(dataset, [other, (scene, [objects[0], objects[2]])])
    r = run_driver(dataset)
    assert r.returncode == 1
    assert (
        "scene 2 in shard 0 of 1 (part-00000-of-00001.parquet) declares num_objects=3 "
        "but objects holds object_ids [0, 2]; missing [1]" in r.stderr
    )
    assert "Traceback" not in r.stderr
    assert no_render_outputs(dataset)


def test_object_of_a_missing_scene_is_one_clear_error(tmp_path):
    dataset = tmp_path / "tiny"
    good = tiny_scenes(1)
    _, stray_objects = tiny_scenes(1, first_id=5)[0]
    write_inputs(dataset, good)
    objects = good[0][1] + stray_objects
    boxpose_io.write_shard(
        boxpose_io.shard_path(dataset, "objects", 0, 1),
        boxpose_io.table_from_rows("objects", objects),
    )
    r = run_driver(dataset)
    assert r.returncode == 1
    assert (
        "objects row (scene_id=5, object_id=0) in shard 0 of 1 (part-00000-of-00001.parquet) "
        "references scene 5, which is not in the scenes table" in r.stderr
    )
    assert no_render_outputs(dataset)


def test_missing_bpy_is_one_clear_error(tmp_path):
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(1))
    fake = tmp_path / "nobpy" / "bpy"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('No module named bpy (simulated)')\n")
    r = run_driver(dataset, env={"PYTHONPATH": str(fake.parent)})
    assert r.returncode == 1
    assert "error: bpy is not importable by" in r.stderr and "make setup" in r.stderr
    assert no_render_outputs(dataset)


def test_worker_alone_writes_the_shard(tmp_path):
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(1, first_id=3), shard=1, num_shards=2)
    cmd = [
        sys.executable,
        "-m",
        "blender_scripts.worker",
        "--dataset",
        str(dataset),
        "--shard",
        "1",
        "--num-shards",
        "2",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    frames = pd.read_parquet(dataset / "frames" / "part-00001-of-00002.parquet")
    assert list(frames.scene_id) == [3]
    assert (dataset / "instances" / "part-00001-of-00002.parquet").is_file()


def worker_pids(dataset: Path) -> list[int]:
    """Blender worker processes rendering `dataset` (from /proc: no psutil needed)."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().split(b"\0")
        except OSError:
            continue
        if b"blender_scripts.worker" in args and str(dataset).encode() in args:
            pids.append(int(cmdline.parent.name))
    return pids


def alive(pid: int) -> bool:
    """Running and not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def start_driver(dataset: Path, *extra: str) -> tuple[subprocess.Popen, int]:
    """The driver on two tiny scenes, and the pid of its first worker once that has started."""
    write_inputs(dataset, tiny_scenes(2))
    cmd = DRIVER + ["--recipe", "tiny", "--dataset", str(dataset), "--no-inspect", *extra]
    driver = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (pids := worker_pids(dataset)):
        assert time.monotonic() < deadline and driver.poll() is None, "no worker started"
        time.sleep(0.05)
    return driver, pids[0]


def test_a_hung_worker_is_stopped_by_the_watchdog(tmp_path):
    """A worker that stops reporting progress (here: SIGSTOP, as a deadlock would) is killed
    after --worker-timeout, with a message that says so, and resume finishes the shard."""
    dataset = tmp_path / "tiny"
    driver, worker = start_driver(dataset, "--worker-timeout", "3", "--scenes-per-worker", "1")
    os.kill(worker, signal.SIGSTOP)
    _, stderr = driver.communicate(timeout=60)
    assert driver.returncode == 1, stderr
    assert "made no progress for 3 s (--worker-timeout)" in stderr
    assert not alive(worker)
    assert no_render_outputs(dataset)
    r = run_driver(dataset)
    assert r.returncode == 0, r.stderr
    assert sorted(pd.read_parquet(dataset / "frames").scene_id) == [0, 1]


def test_sigterm_to_the_driver_stops_its_workers(tmp_path):
    dataset = tmp_path / "tiny"
    driver, worker = start_driver(dataset)
    os.kill(worker, signal.SIGSTOP)  # still rendering when the signal comes, however fast it is
    driver.send_signal(signal.SIGTERM)
    _, stderr = driver.communicate(timeout=60)
    assert driver.returncode == 128 + signal.SIGTERM, stderr
    assert "stopped by SIGTERM: run the same command again to resume" in stderr
    assert not alive(worker) and not worker_pids(dataset)


def test_a_resume_with_other_settings_is_refused_or_regenerated(tmp_path):
    """The folder's manifest.json remembers the recipe text, scene count and shard count; a
    resume with another one would mix two datasets."""
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(2))
    r = run_driver(dataset)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((dataset / "manifest.json").read_text())
    assert (manifest["recipe"], manifest["num_scenes"], manifest["num_shards"]) == ("tiny", 2, 1)

    r = run_driver(dataset, "--num-scenes", "1")
    assert r.returncode == 1
    assert "num_scenes 2 then, 1 now" in r.stderr and "--regenerate" in r.stderr
    r = run_driver(dataset, "--num-shards", "2")
    assert r.returncode == 1 and "num_shards 1 then, 2 now" in r.stderr
    assert sorted(pd.read_parquet(dataset / "frames").scene_id) == [0, 1]  # nothing lost

    r = run_driver(dataset, "--num-scenes", "1", "--regenerate")
    assert r.returncode == 0, r.stderr
    assert "--regenerate: deleted" in r.stdout
    assert len(pd.read_parquet(dataset / "scenes")) == 1  # the Drake stage ran again
    assert json.loads((dataset / "manifest.json").read_text())["num_scenes"] == 1


def test_rendered_tables_without_a_manifest_are_another_commands_dataset(tmp_path):
    """A folder with frames but no manifest.json (`boxpose render`, an older boxpose) is not
    adopted: its tables would be mixed with this recipe's. --regenerate deletes them."""
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(2))
    assert run_driver(dataset).returncode == 0
    (dataset / "manifest.json").unlink()
    before = {p: p.read_bytes() for p in dataset.rglob("*.parquet")}
    r = run_driver(dataset)
    assert r.returncode == 1
    assert "without the manifest.json" in r.stderr and "--regenerate" in r.stderr, r.stderr
    assert {p: p.read_bytes() for p in dataset.rglob("*.parquet")} == before
    assert not (dataset / "manifest.json").exists()
    r = run_driver(dataset, "--regenerate")
    assert r.returncode == 0, r.stderr
    assert "--regenerate: deleted" in r.stdout and (dataset / "manifest.json").is_file()


def test_a_second_driver_on_one_dataset_is_refused(tmp_path):
    dataset = tmp_path / "tiny"
    first, worker = start_driver(dataset)
    os.kill(worker, signal.SIGSTOP)  # hold the first driver mid-render, however fast it is
    try:
        r = run_driver(dataset)
        assert r.returncode == 1
        assert f"{dataset} is being generated by make scenes (pid {first.pid})" in r.stderr
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=60)
    assert not alive(worker)
    r = run_driver(dataset)  # the lock went with the first driver
    assert r.returncode == 0, r.stderr


def test_drivers_of_other_shards_run_side_by_side_and_of_one_shard_are_refused(tmp_path):
    """What `python -m boxpose_ray scenes` relies on: a driver of some shards (--shards) holds
    only those; another driver of shard 1 runs beside it, a second of shard 0 or one of every
    shard is refused."""
    dataset = tmp_path / "tiny"
    write_inputs(dataset, tiny_scenes(1), shard=0, num_shards=2)
    write_inputs(dataset, tiny_scenes(1, first_id=1), shard=1, num_shards=2)
    two = ("--num-shards", "2", "--num-scenes", "2")
    cmd = DRIVER + ["--recipe", "tiny", "--dataset", str(dataset), "--no-inspect", *two]
    first = subprocess.Popen([*cmd, "--shards", "0"], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (pids := worker_pids(dataset)):
        assert time.monotonic() < deadline and first.poll() is None, "no worker started"
        time.sleep(0.05)
    os.kill(pids[0], signal.SIGSTOP)  # hold shard 0's driver mid-render
    try:
        r = run_driver(dataset, *two, "--shards", "0")
        held = f"shard 0 of 2 of {dataset} is being generated by make scenes (pid {first.pid})"
        assert r.returncode == 1 and held in r.stderr, r.stderr
        r = run_driver(dataset, *two)
        assert r.returncode == 1 and f"{dataset} is being generated by" in r.stderr, r.stderr
        r = run_driver(dataset, *two, "--shards", "1")
        assert r.returncode == 0, r.stderr
    finally:
        os.kill(pids[0], signal.SIGCONT)
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert sorted(pd.read_parquet(dataset / "frames").scene_id) == [0, 1]


def test_a_folder_holding_other_files_is_refused(tmp_path):
    dataset = tmp_path / "mine"
    write_inputs(dataset, tiny_scenes(1))
    (dataset / "notes.txt").write_text("not boxpose's")
    r = run_driver(dataset)
    assert r.returncode == 1 and "holds files that are not a dataset's (notes.txt)" in r.stderr
    assert no_render_outputs(dataset) and (dataset / "notes.txt").read_text() == "not boxpose's"
