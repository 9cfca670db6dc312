"""Dataset recipes (datasets/recipes/*.toml): the sections the Drake stage reads.

The recipe format is shared with the Blender and MuJoCo stages; `boxpose_io.recipe` reads and
checks it (every key's type, bounds, choices and default, from the one reference in
rust/data/src/recipe.rs), so that a typo or an impossible value fails at start-up, not after an
hour of generation. This module only builds the Drake stage's dataclasses from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from boxpose_io.recipe import (
    DRAKE_SECTIONS,
    MaterialsSpec,
    RecipeError,
    SupportSpec,
    read,
    section,
)

__all__ = ["Recipe", "RecipeError", "SupportSpec", "MaterialsSpec"]


@dataclass(frozen=True)
class BoxesSpec:
    count: tuple[int, int]  # inclusive
    size_min_m: tuple[float, float, float]
    size_max_m: tuple[float, float, float]
    density_kg_m3: tuple[float, float]
    friction: tuple[float, float]


@dataclass(frozen=True)
class DropSpec:
    height_m: tuple[float, float]
    min_separation_m: float
    max_solve_attempts: int


@dataclass(frozen=True)
class SettleSpec:
    time_step_s: float
    max_time_s: float
    window_s: float
    max_linear_speed_mps: float
    max_angular_speed_radps: float
    max_penetration_m: float
    # The simulator of the drop: "drake" (certified) or "mujoco" (`boxpose settle-drops`, for
    # training data); rust/data/src/recipe.rs, SETTLE_ENGINES.
    engine: str


@dataclass(frozen=True)
class Recipe:
    name: str
    seed: int
    num_scenes: int
    boxes: BoxesSpec
    support: SupportSpec
    drop: DropSpec
    settle: SettleSpec
    materials: MaterialsSpec
    toml_text: str  # verbatim, stored in every scenes row so the scene can be regenerated
    source: str  # where it came from, for messages

    @staticmethod
    def load(path: str | Path) -> Recipe:
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as e:
            raise RecipeError(f"recipe {path}: cannot read it ({e.strerror})") from e
        return Recipe.from_toml(text, source=str(path))

    @staticmethod
    def from_toml(text: str, source: str = "<string>") -> Recipe:
        values = read(text, source, DRAKE_SECTIONS)
        return Recipe(
            name=values["name"],
            seed=values["seed"],
            num_scenes=values["num_scenes"],
            boxes=BoxesSpec(**section(values, "boxes")),
            support=SupportSpec(**section(values, "support")),
            drop=DropSpec(**section(values, "drop")),
            settle=SettleSpec(**section(values, "settle")),
            materials=MaterialsSpec(**section(values, "materials")),
            toml_text=text,
            source=source,
        )

    def error(self, problem: str) -> RecipeError:
        return RecipeError(f"recipe '{self.name}' ({self.source}): {problem}")
