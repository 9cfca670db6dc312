"""One scene from sample to contract rows, and one shard of scenes from a recipe.

A scene is: sampled (sampling.py) → projected to non-penetration (projection.py) → dropped and
settled (settle.py, or MuJoCo through mujoco.py when the recipe's `settle.engine` says so) →
certified. Only certified scenes become rows; every other scene is counted under its rejection
reason.
"""

from __future__ import annotations

import contextlib
import json
import platform
import time
from collections import Counter
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path

import numpy as np
from tqdm import tqdm

import boxpose_io
from drake_scenes.mujoco import MujocoSettler
from drake_scenes.projection import SOLVER_FAILURE, project
from drake_scenes.recipe import Recipe
from drake_scenes.sampling import SceneSample, bounding_radius, sample_scene
from drake_scenes.settle import LEFT_SUPPORT, NOT_SETTLED, PENETRATION, SettleResult, settle

REJECTION_REASONS = (SOLVER_FAILURE, NOT_SETTLED, PENETRATION, LEFT_SUPPORT)
# After this many consecutive scenes whose projection failed every attempt (or every scene of
# the shard, if fewer), the recipe is declared impossible rather than silently producing nothing.
MAX_CONSECUTIVE_SOLVER_FAILURES = 10


def tool_versions(engine: str = "drake") -> str:
    versions = {
        "drake": version("drake"),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    if engine == "mujoco":
        # the library boxpose-physics links: the pinned wheel's (docs/design.md)
        versions["mujoco"] = version("mujoco")
    return json.dumps(versions, sort_keys=True)


@dataclass
class SceneOutcome:
    sample: SceneSample
    rejection: str | None  # None: accepted
    scene_row: dict | None = None
    object_rows: list[dict] = field(default_factory=list)
    solver_status: str = ""
    projection_s: float = 0.0
    settle_s: float = 0.0


def check_feasible(recipe: Recipe) -> None:
    """Rejects, before any solve, recipes whose boxes cannot fit the support region."""
    b, (hx, hy) = recipe.boxes, recipe.support.half_extent_m
    reach = bounding_radius(b.size_max_m)
    if reach > min(hx, hy):
        raise recipe.error(
            f"the largest box {list(b.size_max_m)} m reaches {reach:.3f} m from its centre in "
            f"some orientation, more than the support region's half extent {min(hx, hy)} m: "
            "it cannot be dropped inside the region"
        )
    smallest_face = min(
        b.size_min_m[0] * b.size_min_m[1],
        b.size_min_m[0] * b.size_min_m[2],
        b.size_min_m[1] * b.size_min_m[2],
    )
    footprint, area = b.count[0] * smallest_face, 4 * hx * hy
    if footprint > area:
        raise recipe.error(
            f"even the smallest scene ({b.count[0]} boxes of at least {smallest_face:.4f} m² "
            "footprint each, "
            f"{footprint:.3f} m² in all) covers more than the support region ({area:.3f} m²)"
        )


def generate_scene(
    recipe: Recipe,
    scene_id: int,
    tool_versions_json: str,
    num_boxes: int | None = None,
    mujoco: MujocoSettler | None = None,
) -> SceneOutcome:
    """Samples, projects, drops and settles scene `scene_id`: with Drake, or with `mujoco` (an
    open `MujocoSettler`) when the recipe's `settle.engine` is "mujoco"."""
    sample = sample_scene(recipe, scene_id, num_boxes)
    # The jitter of retried solves has its own stream, derived from the scene seed only.
    jitter_rng = np.random.default_rng(np.random.SeedSequence([sample.seed, 1]))
    start = time.perf_counter()
    projection = project(sample.boxes, recipe, jitter_rng)
    outcome = SceneOutcome(
        sample, None, solver_status=projection.status, projection_s=time.perf_counter() - start
    )
    if not projection.success:
        outcome.rejection = SOLVER_FAILURE
        return outcome

    if recipe.settle.engine == "mujoco":
        if mujoco is None:
            raise RuntimeError('a recipe with settle.engine = "mujoco" needs a MujocoSettler')
        settled: SettleResult = mujoco.settle(projection.boxes, recipe)
    else:
        settled = settle(projection.boxes, recipe)
    outcome.settle_s = settled.wall_time_s
    cert = settled.certificate
    outcome.rejection = cert.rejection
    outcome.scene_row = {
        "scene_id": scene_id,
        "seed": sample.seed,
        "recipe": recipe.name,
        "recipe_toml": recipe.toml_text,
        "tool_versions": tool_versions_json,
        "physics_backend": recipe.settle.engine,
        "support": recipe.support.kind,
        "num_objects": len(sample.boxes),
        "solver": projection.solver,
        "solver_status": projection.status,
        "solve_attempts": projection.attempts,
        "settle_time_s": cert.settle_time_s,
        "max_linear_speed_mps": cert.max_linear_speed_mps,
        "max_angular_speed_radps": cert.max_angular_speed_radps,
        "min_signed_distance_m": cert.min_signed_distance_m,
        "stable": cert.stable,
    }
    for object_id, (box, initial, (quat, translation), material) in enumerate(
        zip(sample.boxes, projection.boxes, settled.poses, sample.materials, strict=True)
    ):
        outcome.object_rows.append(
            {
                "scene_id": scene_id,
                "object_id": object_id,
                "size_m": [float(v) for v in box.size_m],
                "world_box_quat_wxyz": [float(v) for v in quat],
                "world_box_translation_m": [float(v) for v in translation],
                "initial_world_box_quat_wxyz": [float(v) for v in initial.quat_wxyz],
                "initial_world_box_translation_m": [float(v) for v in initial.translation_m],
                "mass_kg": box.mass_kg,
                "friction": box.friction,
                "base_color_rgb": [float(v) for v in material.base_color_rgb],
                "roughness": material.roughness,
                "texture_seed": material.texture_seed,
                "has_tape": material.has_tape,
                "has_label": material.has_label,
            }
        )
    return outcome


@dataclass
class ShardSummary:
    recipe: str
    shard: int
    num_shards: int
    scene_ids: list[int]
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    paths: dict[str, Path] = field(default_factory=dict)
    rows: dict[str, int] = field(default_factory=dict)
    projection_s: float = 0.0
    settle_s: float = 0.0
    wall_s: float = 0.0
    skipped: bool = False  # the shard already existed (resume)

    def report(self) -> str:
        where = f"recipe '{self.recipe}', shard {self.shard} of {self.num_shards}"
        if self.skipped:
            paths = ", ".join(str(p) for p in self.paths.values())
            return f"{where}: already complete, skipped ({paths})"
        n = len(self.scene_ids)
        lines = [f"{where}: {n} scenes, {self.accepted} accepted, {n - self.accepted} rejected"]
        lines.append(
            "  rejected by reason: "
            + ", ".join(f"{r}: {self.rejected[r]}" for r in REJECTION_REASONS)
        )
        if n:
            lines.append(
                f"  time: {self.wall_s:.1f} s, {self.wall_s / n:.2f} s/scene "
                f"(projection {self.projection_s / n:.2f} s, "
                f"drop and settle {self.settle_s / n:.2f} s)"
            )
        for table, path in self.paths.items():
            lines.append(f"  {table}: {path} ({self.rows[table]} rows)")
        return "\n".join(lines)


def shard_scene_ids(num_scenes: int, shard: int, num_shards: int) -> list[int]:
    return [i for i in range(num_scenes) if i % num_shards == shard]


def run_shard(
    recipe: Recipe,
    out: Path,
    shard: int = 0,
    num_shards: int = 1,
    num_scenes: int | None = None,
    progress: bool = True,
    boxpose: Path | None = None,
) -> ShardSummary:
    """Generates the scenes of one shard and writes its `scenes` and `objects` shards, both or
    none: a RecipeError (impossible recipe) leaves nothing behind. `boxpose`: the binary that
    settles the drops of a recipe whose `settle.engine` is "mujoco" (default: the repository's
    release build, then PATH)."""
    out = Path(out)
    num_scenes = recipe.num_scenes if num_scenes is None else num_scenes
    summary = ShardSummary(
        recipe.name, shard, num_shards, shard_scene_ids(num_scenes, shard, num_shards)
    )
    paths = {t: boxpose_io.shard_path(out, t, shard, num_shards) for t in ("scenes", "objects")}
    if all(p.exists() for p in paths.values()):
        summary.skipped, summary.paths = True, paths
        return summary

    check_feasible(recipe)
    with contextlib.ExitStack() as stack:
        mujoco = None
        if recipe.settle.engine == "mujoco":
            mujoco = stack.enter_context(MujocoSettler(boxpose))
        scene_rows, object_rows = _generate(recipe, summary, mujoco, progress)

    # Build both tables (validating every row) before writing either.
    tables = {
        "scenes": boxpose_io.table_from_rows("scenes", scene_rows),
        "objects": boxpose_io.table_from_rows("objects", object_rows),
    }
    for table_name, table in tables.items():
        boxpose_io.write_shard(paths[table_name], table)
        summary.rows[table_name] = table.num_rows
    summary.paths = paths
    return summary


def _generate(
    recipe: Recipe, summary: ShardSummary, mujoco: MujocoSettler | None, progress: bool
) -> tuple[list[dict], list[dict]]:
    """The rows of `summary`'s scenes (accepted ones), counting the rest in `summary`."""
    versions = tool_versions(recipe.settle.engine)
    scene_rows, object_rows = [], []
    consecutive_failures = 0
    give_up_after = min(MAX_CONSECUTIVE_SOLVER_FAILURES, len(summary.scene_ids))
    start = time.perf_counter()
    bar = tqdm(
        summary.scene_ids,
        desc=f"{recipe.name} {summary.shard}/{summary.num_shards}",
        unit="scene",
        disable=not progress,
        mininterval=1.0,
        dynamic_ncols=True,
    )
    for scene_id in bar:
        outcome = generate_scene(recipe, scene_id, versions, mujoco=mujoco)
        summary.projection_s += outcome.projection_s
        summary.settle_s += outcome.settle_s
        if outcome.rejection is None:
            summary.accepted += 1
            scene_rows.append(outcome.scene_row)
            object_rows.extend(outcome.object_rows)
        else:
            summary.rejected[outcome.rejection] += 1
        consecutive_failures = (
            consecutive_failures + 1 if outcome.rejection == SOLVER_FAILURE else 0
        )
        if consecutive_failures >= give_up_after:
            raise recipe.error(
                f"the non-penetration solve failed all {recipe.drop.max_solve_attempts} attempts "
                f"for {consecutive_failures} consecutive scenes (last: scene {scene_id}, "
                f"{outcome.solver_status}); the boxes do not fit the drop region: fewer or smaller "
                "boxes, a larger support.half_extent_m or a wider drop.height_m range"
            )
        bar.set_postfix(
            accepted=summary.accepted, rejected=sum(summary.rejected.values()), refresh=False
        )
    bar.close()
    summary.wall_s = time.perf_counter() - start
    return scene_rows, object_rows
