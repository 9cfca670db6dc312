"""The benchmark scene shared by scripts/bench_render.py and the Rust crop bench: the clutter
recipe (640×480 camera, bin) over `boxes` synthetic boxes, one of them stacked."""

from __future__ import annotations

from pathlib import Path

from blender_scripts.synthetic import synthetic_scene

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "recipes" / "clutter.toml"


def bench_scene(boxes: int = 12, seed: int = 2024) -> tuple[dict, list[dict]]:
    return synthetic_scene(0, RECIPE.read_text(), boxes, seed=seed, stack=True, spread_m=0.24)
