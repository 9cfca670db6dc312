"""Dataset recipes (datasets/recipes/*.toml): the subset of keys the Drake stage reads.

The recipe format is shared with the Blender and MuJoCo stages; this module only reads it. Keys
are read strictly (a missing key is an error naming the recipe and the key) so that a typo in a
recipe fails at start-up, not after an hour of generation.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from boxpose_io.recipe_keys import unknown_keys_problem
from boxpose_io.schema import (
    MAX_SETTLE_STEPS,
    SETTLE_ENGINE_DEFAULT,
    SETTLE_ENGINES,
    SUPPORT_KINDS,
    TAPE_ALONG,
    TAPE_ALONG_DEFAULT,
)


class RecipeError(ValueError):
    """A recipe that is malformed or that cannot be generated; the message names the recipe."""


@dataclass(frozen=True)
class BoxesSpec:
    count: tuple[int, int]  # inclusive
    size_min_m: tuple[float, float, float]
    size_max_m: tuple[float, float, float]
    density_kg_m3: tuple[float, float]
    friction: tuple[float, float]


@dataclass(frozen=True)
class SupportSpec:
    kind: str
    half_extent_m: tuple[float, float]
    wall_height_m: float


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
    # The simulator of the drop: "drake" (certified, the default) or "mujoco" (`boxpose
    # settle-drops`, for training data); rust/data/src/recipe.rs, SETTLE_ENGINES.
    engine: str = SETTLE_ENGINE_DEFAULT


@dataclass(frozen=True)
class MaterialsSpec:
    roughness: tuple[float, float]
    tape_probability: float
    label_probability: float
    # Which side of the top face the tape and the label's long axis follow: "long" or "random"
    # (rust/data/src/recipe.rs, TAPE_ALONG). The Blender stage applies it; read here so that both
    # stages accept and refuse the same recipes.
    tape_along: str


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
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise RecipeError(f"recipe {source}: invalid TOML ({e})") from e
        if problem := unknown_keys_problem(data, source):
            raise RecipeError(problem)
        reader = _Reader(data, source)
        recipe = Recipe(
            name=reader.get("name", str),
            seed=reader.get("seed", int),
            num_scenes=reader.get("num_scenes", int),
            boxes=BoxesSpec(
                count=reader.pair("boxes.count", int),
                size_min_m=reader.triple("boxes.size_min_m"),
                size_max_m=reader.triple("boxes.size_max_m"),
                density_kg_m3=reader.pair("boxes.density_kg_m3", float),
                friction=reader.pair("boxes.friction", float),
            ),
            support=read_support(data, source),
            drop=DropSpec(
                height_m=reader.pair("drop.height_m", float),
                min_separation_m=reader.get("drop.min_separation_m", float),
                max_solve_attempts=reader.get("drop.max_solve_attempts", int),
            ),
            settle=SettleSpec(
                time_step_s=reader.get("settle.time_step_s", float),
                max_time_s=reader.get("settle.max_time_s", float),
                window_s=reader.get("settle.window_s", float),
                max_linear_speed_mps=reader.get("settle.max_linear_speed_mps", float),
                max_angular_speed_radps=reader.get("settle.max_angular_speed_radps", float),
                max_penetration_m=reader.get("settle.max_penetration_m", float),
                engine=read_settle_engine(data, source),
            ),
            materials=MaterialsSpec(
                roughness=reader.pair("materials.roughness", float),
                tape_probability=reader.get("materials.tape_probability", float),
                label_probability=reader.get("materials.label_probability", float),
                tape_along=read_tape_along(data, source),
            ),
            toml_text=text,
            source=source,
        )
        recipe._check_ranges()
        return recipe

    def error(self, problem: str) -> RecipeError:
        return RecipeError(f"recipe '{self.name}' ({self.source}): {problem}")

    def _check_ranges(self) -> None:
        b, s, d, st = self.boxes, self.support, self.drop, self.settle
        problems = []
        if self.num_scenes < 0:
            problems.append("num_scenes must be >= 0")
        if not 1 <= b.count[0] <= b.count[1]:
            problems.append(
                f"boxes.count {list(b.count)} must be an inclusive range with 1 <= min <= max"
            )
        if any(not 0 < lo <= hi for lo, hi in zip(b.size_min_m, b.size_max_m, strict=True)):
            problems.append(
                "boxes.size_min_m must be positive and <= boxes.size_max_m on every axis"
            )
        for key, (lo, hi) in (
            ("boxes.density_kg_m3", b.density_kg_m3),
            ("boxes.friction", b.friction),
        ):
            if not 0 < lo <= hi:
                problems.append(f"{key} must be a positive range [min, max]")
        problems += support_problems(s)
        problems += materials_problems(self.materials)
        if (
            not 0 <= d.height_m[0] <= d.height_m[1]
            or d.min_separation_m <= 0
            or d.max_solve_attempts < 1
        ):
            problems.append(
                "drop: need 0 <= height_m min <= max, min_separation_m > 0, max_solve_attempts >= 1"
            )
        if not 0 < st.time_step_s < st.window_s < st.max_time_s:
            problems.append("settle: need 0 < time_step_s < window_s < max_time_s")
        elif st.max_time_s / st.time_step_s > MAX_SETTLE_STEPS:
            problems.append(
                f"settle: max_time_s / time_step_s = {st.max_time_s / st.time_step_s:.3g} steps "
                f"is more than {MAX_SETTLE_STEPS:.0e}"
            )
        if min(st.max_linear_speed_mps, st.max_angular_speed_radps, st.max_penetration_m) <= 0:
            problems.append("settle: speed and penetration thresholds must be positive")
        if problems:
            raise self.error("; ".join(problems))


def read_support(data: dict, source: str) -> SupportSpec:
    """The [support] section of parsed recipe TOML, read strictly; the Blender stage reads it
    with this too. `half_extent_m` is the region's half size along (x, y), not a range. Check
    the values with `support_problems`."""
    reader = _Reader(data, source)
    return SupportSpec(
        kind=reader.get("support.kind", str),
        half_extent_m=reader.pair("support.half_extent_m", float),
        wall_height_m=reader.get("support.wall_height_m", float),
    )


def read_choice(
    data: dict, source: str, key: str, accepted: tuple[str, ...], default: str, hint: str
) -> str:
    """The dotted `key` ("section.name") of parsed recipe TOML: one of `accepted`, `default` when
    absent; otherwise a RecipeError naming the key, the accepted values and `hint`. The Rust
    readers apply the same rule (`boxpose_data::recipe::choice`)."""
    section, name = key.split(".")
    table = data.get(section)
    if not isinstance(table, dict) or name not in table:
        return default
    value = table[name]
    if not isinstance(value, str) or value not in accepted:
        names = " or ".join(f'"{a}"' for a in accepted)
        raise RecipeError(f"recipe {source}: key '{key}' must be {names}, got {value!r} ({hint})")
    return value


def read_tape_along(data: dict, source: str) -> str:
    """`materials.tape_along` of parsed recipe TOML: "long" or "random", "random" when absent (the
    datasets written before the key existed, and the networks trained on them, stay as they are).
    The Blender stage reads it with this too."""
    return read_choice(
        data,
        source,
        "materials.tape_along",
        TAPE_ALONG,
        TAPE_ALONG_DEFAULT,
        '"long" ties the tape and the label to the top face\'s longer side, for new recipes; '
        '"random", the default, draws them as the existing datasets do',
    )


def read_settle_engine(data: dict, source: str) -> str:
    """`settle.engine` of parsed recipe TOML: "drake" or "mujoco", "drake" when absent."""
    return read_choice(
        data,
        source,
        "settle.engine",
        SETTLE_ENGINES,
        SETTLE_ENGINE_DEFAULT,
        '"drake", the default, certifies the scenes; "mujoco" settles training scenes '
        "≈ 50× faster under the same rules",
    )


def materials_problems(m: MaterialsSpec) -> list[str]:
    """What is wrong with a [materials] section (empty when nothing is): the tape and label
    probabilities must be probabilities, as the search's Rust reader requires."""
    return [
        f"materials.{key} must be a probability in [0, 1], got {value}"
        for key, value in (
            ("tape_probability", m.tape_probability),
            ("label_probability", m.label_probability),
        )
        if not 0.0 <= value <= 1.0
    ]


def support_problems(s: SupportSpec) -> list[str]:
    """What is wrong with a support (empty when nothing is): a kind the contract does not know,
    a half extent that is not positive, a negative wall, a bin without walls."""
    problems = []
    if s.kind not in SUPPORT_KINDS:
        problems.append(f"support.kind '{s.kind}' is not one of {', '.join(SUPPORT_KINDS)}")
    if min(s.half_extent_m) <= 0 or s.wall_height_m < 0:
        problems.append("support.half_extent_m must be positive and support.wall_height_m >= 0")
    if s.kind == "bin" and s.wall_height_m <= 0:
        problems.append("a bin needs support.wall_height_m > 0")
    return problems


class _Reader:
    """Reads dotted keys from parsed TOML with errors that name the recipe and the key."""

    def __init__(self, data: dict, source: str):
        self.data, self.source = data, source

    def _raw(self, key: str):
        node = self.data
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                raise RecipeError(f"recipe {self.source}: missing key '{key}'")
            node = node[part]
        return node

    def get(self, key: str, kind: type):
        value = self._raw(key)
        # TOML writes 0 for 0.0 happily; accept ints where floats are expected, never bools.
        ok = isinstance(value, kind) or (kind is float and isinstance(value, int))
        if isinstance(value, bool) or not ok:
            raise RecipeError(
                f"recipe {self.source}: key '{key}' must be a {kind.__name__}, got {value!r}"
            )
        # TOML spells inf and nan; no recipe quantity may be either (an infinite
        # settle.max_time_s would simulate forever).
        if kind is float and not math.isfinite(value):
            raise RecipeError(f"recipe {self.source}: key '{key}' must be finite, got {value!r}")
        return kind(value)

    def _list(self, key: str, n: int, kind: type) -> tuple:
        value = self._raw(key)
        bad = not isinstance(value, list) or len(value) != n
        bad = bad or any(
            isinstance(v, bool) or not isinstance(v, (int, float) if kind is float else kind)
            for v in value
        )
        if bad:
            raise RecipeError(
                f"recipe {self.source}: key '{key}' must be a list of {n} {kind.__name__}s, "
                f"got {value!r}"
            )
        if kind is float and not all(math.isfinite(v) for v in value):
            raise RecipeError(f"recipe {self.source}: key '{key}' must be finite, got {value!r}")
        return tuple(kind(v) for v in value)

    def pair(self, key: str, kind: type) -> tuple:
        return self._list(key, 2, kind)

    def triple(self, key: str) -> tuple:
        return self._list(key, 3, float)
