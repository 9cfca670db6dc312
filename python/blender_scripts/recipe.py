"""The recipe sections the Blender stage consumes: [camera], [lighting], [materials], [render].

A scene carries its recipe verbatim (`scenes.recipe_toml`), so a scene row alone says how to render
it. `boxpose_io.recipe` reads and checks the keys, with their defaults, from the one reference
(rust/data/src/recipe.rs); this module builds the Blender stage's dataclasses from them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from boxpose_io.recipe import (
    BLENDER_KEYS,
    BLENDER_SECTIONS,
    MaterialsSpec,
    RecipeError,
    SupportSpec,
    read,
    section,
)

__all__ = ["CameraSpec", "LightingSpec", "RecipeError", "RenderRecipe", "RenderSpec"]


# Every field is read by `boxpose_io.recipe.read`, with the reference's defaults for the optional
# keys (docs/recipes.md): they are not repeated here.


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
    # "frame" renders the whole image; "box" only the region around one box per frame (the
    # keypoint network's crop), region_margin × the box's projected extent.
    region: str
    region_margin: float
    # Aim at this box's centre instead of the boxes' centroid (the search's target box).
    look_at_object: int | None = None


@dataclass(frozen=True)
class LightingSpec:
    sun_strength: tuple[float, float]
    area_lights: tuple[int, int]  # inclusive
    area_power_w: tuple[float, float]
    world_strength: tuple[float, float]
    world_color_jitter: float
    # The range of the direction towards the sun (the search pins them).
    sun_elevation_deg: tuple[float, float]
    sun_azimuth_deg: tuple[float, float]


@dataclass(frozen=True)
class RenderSpec:
    samples: int
    denoise: bool
    sensor_depth: bool
    max_bounces: int  # Cycles light bounces
    view_transform: str  # Blender colour management view transform of the PNGs
    exposure: float  # colour management exposure (stops)


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


def parse_render_recipe(text: str, source: str = "<recipe>") -> RenderRecipe:
    values = read(text, source, BLENDER_SECTIONS, BLENDER_KEYS)
    return RenderRecipe(
        values["name"],
        CameraSpec(**section(values, "camera")),
        LightingSpec(**section(values, "lighting")),
        MaterialsSpec(**section(values, "materials")),
        RenderSpec(**section(values, "render")),
        SupportSpec(**section(values, "support")),
        # Settled boxes may sink into each other and the support by up to
        # settle.max_penetration_m.
        values["settle.max_penetration_m"] + 0.001,
    )
