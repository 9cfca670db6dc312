"""Every key a scene recipe may hold: `RECIPE_KEYS`, defined once in `rust/data/src/recipe.rs`
and loaded from the generated schema.json. The Drake stage and the Blender stage each read their
own part of a recipe; both refuse a key that is in neither part (a misspelt `max_tiem_s` used to
be ignored silently), naming the key, as the Rust reader does. A test checks that the two Python
readers read exactly these keys."""

from boxpose_io.schema import RECIPE_KEYS

__all__ = ["RECIPE_KEYS", "unknown_keys_problem", "unknown_recipe_keys"]


def unknown_recipe_keys(data: dict, prefix: str = "") -> list[str]:
    """Dotted keys of a parsed recipe that are not recipe keys (a table that is not a section
    counts as one unknown key)."""
    unknown = []
    for key, value in data.items():
        dotted = prefix + key
        if isinstance(value, dict) and any(k.startswith(dotted + ".") for k in RECIPE_KEYS):
            unknown += unknown_recipe_keys(value, dotted + ".")
        elif dotted not in RECIPE_KEYS:
            unknown.append(dotted)
    return sorted(unknown)


def unknown_keys_problem(data: dict, source: str) -> str | None:
    """The message both recipe readers raise for keys that are not recipe keys, or None."""
    unknown = unknown_recipe_keys(data)
    if not unknown:
        return None
    return (
        f"recipe {source}: unknown key{'s' if len(unknown) > 1 else ''} "
        f"{', '.join(repr(k) for k in unknown)} (misspelt? docs/recipes.md lists every recipe "
        'key with its type, range and default, as does `boxpose schema` under "recipe")'
    )
