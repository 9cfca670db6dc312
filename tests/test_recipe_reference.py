"""docs/recipes.md against the readers: the bounds and defaults it documents (rust/data/src/
recipe.rs, RECIPE_REFERENCE, exported into schema.json) are the ones the Python recipe readers
enforce, and every key a shipped recipe uses is documented."""

import json
import tomllib
from pathlib import Path

import pytest

import boxpose_io.schema
from blender_scripts.recipe import parse_render_recipe
from boxpose_io.recipe import BLENDER_SECTIONS, DRAKE_SECTIONS
from drake_scenes.recipe import Recipe, RecipeError

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = {
    k["key"]: k
    for k in json.loads((Path(boxpose_io.schema.__file__).parent / "schema.json").read_text())[
        "recipe"
    ]["reference"]
}
BASE = (ROOT / "datasets/recipes/clutter.toml").read_text()
LIST_LENGTH = {"[min, max] integers": 2, "[min, max] floats": 2, "[x, y] floats": 2}
LIST_LENGTH["[dx, dy, dz] floats"] = 3


def flat_keys(table: dict, prefix: str = "") -> set[str]:
    keys = set()
    for key, value in table.items():
        if isinstance(value, dict):
            keys |= flat_keys(value, f"{prefix}{key}.")
        else:
            keys.add(prefix + key)
    return keys


def with_value(key: str, number: float) -> str:
    """clutter.toml with `key` set to `number` (every number of it, for a list)."""
    data = tomllib.loads(BASE)
    section, _, name = key.rpartition(".")
    table = data.setdefault(section, {}) if section else data
    kind = REFERENCE[key]["type"]
    if kind.endswith("integers") or kind == "integer":
        number = int(number)
    table[name] = [number] * LIST_LENGTH[kind] if kind in LIST_LENGTH else number
    return to_toml(data)


def to_toml(data: dict) -> str:
    """The few TOML shapes a recipe uses (no TOML writer is installed)."""
    lines = [f"{k} = {json.dumps(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for section, table in data.items():
        if isinstance(table, dict):
            lines.append(f"[{section}]")
            lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def refused(key: str, text: str) -> bool:
    """Whether a reader that checks `key`'s section refuses `text`; every such reader must
    agree."""
    section = key.rpartition(".")[0]
    readers = []
    if section in DRAKE_SECTIONS:
        readers.append(lambda: Recipe.from_toml(text))
    if section in BLENDER_SECTIONS:
        readers.append(lambda: parse_render_recipe(text))
    verdicts = set()
    for read in readers:
        try:
            read()
            verdicts.add(False)
        except RecipeError:
            verdicts.add(True)
    assert len(verdicts) == 1, f"the readers disagree on {key}"
    return verdicts.pop()


def test_every_key_a_shipped_recipe_uses_is_documented():
    recipes = sorted((ROOT / "datasets/recipes").glob("*.toml"))
    assert recipes
    for path in recipes:
        undocumented = flat_keys(tomllib.loads(path.read_text())) - REFERENCE.keys()
        assert not undocumented, f"{path.name}: {sorted(undocumented)} not in docs/recipes.md"


def test_the_base_recipe_is_accepted():
    assert not refused("materials.roughness", BASE)


# Every key whose documented interval involves no other key: its bounds alone say what is refused.
BOUNDED = sorted(
    k
    for k, ref in REFERENCE.items()
    if ref["accepted"] is not None
    and "one_of" not in ref["accepted"]
    and not ref["accepted"]["and"]
)


def test_the_bounded_keys_include_those_users_get_wrong():
    assert {
        "materials.tape_probability",
        "materials.label_probability",
        "camera.elevation_deg",
        "camera.hfov_deg",
        "render.samples",
        "lighting.sun_elevation_deg",
    } <= set(BOUNDED)


@pytest.mark.parametrize("key", BOUNDED)
def test_documented_bounds_are_what_the_readers_refuse(key):
    """At an inclusive bound the readers accept, at an exclusive one they refuse; one step past
    either (1 for an integer) they refuse, one step inside they accept."""
    accepted = REFERENCE[key]["accepted"]
    integer = "integer" in REFERENCE[key]["type"]
    step = 1 if integer else 1e-6
    for bound, outwards in ((accepted["min"], -1), (accepted["max"], +1)):
        if bound is None:
            continue
        value = bound["value"]
        at = refused(key, with_value(key, value))
        assert at is not bound["inclusive"], f"{key} = {value}: documented {bound}"
        assert refused(key, with_value(key, value + outwards * step)), f"{key} past {value}"
        assert not refused(key, with_value(key, value - outwards * step)), f"{key} inside {value}"


@pytest.mark.parametrize(
    "key, wild",
    [
        ("seed", -7),
        ("materials.roughness", 5.0),
        ("camera.azimuth_deg", -720.0),
        ("camera.look_at_jitter_m", -1.0),
        ("lighting.area_power_w", -10.0),
        ("lighting.world_color_jitter", -3.0),
        ("render.exposure", 40.0),
    ],
)
def test_not_checked_keys_are_not_checked(key, wild):
    assert REFERENCE[key]["accepted"] is None
    assert not refused(key, with_value(key, wild))


def test_a_recipe_without_its_optional_keys_reads_the_documented_defaults():
    """Every optional key left out is read as docs/recipes.md's default, by both readers."""
    data = tomllib.loads(BASE)
    optional = [k for k, ref in REFERENCE.items() if not ref["required"]]
    for key in optional:
        section, _, name = key.rpartition(".")
        (data.get(section, {}) if section else data).pop(name, None)
    text = to_toml(data)
    blender = parse_render_recipe(text).as_dict()
    drake = Recipe.from_toml(text)
    checked = 0
    for key in optional:
        section, _, name = key.rpartition(".")
        default = REFERENCE[key]["default_toml"]
        expected = None if default is None else tomllib.loads(f"v = {default}")["v"]
        if section in BLENDER_SECTIONS:
            value = blender[section][name]
        elif section and section in DRAKE_SECTIONS:
            value = getattr(getattr(drake, section), name)
        else:  # the top level's optional key is the description, which no stage reads
            continue
        value = list(value) if isinstance(value, tuple) else value
        assert value == expected, f"{key}: read {value!r}, documented {expected!r}"
        checked += 1
    assert checked >= 8
