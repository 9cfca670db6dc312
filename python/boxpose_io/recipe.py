"""The recipe model of the Python stages: the reference of `rust/data/src/recipe.rs`
(`RECIPE_REFERENCE`, exported into schema.json), read and checked in one place.

`read` parses a recipe, refuses a key that is not a recipe key, and checks every key of the
sections a stage reads: present when required, of its type, finite, a range with min ≤ max,
within its documented bounds, one of its choices, and the rules between keys that bounds cannot
say. It returns the values with the documented defaults filled in, so that the Drake and the
Blender stage only name their sections and build their dataclasses. The Rust readers check the
same reference (`boxpose_data::recipe::Recipe`) with the same messages.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from typing import Any

from boxpose_io.recipe_keys import unknown_keys_problem
from boxpose_io.schema import MAX_SETTLE_STEPS, RECIPE_REFERENCE


class RecipeError(ValueError):
    """A recipe that is malformed or that cannot be generated; the message names the recipe."""


@dataclass(frozen=True)
class SupportSpec:
    """`[support]`: read by the Drake stage (the support it drops onto) and the Blender stage
    (the support it draws); `half_extent_m` is the region's half size along (x, y)."""

    kind: str
    half_extent_m: tuple[float, float]
    wall_height_m: float


@dataclass(frozen=True)
class MaterialsSpec:
    """`[materials]`: drawn by the Drake stage into the objects rows, applied by Blender."""

    roughness: tuple[float, float]
    tape_probability: float
    label_probability: float
    # Which side of the top face the tape and the label's long axis follow: "long" or "random".
    tape_along: str


# What each Python stage reads: "" is the top level. [support] and [materials] are read by both;
# the Blender stage also reads the recipe's name and how far settled boxes may sink into others.
DRAKE_SECTIONS = frozenset({"", "boxes", "support", "drop", "settle", "materials"})
BLENDER_SECTIONS = frozenset({"camera", "lighting", "render", "materials", "support"})
BLENDER_KEYS = frozenset({"name", "settle.max_penetration_m"})

_LIST_SHAPE = {  # a list type: (length, integer numbers)
    "[min, max] integers": (2, True),
    "[min, max] floats": (2, False),
    "[x, y] floats": (2, False),
    "[dx, dy, dz] floats": (3, False),
}


def read(
    text: str, source: str, sections: frozenset[str], keys: frozenset[str] = frozenset()
) -> dict[str, Any]:
    """The values of `sections` (and of single `keys` outside them) of a recipe's TOML text,
    dotted by section ("camera.width", "seed"), checked, with the documented defaults; a list is
    a tuple, and a key whose absence means "not used" is left out. RecipeError names `source`
    and the first problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"recipe {source}: invalid TOML ({e})") from e
    if problem := unknown_keys_problem(data, source):
        raise RecipeError(problem)
    values = {}
    for key, ref in RECIPE_REFERENCE.items():
        section, _, name = key.rpartition(".")
        if section not in sections and key not in keys:
            continue
        table = data.get(section, {}) if section else data
        if name in table:
            values[key] = _checked(key, ref, table[name], source)
        elif ref["required"]:
            raise RecipeError(f"recipe {source}: missing key '{key}'")
        elif ref["default_toml"] is not None:
            values[key] = _as_python(tomllib.loads(f"v = {ref['default_toml']}")["v"])
    if problem := _rule_problem(values):
        raise RecipeError(f"recipe {source}: {problem}")
    return values


def section(values: dict[str, Any], name: str) -> dict[str, Any]:
    """The values of one section from `read`, keyed by name: a dataclass's keyword arguments."""
    prefix = name + "."
    return {k.removeprefix(prefix): v for k, v in values.items() if k.startswith(prefix)}


def _as_python(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


def _is_number(value: Any, integer: bool) -> bool:
    # TOML writes 0 for 0.0 happily: an integer is a float too; a boolean is neither.
    kinds = int if integer else (int, float)
    return isinstance(value, kinds) and not isinstance(value, bool)


def _checked(key: str, ref: dict, value: Any, source: str) -> Any:
    kind, accepted = ref["type"], ref["accepted"]
    written = json.dumps(value)

    def refuse(problem: str) -> RecipeError:
        return RecipeError(f"recipe {source}: key '{key}' {problem}, got {written}")

    if kind == "string":
        # a choice says its choices whatever was written instead (a number, a list, …)
        if accepted and "one_of" in accepted and value not in accepted["one_of"]:
            raise refuse("must be " + " or ".join(f'"{c}"' for c in accepted["one_of"]))
        if not isinstance(value, str):
            raise refuse(f"must be {kind}")
        return value
    if kind == "boolean":
        if not isinstance(value, bool):
            raise refuse(f"must be {kind}")
        return value
    if kind in _LIST_SHAPE:
        length, integer = _LIST_SHAPE[kind]
        ok = isinstance(value, list) and len(value) == length
        if not ok or not all(_is_number(v, integer) for v in value):
            raise refuse(f"must be {kind}")
        numbers = [float(v) for v in value]
    else:
        if not _is_number(value, kind == "integer"):
            raise refuse(f"must be {kind}")
        numbers = [float(value)]
    if not all(math.isfinite(v) for v in numbers):
        raise refuse("must be finite")
    if kind.startswith("[min, max]") and numbers[0] > numbers[1]:
        raise RecipeError(
            f"recipe {source}: key '{key}' is a range [min, max] with min above max: {written}"
        )
    if accepted and "min" in accepted and not all(_within(v, accepted) for v in numbers):
        raise refuse(f"must be {accepted['text']}")
    if kind in _LIST_SHAPE:
        return tuple(int(v) if _LIST_SHAPE[kind][1] else float(v) for v in value)
    return value if kind == "integer" else float(value)


def _within(v: float, accepted: dict) -> bool:
    lo, hi = accepted["min"], accepted["max"]
    above = lo is None or (v >= lo["value"] if lo["inclusive"] else v > lo["value"])
    below = hi is None or (v <= hi["value"] if hi["inclusive"] else v < hi["value"])
    return above and below


def _rule_problem(values: dict[str, Any]) -> str | None:
    """The first broken rule between keys (the reference's "and" texts) among `values`, or None;
    `boxpose_data::recipe::check_rules` in Rust."""
    size_min, size_max = values.get("boxes.size_min_m"), values.get("boxes.size_max_m")
    if size_min and size_max and any(lo > hi for lo, hi in zip(size_min, size_max, strict=True)):
        return "boxes.size_min_m must be ≤ boxes.size_max_m on every axis"
    if values.get("support.kind") == "bin" and values.get("support.wall_height_m", 1.0) <= 0:
        return "a bin needs support.wall_height_m > 0"
    step, window, max_time = (
        values.get(f"settle.{k}") for k in ("time_step_s", "window_s", "max_time_s")
    )
    if step is not None and window is not None and max_time is not None:
        if not step < window < max_time:
            return (
                "settle: need time_step_s < window_s < max_time_s, "
                f"got {step} < {window} < {max_time}"
            )
        if max_time / step > MAX_SETTLE_STEPS:
            return (
                f"settle: max_time_s / time_step_s = {max_time / step:.3e} steps is more than "
                f"{MAX_SETTLE_STEPS:.0e}"
            )
    return None
