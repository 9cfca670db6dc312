"""The recipe sections the Blender stage consumes: [camera], [lighting], [materials], [render].

A scene carries its recipe verbatim (`scenes.recipe_toml`), so a scene row alone says how to render
it. Keys are read strictly: a missing or mistyped key is an error naming the recipe and the key.
Optional keys (added for rendering, documented in the recipes) have defaults listed here.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass

from boxpose_io.recipe_keys import unknown_keys_problem
from boxpose_io.schema import CAMERA_REGION_DEFAULT, CAMERA_REGIONS

# [support] and [materials] are defined, read and checked once, by the scene stage that owns them
# (no pydrake import).
from drake_scenes.recipe import (
    MaterialsSpec,
    RecipeError,
    SupportSpec,
    materials_problems,
    read_choice,
    read_support,
    read_tape_along,
    support_problems,
)


@dataclass(frozen=True)
class CameraSpec:
    frames_per_scene: int
    width: int
    height: int
    hfov_deg: tuple[float, float]
    distance_m: tuple[float, float]
    elevation_deg: tuple[float, float]
    azimuth_deg: tuple[float, float]
    look_at_jitter_m: float
    # Optional: aim at this box's centre instead of the boxes' centroid (the search's target box).
    look_at_object: int | None = None
    # Optional: "frame" renders the whole image; "box" only the region around one box per frame
    # (the keypoint network's crop), region_margin × the box's projected extent.
    region: str = CAMERA_REGION_DEFAULT
    region_margin: float = 1.75


@dataclass(frozen=True)
class LightingSpec:
    sun_strength: tuple[float, float]
    area_lights: tuple[int, int]  # inclusive
    area_power_w: tuple[float, float]
    world_strength: tuple[float, float]
    world_color_jitter: float
    # Optional: the range of the direction towards the sun (the search pins them).
    sun_elevation_deg: tuple[float, float] = (30.0, 80.0)
    sun_azimuth_deg: tuple[float, float] = (0.0, 360.0)


@dataclass(frozen=True)
class RenderSpec:
    samples: int
    denoise: bool
    sensor_depth: bool
    # Optional keys:
    max_bounces: int = 4  # Cycles light bounces (cardboard is diffuse: 4 is plenty)
    view_transform: str = "AgX"  # Blender colour management view transform of the PNGs
    exposure: float = -1.0  # colour management exposure (stops)


@dataclass(frozen=True)
class RenderRecipe:
    name: str
    camera: CameraSpec
    lighting: LightingSpec
    materials: MaterialsSpec
    render: RenderSpec
    support: SupportSpec
    contact_m: float  # corners this close to another surface are not occluded by it

    def as_dict(self) -> dict:
        return asdict(self)


_OPTIONAL_RENDER = {"max_bounces": int, "view_transform": str, "exposure": float}


def _get(data: dict, key: str, kind, source: str):
    node = data
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            raise RecipeError(f"recipe {source}: missing key '{key}'")
        node = node[part]
    ok = isinstance(node, kind) or (kind is float and isinstance(node, int))
    if (isinstance(node, bool) and kind is not bool) or not ok:
        raise RecipeError(f"recipe {source}: key '{key}' must be a {kind.__name__}, got {node!r}")
    if kind is float and not math.isfinite(node):
        raise RecipeError(f"recipe {source}: key '{key}' must be finite, got {node!r}")
    return kind(node)


def _pair(data: dict, key: str, kind, source: str) -> tuple:
    node = _get(data, key, list, source)
    if len(node) != 2 or any(
        isinstance(v, bool) or not isinstance(v, (int, float) if kind is float else kind)
        for v in node
    ):
        raise RecipeError(
            f"recipe {source}: key '{key}' must be a list of 2 {kind.__name__}s, got {node!r}"
        )
    lo, hi = kind(node[0]), kind(node[1])
    if kind is float and not (math.isfinite(lo) and math.isfinite(hi)):
        raise RecipeError(f"recipe {source}: key '{key}' must be finite, got {node!r}")
    if lo > hi:
        raise RecipeError(f"recipe {source}: key '{key}' must be a range [min, max], got {node!r}")
    return lo, hi


def parse_render_recipe(text: str, source: str = "<recipe>") -> RenderRecipe:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"recipe {source}: invalid TOML ({e})") from e
    if problem := unknown_keys_problem(data, source):
        raise RecipeError(problem)
    g = lambda key, kind: _get(data, key, kind, source)  # noqa: E731
    p = lambda key, kind=float: _pair(data, key, kind, source)  # noqa: E731
    camera = CameraSpec(
        frames_per_scene=g("camera.frames_per_scene", int),
        width=g("camera.width", int),
        height=g("camera.height", int),
        hfov_deg=p("camera.hfov_deg"),
        distance_m=p("camera.distance_m"),
        elevation_deg=p("camera.elevation_deg"),
        azimuth_deg=p("camera.azimuth_deg"),
        look_at_jitter_m=g("camera.look_at_jitter_m", float),
        region=read_choice(
            data,
            source,
            "camera.region",
            CAMERA_REGIONS,
            CAMERA_REGION_DEFAULT,
            '"frame" renders whole images; "box" the region around one box per frame',
        ),
        **{
            k: g(f"camera.{k}", kind)
            for k, kind in (("look_at_object", int), ("region_margin", float))
            if k in data.get("camera", {})
        },
    )
    lighting = LightingSpec(
        sun_strength=p("lighting.sun_strength"),
        area_lights=p("lighting.area_lights", int),
        area_power_w=p("lighting.area_power_w"),
        world_strength=p("lighting.world_strength"),
        world_color_jitter=g("lighting.world_color_jitter", float),
        **{
            k: p(f"lighting.{k}")
            for k in ("sun_elevation_deg", "sun_azimuth_deg")
            if k in data.get("lighting", {})
        },
    )
    materials = MaterialsSpec(
        roughness=p("materials.roughness"),
        tape_probability=g("materials.tape_probability", float),
        label_probability=g("materials.label_probability", float),
        tape_along=read_tape_along(data, source),
    )
    optional = {
        k: g(f"render.{k}", kind)
        for k, kind in _OPTIONAL_RENDER.items()
        if k in data.get("render", {})
    }
    render = RenderSpec(
        samples=g("render.samples", int),
        denoise=g("render.denoise", bool),
        sensor_depth=g("render.sensor_depth", bool),
        **optional,
    )
    # Read and checked exactly as the scene stage does: half_extent_m is (x, y), not a range.
    support = read_support(data, source)
    problems = support_problems(support) + materials_problems(materials)
    if camera.frames_per_scene < 1 or camera.width < 1 or camera.height < 1:
        problems.append("camera.frames_per_scene, width and height must be >= 1")
    if not (0 < camera.hfov_deg[0] and camera.hfov_deg[1] < 180):
        problems.append("camera.hfov_deg must lie in (0, 180)")
    if camera.distance_m[0] <= 0:
        problems.append("camera.distance_m must be positive")
    if not (-90 < camera.elevation_deg[0] and camera.elevation_deg[1] < 90):
        problems.append("camera.elevation_deg must lie in (-90, 90)")
    if camera.look_at_object is not None and camera.look_at_object < 0:
        problems.append("camera.look_at_object must be an object_id >= 0")
    if not camera.region_margin >= 1:
        problems.append(f"camera.region_margin must be >= 1, got {camera.region_margin}")
    if not (-90 <= lighting.sun_elevation_deg[0] and lighting.sun_elevation_deg[1] <= 90):
        problems.append("lighting.sun_elevation_deg must lie in [-90, 90]")
    if lighting.area_lights[0] < 0:
        problems.append("lighting.area_lights must be >= 0")
    if render.samples < 1 or render.max_bounces < 0:
        problems.append("render.samples must be >= 1 and render.max_bounces >= 0")
    if problems:
        raise RecipeError(f"recipe {source}: " + "; ".join(problems))
    # Settled boxes may sink into each other and the support by up to settle.max_penetration_m.
    penetration = (
        g("settle.max_penetration_m", float)
        if "max_penetration_m" in data.get("settle", {})
        else 0.002
    )
    return RenderRecipe(
        _get(data, "name", str, source),
        camera,
        lighting,
        materials,
        render,
        support,
        penetration + 0.001,
    )
