"""Shared fixtures of the end-to-end tests: the built `boxpose` binary and the repository root."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

# A single-box search space over a small range of every parameter; {recipe} is its base recipe.
TINY_SEARCH_SPACE = """
name = "test_single_box"
recipe = "{recipe}"

[target]
size_m = {{ x = [0.10, 0.20], y = [0.08, 0.16], z = [0.06, 0.12] }}
orientation = "so3"
x_m = [-0.05, 0.05]
y_m = [-0.05, 0.05]
drop_height_m = [0.02, 0.08]

[camera]
distance_m = [0.45, 0.55]
elevation_deg = [40.0, 65.0]
azimuth_deg = [0.0, 360.0]
hfov_deg = [45.0, 55.0]

[lighting]
sun_elevation_deg = [30.0, 80.0]
sun_azimuth_deg = [0.0, 360.0]
sun_strength = [1.0, 4.0]
world_strength = [0.2, 0.8]
"""


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def boxpose_bin() -> Path:
    """The release binary built by `make setup` (override with BOXPOSE_BIN)."""
    path = Path(os.environ.get("BOXPOSE_BIN", REPO / "target" / "release" / "boxpose"))
    if not path.is_file():
        pytest.fail(f"{path} is missing: run `make setup` (or `cargo build --release`) first")
    return path


def run_boxpose(boxpose_bin: Path, *args, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run([str(boxpose_bin), *map(str, args)], capture_output=True, text=True)
    if check and result.returncode != 0:
        raise AssertionError(f"boxpose {' '.join(map(str, args))} failed:\n{result.stderr}")
    return result


def peak_rss_mb(*command) -> float:
    """Peak resident memory of `command`, measured by a fresh Python process whose only child
    it is (this test process has had other children)."""
    probe = (
        "import resource, subprocess, sys; "
        "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
        "assert r.returncode == 0, r.stderr; "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe, *map(str, command)],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout) / 1024


def tiny_recipe(width: int, height: int, frames: int) -> str:
    """The `tiny` recipe (1 sample, no denoise) at another image size and number of views."""
    text = (REPO / "datasets" / "recipes" / "tiny.toml").read_text()
    return (
        text.replace("width = 64", f"width = {width}")
        .replace("height = 64", f"height = {height}")
        .replace("frames_per_scene = 1", f"frames_per_scene = {frames}")
    )


def render_synthetic_dataset(
    root: Path,
    width: int,
    height: int,
    *,
    shared_size_in_scene_0: bool = False,
    tape_along: str | None = None,
    sensor_depth: bool = False,
) -> Path:
    """Two synthetic scenes (2 boxes spread out, 3 boxes stacked), two views each, rendered by the
    Python worker into the dataset folder `root`. With `shared_size_in_scene_0`, scene 0's two
    boxes get one square-based size (one BOP obj_id with 7 discrete symmetries); `tape_along`
    sets the recipe's materials.tape_along (absent by default, as in the shipped recipes);
    `sensor_depth` renders the simulated sensor's depth channel too."""
    import boxpose_io
    from blender_scripts.synthetic import synthetic_scene

    recipe_toml = tiny_recipe(width, height, 2)
    if tape_along is not None:
        recipe_toml = recipe_toml.replace(
            "[materials]\n", f'[materials]\ntape_along = "{tape_along}"\n'
        )
    if sensor_depth:
        recipe_toml = recipe_toml.replace("sensor_depth = false", "sensor_depth = true")
        assert "sensor_depth = true" in recipe_toml
    rows = [
        synthetic_scene(k, recipe_toml, 2 + k, seed=40 + k, stack=k == 1, spread_m=0.1)
        for k in range(2)
    ]
    if shared_size_in_scene_0:
        boxes = rows[0][1]
        side = min(boxes[0]["size_m"][:2])
        for box in boxes:
            box["size_m"] = [side, side, boxes[0]["size_m"][2]]
    boxpose_io.write_shard(
        boxpose_io.shard_path(root, "scenes", 0, 1),
        boxpose_io.table_from_rows("scenes", [s for s, _ in rows]),
    )
    boxpose_io.write_shard(
        boxpose_io.shard_path(root, "objects", 0, 1),
        boxpose_io.table_from_rows("objects", [o for _, objs in rows for o in objs]),
    )
    cmd = [
        sys.executable,
        "-m",
        "blender_scripts.worker",
        "--dataset",
        str(root),
        "--shard",
        "0",
        "--num-shards",
        "1",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    return root
