"""drake_scenes: real Drake on the tiny recipe. One module-scoped generation (two independent
runs, for determinism) feeds most tests; each other test generates at most a scene or two."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import boxpose_io
from blender_scripts.recipe import parse_render_recipe
from boxpose_io.recipe import BLENDER_KEYS, BLENDER_SECTIONS, DRAKE_SECTIONS, read as recipe_values
from boxpose_io.recipe_keys import RECIPE_KEYS
from boxpose_io.schema import RECIPE_REFERENCE
from drake_scenes.generate import check_feasible, run_shard
from drake_scenes.plant import BoxBody, build_scene_plant, min_signed_distance
from drake_scenes.projection import project
from drake_scenes.recipe import Recipe, RecipeError
from drake_scenes.sampling import sample_scene
from drake_scenes.settle import settle

REPO = Path(__file__).resolve().parent.parent
RECIPES = REPO / "datasets" / "recipes"
TINY = RECIPES / "tiny.toml"
TABLES = ("scenes", "objects")


def run_cli(*args, module="drake_scenes") -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )


def read(dataset: Path, table: str, shard: int = 0, num_shards: int = 1):
    return pq.read_table(boxpose_io.shard_path(dataset, table, shard, num_shards))


def tiny_variant(tmp_path: Path, name: str, **replacements) -> Path:
    """The tiny recipe with some lines replaced, e.g. count="count = [40, 40]"."""
    text = TINY.read_text()
    for key, line in replacements.items():
        old = next(t for t in text.splitlines() if t.split("=")[0].strip() == key)
        text = text.replace(old, line)
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace('name = "tiny"', f'name = "{name}"'))
    return path


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    """The tiny recipe generated twice, by two processes, into two folders."""
    runs = []
    for label in ("a", "b"):
        out = tmp_path_factory.mktemp(f"tiny_{label}")
        result = run_cli("--recipe", TINY, "--out", out, "--no-progress")
        assert result.returncode == 0, result.stderr
        runs.append((out, result.stdout))
    return runs


@pytest.fixture(scope="module")
def tiny(tiny_runs):
    out, _ = tiny_runs[0]
    return {t: read(out, t).to_pandas() for t in TABLES}


@pytest.fixture(scope="module")
def recipe():
    return Recipe.load(TINY)


def box_bodies(objects: pd.DataFrame, pose: str) -> list[BoxBody]:
    prefix = "initial_world_box" if pose == "initial" else "world_box"
    return [
        BoxBody(
            np.asarray(o.size_m),
            o.mass_kg,
            o.friction,
            np.asarray(o[f"{prefix}_quat_wxyz"]),
            np.asarray(o[f"{prefix}_translation_m"]),
        )
        for _, o in objects.sort_values("object_id").iterrows()
    ]


def signed_distance_of(boxes: list[BoxBody], recipe: Recipe) -> float:
    """Recomputed from scratch: a fresh plant posed from the given boxes."""
    scene = build_scene_plant(boxes, recipe.support)
    return min_signed_distance(scene, scene.new_context(boxes))


def test_cli_reports_what_it_wrote(tiny_runs, tiny, recipe):
    out, stdout = tiny_runs[0]
    assert f"{recipe.num_scenes} scenes, {len(tiny['scenes'])} accepted" in stdout
    for reason in (
        "solver failure",
        "not settled in time",
        "penetration",
        "box left the support region",
    ):
        assert f"{reason}: " in stdout
    for table in TABLES:
        assert str(boxpose_io.shard_path(out, table, 0, 1)) in stdout
    # The tiny recipe is easy: losing a scene there means something is off.
    assert len(tiny["scenes"]) == recipe.num_scenes


def same_schema(read_back: pa.Schema, contract: pa.Schema) -> bool:
    """Equal up to the name of a list's child field: Parquet stores lists with the child
    `element`, and pyarrow reads that name back instead of the contract's `item`."""

    def plain(t: pa.DataType):
        return ("list", plain(t.value_type), t.list_size) if pa.types.is_fixed_size_list(t) else t

    def fields(s: pa.Schema):
        return [(f.name, plain(f.type), f.nullable) for f in s]

    return fields(read_back) == fields(contract) and read_back.metadata == contract.metadata


def test_shards_match_the_contract_and_read_with_plain_pandas(tiny_runs):
    out, _ = tiny_runs[0]
    for table in TABLES:
        path = boxpose_io.shard_path(out, table, 0, 1)
        assert same_schema(pq.read_schema(path), boxpose_io.arrow_schema(table))
        frame = pd.read_parquet(path.parent)  # the folder, as a dataset user would
        assert list(frame.columns) == boxpose_io.column_names(table)
        assert len(frame) > 0
        assert not list(path.parent.glob("*.tmp"))


def test_rows_are_consistent(tiny, recipe):
    scenes, objects = tiny["scenes"], tiny["objects"]
    assert scenes.scene_id.is_unique
    for row in scenes.itertuples():
        mine = objects[objects.scene_id == row.scene_id]
        assert sorted(mine.object_id) == list(range(row.num_objects))
        assert recipe.boxes.count[0] <= row.num_objects <= recipe.boxes.count[1]
        assert row.recipe == "tiny" and row.recipe_toml == TINY.read_text()
        assert row.physics_backend == "drake" and row.support == recipe.support.kind
        assert set(json.loads(row.tool_versions)) >= {"drake", "python", "numpy"}
    for column in ("world_box_quat_wxyz", "initial_world_box_quat_wxyz"):
        norms = np.linalg.norm(np.stack(objects[column]), axis=1)
        np.testing.assert_allclose(norms, 1.0, atol=1e-9)
    sizes = np.stack(objects.size_m)
    assert np.all(sizes >= recipe.boxes.size_min_m) and np.all(sizes <= recipe.boxes.size_max_m)
    density = objects.mass_kg / sizes.prod(axis=1)
    assert density.between(*recipe.boxes.density_kg_m3).all()
    assert objects.friction.between(*recipe.boxes.friction).all()
    assert objects.roughness.between(*recipe.materials.roughness).all()
    assert np.all((np.stack(objects.base_color_rgb) >= 0) & (np.stack(objects.base_color_rgb) <= 1))


def test_projected_drop_poses_do_not_interpenetrate(tiny, recipe):
    for scene_id, objects in tiny["objects"].groupby("scene_id"):
        distance = signed_distance_of(box_bodies(objects, "initial"), recipe)
        assert distance >= recipe.drop.min_separation_m - 1e-4, f"scene {scene_id}: {distance}"


def test_projection_separates_overlapping_boxes(recipe):
    """Three boxes sampled, then stacked into one another on purpose."""
    boxes = sample_scene(recipe, 0, num_boxes=3).boxes
    for box in boxes:
        box.translation_m = np.array([0.0, 0.0, 0.08])
    assert signed_distance_of(boxes, recipe) < -0.01  # really overlapping before
    result = project(boxes, recipe, np.random.default_rng(0))
    assert result.success, result.status
    assert (
        result.solver in ("SNOPT", "IPOPT")
        and 1 <= result.attempts <= recipe.drop.max_solve_attempts
    )
    assert signed_distance_of(result.boxes, recipe) >= recipe.drop.min_separation_m - 1e-4
    hx, hy = recipe.support.half_extent_m
    for box in result.boxes:
        assert (
            abs(box.translation_m[0]) <= hx
            and abs(box.translation_m[1]) <= hy
            and box.translation_m[2] > 0
        )


def test_every_written_scene_is_certified_within_the_recipe(tiny, recipe):
    s = recipe.settle
    for row in tiny["scenes"].itertuples():
        assert row.stable
        assert row.max_linear_speed_mps <= s.max_linear_speed_mps
        assert row.max_angular_speed_radps <= s.max_angular_speed_radps
        assert row.min_signed_distance_m >= -s.max_penetration_m
        assert s.window_s <= row.settle_time_s <= s.max_time_s
        assert (
            row.solver in ("SNOPT", "IPOPT")
            and 1 <= row.solve_attempts <= recipe.drop.max_solve_attempts
        )
        objects = tiny["objects"][tiny["objects"].scene_id == row.scene_id]
        settled = box_bodies(objects, "settled")
        # The recorded distance is what the settled poses give, recomputed independently.
        assert signed_distance_of(settled, recipe) == pytest.approx(
            row.min_signed_distance_m, abs=1e-6
        )
        hx, hy = recipe.support.half_extent_m
        for box in settled:
            x, y, z = box.translation_m
            assert abs(x) <= hx and abs(y) <= hy
            # Resting: the centre is no higher than the box could stand, and above the floor.
            assert 0 < z <= 0.5 * np.linalg.norm(box.size_m) * len(settled)


def test_runs_are_deterministic(tiny_runs):
    (a, _), (b, _) = tiny_runs
    for table in TABLES:
        # Bitwise: SNOPT and Drake's simulation are deterministic for the same inputs.
        assert read(a, table).equals(read(b, table)), f"{table} differs between two identical runs"


def test_rows_do_not_depend_on_the_shard_count(tiny, tmp_path):
    result = run_cli(
        "--recipe", TINY, "--out", tmp_path, "--shard", 1, "--num-shards", 2, "--no-progress"
    )
    assert result.returncode == 0, result.stderr
    scenes = read(tmp_path, "scenes", 1, 2).to_pandas()
    assert list(scenes.scene_id) == [1]
    expected = tiny["scenes"][tiny["scenes"].scene_id == 1].reset_index(drop=True)
    pd.testing.assert_frame_equal(scenes, expected)
    objects = read(tmp_path, "objects", 1, 2).to_pandas()
    expected = tiny["objects"][tiny["objects"].scene_id == 1].reset_index(drop=True)
    pd.testing.assert_frame_equal(objects, expected)


def test_existing_shards_are_skipped(tiny_runs):
    out, _ = tiny_runs[0]
    paths = [boxpose_io.shard_path(out, t, 0, 1) for t in TABLES]
    before = [p.stat().st_mtime_ns for p in paths]
    result = run_cli("--recipe", TINY, "--out", out, "--no-progress")
    assert result.returncode == 0 and "already complete, skipped" in result.stdout
    assert [p.stat().st_mtime_ns for p in paths] == before


def test_too_many_boxes_for_the_support_fails_up_front(tmp_path):
    # 40 boxes of at least 10 × 10 cm footprint: 0.4 m² on a 0.5 × 0.5 m floor.
    recipe = tiny_variant(
        tmp_path, "crowded", count="count = [40, 40]", size_min_m="size_min_m = [0.1, 0.1, 0.1]"
    )
    out = tmp_path / "out"
    result = run_cli("--recipe", recipe, "--out", out, "--no-progress")
    assert result.returncode == 2
    assert (
        "recipe 'crowded'" in result.stderr
        and "covers more than the support region" in result.stderr
    )
    assert "Traceback" not in result.stderr
    assert not list(out.rglob("*.parquet")) and not list(out.rglob("*.tmp"))


def test_recipe_whose_solve_always_fails_is_reported_without_a_shard(tmp_path):
    """Passes the up-front checks, but no box can be 0.5 m from the floor while its lowest
    point stays within drop.height_m (at most 0.15 m) of it: every solve fails."""
    recipe = tiny_variant(
        tmp_path,
        "unreachable",
        min_separation_m="min_separation_m = 0.5",
        count="count = [1, 1]",
        max_solve_attempts="max_solve_attempts = 1",
    )
    out = tmp_path / "out"
    result = run_cli("--recipe", recipe, "--out", out, "--no-progress")
    assert result.returncode == 2, result.stdout + result.stderr
    assert (
        "recipe 'unreachable'" in result.stderr and "non-penetration solve failed" in result.stderr
    )
    assert "Traceback" not in result.stderr
    assert not list(out.rglob("*.parquet"))


def test_bad_recipe_key_names_the_key(tmp_path):
    recipe = tiny_variant(tmp_path, "typo", kind='kind = "trampoline"')
    result = run_cli("--recipe", recipe, "--out", tmp_path / "out")
    assert result.returncode == 2
    accepted = 'must be "floor" or "bin" or "pallet", got "trampoline"'
    assert f"key 'support.kind' {accepted}" in result.stderr


def test_a_misspelt_recipe_key_is_refused_by_both_readers(tmp_path):
    recipe = tiny_variant(tmp_path, "misspelt", window_s="window_s = 0.2\nwindow_seconds = 0.2")
    with pytest.raises(RecipeError, match="unknown key 'settle.window_seconds'"):
        Recipe.load(recipe)
    with pytest.raises(RecipeError, match="unknown key 'settle.window_seconds'"):
        parse_render_recipe(recipe.read_text(), str(recipe))


def test_the_recipe_readers_read_exactly_the_recipe_keys():
    """RECIPE_KEYS is the one list of keys: the reference documents exactly those, every one of
    them is read by one of the two stages, and so is every key a shipped recipe writes."""
    import tomllib

    assert set(RECIPE_REFERENCE) == RECIPE_KEYS
    documented = {key for key in RECIPE_KEYS if key != "description"}  # which no stage reads
    read_by_a_stage = set()
    for path in sorted(RECIPES.glob("*.toml")):
        text = path.read_text()
        drake = recipe_values(text, str(path), DRAKE_SECTIONS)
        blender = recipe_values(text, str(path), BLENDER_SECTIONS, BLENDER_KEYS)
        data = tomllib.loads(text)
        written = {f"{s}.{k}" for s, t in data.items() if isinstance(t, dict) for k in t}
        written |= {k for k, v in data.items() if not isinstance(v, dict)} - {"description"}
        read_by_a_stage |= drake.keys() | blender.keys()
        assert written <= drake.keys() | blender.keys(), f"{path.name}: not read: {written}"
    # camera.look_at_object is left out when absent ("not used"), and no shipped recipe sets it
    assert documented - read_by_a_stage <= {"camera.look_at_object"}


@pytest.mark.parametrize(
    "key, line",
    [("max_time_s", "max_time_s = inf"), ("height_m", "height_m = [0.05, nan]")],
)
def test_non_finite_recipe_values_are_refused_up_front(tmp_path, key, line):
    """An infinite settle.max_time_s simulated forever; a NaN range passed every comparison."""
    recipe = tiny_variant(tmp_path, "nonfinite", **{key: line})
    result = run_cli("--recipe", recipe, "--out", tmp_path / "out")
    assert result.returncode == 2 and "must be finite" in result.stderr and key in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("recipe_file", sorted(RECIPES.glob("*.toml")), ids=lambda p: p.stem)
def test_checked_in_recipes_load(recipe_file):
    recipe = Recipe.load(recipe_file)
    check_feasible(recipe)
    assert recipe.name == recipe_file.stem


def test_bin_support_keeps_boxes_inside(tmp_path):
    recipe = Recipe.load(
        tiny_variant(tmp_path, "tiny_bin", kind='kind = "bin"', wall_height_m="wall_height_m = 0.1")
    )
    summary = run_shard(recipe, tmp_path / "out", num_scenes=1, progress=False)
    assert summary.accepted == 1, summary.report()
    objects = read(tmp_path / "out", "objects").to_pandas()
    xy = np.stack(objects.world_box_translation_m)[:, :2]
    assert np.all(np.abs(xy) < recipe.support.half_extent_m)


def test_bench_settle_writes_initial_states_that_settle_reproduces(tmp_path):
    result = run_cli(
        "--recipe",
        TINY,
        "--boxes",
        2,
        "--scenes",
        1,
        "--out",
        tmp_path,
        module="drake_scenes.bench_settle",
    )
    assert result.returncode == 0, result.stderr
    line = json.loads(result.stdout.strip().splitlines()[-1])
    assert line["boxes"] == 2 and line["scene"] == 0 and line["drake_settle_s"] > 0
    objects = read(tmp_path, "objects").to_pandas()
    scenes = read(tmp_path, "scenes").to_pandas()
    assert len(objects) == 2 and bool(scenes.stable[0]) == line["stable"]
    # The public settle() from the objects rows gives the same settled poses as the bench did.
    rows = [row for _, row in objects.sort_values("object_id").iterrows()]
    again = settle(rows, TINY)
    for (quat, translation), row in zip(again.poses, rows, strict=True):
        np.testing.assert_allclose(quat, row.world_box_quat_wxyz, atol=1e-12)
        np.testing.assert_allclose(translation, row.world_box_translation_m, atol=1e-12)
    assert again.certificate.stable == line["stable"] and again.wall_time_s > 0


def test_recipe_errors_name_the_recipe():
    with pytest.raises(RecipeError, match="missing key 'settle.window_s'"):
        Recipe.from_toml(TINY.read_text().replace("window_s = 0.2", ""), source="x.toml")


def test_the_wide_training_recipe_settles_large_boxes_on_its_floor(tmp_path):
    """train_wide (the learning issue's wider world) at three scenes: boxes of up to 50 cm settle
    on the floor inside the recipe's ranges (its own seed, so the first scenes are always these)."""
    recipe = Recipe.load(RECIPES / "train_wide.toml")
    summary = run_shard(recipe, tmp_path / "out", num_scenes=3, progress=False)
    assert summary.accepted >= 1, summary.report()
    objects = read(tmp_path / "out", "objects").to_pandas()
    sizes = np.stack(objects.size_m)
    assert (sizes >= np.asarray(recipe.boxes.size_min_m) - 1e-9).all()
    assert (sizes <= np.asarray(recipe.boxes.size_max_m) + 1e-9).all()
    per_scene = objects.groupby("scene_id").size()
    assert per_scene.between(*recipe.boxes.count).all()
    assert sizes.max() > 0.2, "no box larger than the training recipes' before train_wide"
    z = np.stack(objects.world_box_translation_m)[:, 2]
    assert (z > 0).all() and (z < sizes.max(axis=1)).all()  # resting on the floor, not stacked high


def test_the_mujoco_engine_settles_the_same_drops_under_the_same_rules(tmp_path, tiny, recipe):
    """`[settle] engine = "mujoco"`: the same sampled and projected drops as Drake's (only the
    simulator differs), settled by `boxpose settle-drops`, certified under the recipe's rules and
    recorded as such in `scenes.physics_backend` and `tool_versions`."""
    path = tiny_variant(tmp_path, "tiny", time_step_s='engine = "mujoco"\ntime_step_s = 0.001')
    mujoco = Recipe.load(path)
    assert mujoco.settle.engine == "mujoco" and recipe.settle.engine == "drake"
    result = run_cli("--recipe", path, "--out", tmp_path / "out", "--no-progress")
    assert result.returncode == 0, result.stderr
    scenes, objects = (read(tmp_path / "out", t).to_pandas() for t in TABLES)
    assert list(scenes.scene_id) == list(tiny["scenes"].scene_id)
    assert (scenes.physics_backend == "mujoco").all() and (
        tiny["scenes"].physics_backend == "drake"
    ).all()
    assert all("mujoco" in json.loads(v) for v in scenes.tool_versions)
    assert scenes.stable.all()
    s = mujoco.settle
    assert (scenes.settle_time_s <= s.max_time_s).all()
    assert (scenes.max_linear_speed_mps <= s.max_linear_speed_mps).all()
    assert (scenes.max_angular_speed_radps <= s.max_angular_speed_radps).all()
    assert (scenes.min_signed_distance_m >= -s.max_penetration_m).all()
    for column in ("size_m", "initial_world_box_quat_wxyz", "initial_world_box_translation_m"):
        np.testing.assert_array_equal(np.stack(objects[column]), np.stack(tiny["objects"][column]))
    # settled: every box fell from its drop height onto the floor (its centre below the start)
    z0 = np.stack(objects.initial_world_box_translation_m)[:, 2]
    z = np.stack(objects.world_box_translation_m)[:, 2]
    assert (z < z0).all() and (z > 0).all()
    # Drake's independent check of the settled poses: nothing interpenetrates beyond the recipe
    for scene_id, rows in objects.groupby("scene_id"):
        distance = signed_distance_of(box_bodies(rows, "settled"), recipe)
        assert distance >= -s.max_penetration_m, (scene_id, distance)


@pytest.mark.parametrize("value", ['"MuJoCo"', '"bullet"', "1", '["drake"]'])
def test_an_unknown_settle_engine_is_refused_by_every_reader(tmp_path, boxpose_bin, value):
    path = tiny_variant(tmp_path, "tiny", time_step_s=f"engine = {value}\ntime_step_s = 0.001")
    with pytest.raises(RecipeError, match=r"settle\.engine.*\"drake\" or \"mujoco\""):
        Recipe.load(path)
    # MuJoCo's reader (rust/physics) says the same when it is handed the recipe
    line = json.dumps({"recipe_toml": path.read_text(), "boxes": []})
    r = subprocess.run(
        [boxpose_bin, "settle-drops"], input=line + "\n", capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    answer = json.loads(r.stdout)
    assert "settle.engine" in answer["error"] and '"drake" or "mujoco"' in answer["error"]


def test_settle_drops_answers_every_line_and_names_what_is_wrong(boxpose_bin, tiny):
    """A bad line gets an error line naming the line and the field; the next drop is still
    settled: a box dropped 5 cm above the floor comes to rest on it."""
    good = {
        "recipe_toml": TINY.read_text(),
        "boxes": [
            {
                "size_m": [0.1, 0.08, 0.06],
                "mass_kg": 0.5,
                "friction": 0.7,
                "quat_wxyz": [1.0, 0.0, 0.0, 0.0],
                "translation_m": [0.0, 0.0, 0.08],
            }
        ],
    }
    bad = {**good, "boxes": [{**good["boxes"][0], "size_m": [0.1, 0.08]}]}
    lines = ["not json", json.dumps(bad), json.dumps(good)]
    r = subprocess.run(
        [boxpose_bin, "settle-drops"], input="\n".join(lines) + "\n", capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    answers = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(answers) == 3
    assert answers[0]["error"].startswith("line 1: not a JSON object")
    assert answers[1]["error"].startswith("line 2: boxes[0]") and "size_m" in answers[1]["error"]
    settled = answers[2]
    assert settled["stable"] and settled["rejection"] is None
    z = settled["poses"][0]["translation_m"][2]
    assert abs(z - 0.03) < 2e-3, z  # resting on its 6 cm face


def test_the_pallet_training_recipe_settles_its_boxes_on_the_deck_with_mujoco(tmp_path):
    """train_pallet (the segmenter's pallets, settled by MuJoCo) at three scenes: every box
    rests on the EUR pallet's deck, inside the deck and the recipe's ranges."""
    recipe = Recipe.load(RECIPES / "train_pallet.toml")
    assert recipe.settle.engine == "mujoco" and recipe.support.kind == "pallet"
    summary = run_shard(recipe, tmp_path / "out", num_scenes=3, progress=False)
    assert summary.accepted >= 2, summary.report()
    scenes, objects = (read(tmp_path / "out", t).to_pandas() for t in TABLES)
    assert (scenes.physics_backend == "mujoco").all() and (scenes.support == "pallet").all()
    sizes = np.stack(objects.size_m)
    assert (sizes >= np.asarray(recipe.boxes.size_min_m) - 1e-9).all()
    assert (sizes <= np.asarray(recipe.boxes.size_max_m) + 1e-9).all()
    centres = np.stack(objects.world_box_translation_m)
    hx, hy = recipe.support.half_extent_m
    assert (np.abs(centres[:, 0]) <= hx).all() and (np.abs(centres[:, 1]) <= hy).all()
    deck = boxpose_io.schema.PALLET_HEIGHT_M
    assert (centres[:, 2] > deck).all() and (centres[:, 2] < deck + sizes.max(axis=1)).all()


def test_the_dense_bin_training_recipe_settles_its_piles_inside_the_bin_with_mujoco(tmp_path):
    """train_bins (the segmenter's dense bins, settled by MuJoCo) at two scenes: 3–20 boxes per
    scene, every box inside the bin's walls and on or above its floor."""
    recipe = Recipe.load(RECIPES / "train_bins.toml")
    assert recipe.settle.engine == "mujoco" and recipe.support.kind == "bin"
    summary = run_shard(recipe, tmp_path / "out", num_scenes=2, progress=False)
    assert summary.accepted >= 1, summary.report()
    scenes, objects = (read(tmp_path / "out", t).to_pandas() for t in TABLES)
    assert (scenes.physics_backend == "mujoco").all() and scenes.stable.all()
    assert objects.groupby("scene_id").size().between(*recipe.boxes.count).all()
    centres = np.stack(objects.world_box_translation_m)
    hx, hy = recipe.support.half_extent_m
    assert (np.abs(centres[:, 0]) < hx).all() and (np.abs(centres[:, 1]) < hy).all()
    assert (centres[:, 2] > 0).all()
