"""No output replaces what it did not write (issue 31, item 2): every command that writes a dataset
or run folder, pointed at a folder that holds another dataset, refuses with a message naming the
folder and leaves every file of it byte for byte as it was, and adds none; and a folder another
boxpose process is writing into is refused the same way."""

import fcntl
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, render_synthetic_dataset

KEYPOINT_MODEL = REPO / "models" / "keypoint-slim"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """The valid input every command reads: two tiny synthetic scenes, two 32×24 views each."""
    return render_synthetic_dataset(tmp_path_factory.mktemp("outputs") / "input", 32, 24)


@pytest.fixture
def foreign(dataset, tmp_path) -> Path:
    """Another dataset, as `make scenes` leaves one: its tables and its manifest.json."""
    folder = tmp_path / "other-dataset"
    shutil.copytree(dataset, folder)
    manifest = {"recipe": "other", "recipe_sha256": "0" * 64, "num_scenes": 2, "num_shards": 1}
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return folder


@pytest.fixture(scope="module")
def search_run(boxpose_bin, tmp_path_factory) -> Path:
    """A finished search run folder (two samples, seed 99: another search than the table's)."""
    out = tmp_path_factory.mktemp("outputs-run") / "run"
    subprocess.run(
        [boxpose_bin, "search", "configs/search/single_box.toml", "--samples", "2",
         "--batch-size", "2", "--seed", "99", "--threads", "1", "--out", out],
        capture_output=True, text=True, cwd=REPO, timeout=300, check=True,
    )  # fmt: skip
    return out


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every path under `folder` with its bytes (None for a folder)."""
    return {
        str(p.relative_to(folder)): None if p.is_dir() else p.read_bytes()
        for p in sorted(folder.rglob("*"))
    }


# Each writing command, with valid other arguments, aimed at the folder OUT; DATASET is the input.
BOXPOSE_COMMANDS = {
    "render": ["render", "DATASET", "--scene", "0", "--out", "OUT"],
    "search": ["search", "configs/search/single_box.toml", "--out", "OUT"],
    "search variants": ["search", "variants", "RUN", "--out", "OUT"],
    "search replay": ["search", "replay", "RUN", "--sample", "0", "--out", "OUT"],
    "export bop": ["export", "bop", "DATASET", "OUT"],
    "export coco": ["export", "coco", "DATASET", "OUT"],
    "eval": ["eval", "DATASET", "--model", str(KEYPOINT_MODEL), "--out", "OUT"],
    "eval --sut": [
        "eval",
        "DATASET",
        "--sut",
        "python:examples.sut.pca_baseline:perceive",
        "--out",
        "OUT",
    ],
    "improve": [
        "improve",
        "configs/search/single_box.toml",
        "--dataset",
        "DATASET",
        "--out",
        "OUT",
    ],
    # a file path: aimed at another dataset's manifest
    "eval-geometry": ["eval-geometry", "DATASET", "--out", "OUT/manifest.json"],
    "eval-results bop": ["eval-results", "bop", "RESULTS", "DATASET", "--out", "OUT"],
    "predict": [
        "predict",
        "DATASET",
        "--scene",
        "0",
        "--frame",
        "0",
        "--model",
        str(KEYPOINT_MODEL),
        "--out",
        "OUT",
    ],
    "train": ["train", "--config", "configs/tiny.toml", "--dataset", "DATASET", "--out", "OUT"],
    "train-segmenter": [
        "train-segmenter",
        "--config",
        "configs/segmenter-tiny.toml",
        "--dataset",
        "DATASET",
        "--out",
        "OUT",
    ],
}


def command_line(name, boxpose_bin, dataset, foreign, tmp_path) -> list[str]:
    if name == "make scenes":
        return [
            sys.executable,
            str(REPO / "scripts" / "make_scenes.py"),
            "--recipe",
            "tiny",
            "--dataset",
            str(foreign),
            "--no-inspect",
        ]
    results = tmp_path / "results.csv"
    results.write_text("scene_id,im_id,obj_id,score,R,t,time\n")
    values = {
        "DATASET": str(dataset),
        "OUT": str(foreign),
        "RUN": str(tmp_path / "no-run-needed"),
        "RESULTS": str(results),
    }
    args = BOXPOSE_COMMANDS[name]
    return [str(boxpose_bin), *(values.get(a, a.replace("OUT", str(foreign))) for a in args)]


def run_command(name, boxpose_bin, dataset, out, tmp_path) -> subprocess.CompletedProcess:
    """Runs command `name` aimed at `out`, from the repository root."""
    return subprocess.run(
        command_line(name, boxpose_bin, dataset, out, tmp_path),
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )


@pytest.mark.parametrize("name", [*BOXPOSE_COMMANDS, "make scenes"])
def test_a_writing_command_refuses_a_folder_holding_another_dataset(
    name, boxpose_bin, dataset, foreign, tmp_path
):
    before = snapshot(foreign)
    result = run_command(name, boxpose_bin, dataset, foreign, tmp_path)
    assert result.returncode != 0, f"{name} wrote into another dataset:\n{result.stdout}"
    assert str(foreign) in result.stderr, result.stderr
    after = snapshot(foreign)
    assert sorted(after) == sorted(before), f"{name} added or removed files"
    changed = [path for path in before if after[path] != before[path]]
    assert not changed, f"{name} changed {changed}"


@pytest.mark.parametrize("name", [*BOXPOSE_COMMANDS, "make scenes"])
def test_a_writing_command_refuses_a_folder_holding_a_search_run(
    name, boxpose_bin, dataset, search_run, tmp_path
):
    run = tmp_path / "other-run"
    shutil.copytree(search_run, run)
    before = snapshot(run)
    # eval-geometry writes one file: aimed at the run's own run.json
    args = [
        a.replace("manifest.json", "run.json")
        for a in command_line(name, boxpose_bin, dataset, run, tmp_path)
    ]
    result = subprocess.run(args, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode != 0, f"{name} wrote into a search run:\n{result.stdout}"
    assert str(run) in result.stderr, result.stderr
    assert snapshot(run) == before, f"{name} changed the run's files"


# The commands that write into a folder of their own: while one runs, the folder is locked.
LOCKING_COMMANDS = [
    "render",
    "search variants",
    "search replay",
    "eval",
    "eval-results bop",
    "predict",
    "train",
    "train-segmenter",
]


@pytest.mark.parametrize("name", LOCKING_COMMANDS)
def test_a_writing_command_refuses_a_folder_another_process_is_writing(
    name, boxpose_bin, dataset, tmp_path
):
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "partial.txt").write_text("written by the other process")
    before = snapshot(busy)
    holder = os.open(busy, os.O_RDONLY)
    try:
        fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what a running boxpose holds
        result = run_command(name, boxpose_bin, dataset, busy, tmp_path)
    finally:
        os.close(holder)
    assert result.returncode != 0, f"{name} wrote into a folder in use:\n{result.stdout}"
    assert "another boxpose command is writing into it" in result.stderr, result.stderr
    assert str(busy) in result.stderr
    assert snapshot(busy) == before


def test_a_command_that_fails_on_its_input_leaves_no_folder_behind(boxpose_bin, dataset, tmp_path):
    out = tmp_path / "new" / "eval"
    result = subprocess.run(
        [boxpose_bin, "eval", dataset, "--model", tmp_path / "no-model", "--out", out],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert result.returncode != 0
    assert "no-model" in result.stderr, result.stderr
    assert not out.exists(), "the failed command left its --out behind"
