"""The scene stage's MuJoCo engine (`[settle] engine = "mujoco"`): the drop that sampling and
projection made is settled by `boxpose settle-drops` (rust/physics, the search's simulator) under
the Drake stage's stop rule and checks, and comes back as the same `SettleResult`.

One `boxpose settle-drops` process serves a whole shard: a drop goes to it as one JSON line and
its answer is read back before the next one is sent.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from boxpose_io import binary
from drake_scenes.plant import BoxBody
from drake_scenes.recipe import Recipe, RecipeError
from drake_scenes.settle import Certificate, SettleResult


def find_boxpose(boxpose: Path | None) -> Path:
    """The `boxpose` binary (`boxpose_io.binary.find_boxpose`); a RecipeError (the recipe asks for
    MuJoCo) that says how to get one otherwise."""
    try:
        return binary.find_boxpose(boxpose)
    except FileNotFoundError as e:
        raise RecipeError(f'settle.engine = "mujoco" needs the boxpose binary: {e}') from None


class MujocoSettler:
    """A `boxpose settle-drops` process; use as a context manager, then `settle` like
    `drake_scenes.settle.settle`."""

    def __init__(self, boxpose: Path | None = None):
        self.binary = find_boxpose(boxpose)
        self.process: subprocess.Popen | None = None

    def __enter__(self) -> MujocoSettler:
        self.process = subprocess.Popen(
            [str(self.binary), "settle-drops"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        return self

    def __exit__(self, *exc) -> None:
        if self.process is not None:
            # end of input ends the process; one that already died has nothing left to read
            with contextlib.suppress(BrokenPipeError):
                self.process.stdin.close()
            self.process.wait(timeout=30)
            self.process.stdout.close()
            self.process = None

    def settle(self, boxes: list[BoxBody], recipe: Recipe) -> SettleResult:
        """Drops `boxes` from their (projected) poses on `recipe`'s support."""
        if self.process is None:
            raise RuntimeError("MujocoSettler.settle outside its `with` block")
        drop = {
            "recipe_toml": recipe.toml_text,
            "boxes": [
                {
                    "size_m": [float(v) for v in box.size_m],
                    "mass_kg": float(box.mass_kg),
                    "friction": float(box.friction),
                    "quat_wxyz": [float(v) for v in box.quat_wxyz],
                    "translation_m": [float(v) for v in box.translation_m],
                }
                for box in boxes
            ],
        }
        start = time.perf_counter()
        self.process.stdin.write(json.dumps(drop) + "\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            code = self.process.wait(timeout=30)
            raise RuntimeError(f"{self.binary} settle-drops exited (status {code}) mid-shard")
        answer = json.loads(line)
        if "error" in answer:
            raise recipe.error(f"MuJoCo could not settle a drop: {answer['error']}")
        return SettleResult(
            poses=[
                (np.asarray(p["quat_wxyz"], float), np.asarray(p["translation_m"], float))
                for p in answer["poses"]
            ],
            certificate=Certificate(
                settle_time_s=answer["settle_time_s"],
                max_linear_speed_mps=answer["max_linear_speed_mps"],
                max_angular_speed_radps=answer["max_angular_speed_radps"],
                min_signed_distance_m=answer["min_signed_distance_m"],
                stable=answer["stable"],
                rejection=answer["rejection"],
            ),
            # the whole exchange: what the scene stage spends on it
            wall_time_s=time.perf_counter() - start,
            simulated_steps=answer["steps"],
        )
