"""Every key a scene recipe may hold, in one place. The Drake stage and the Blender stage each
read their own part of a recipe; both refuse a key that is in neither part (a misspelt
`max_tiem_s` used to be ignored silently), naming the key. A test checks that the two readers
read exactly these keys."""

RECIPE_KEYS: frozenset[str] = frozenset(
    {
        # the recipe itself
        "name",
        "description",
        "seed",
        "num_scenes",
        # Drake: what is dropped, where, and when it counts as settled
        "boxes.count",
        "boxes.size_min_m",
        "boxes.size_max_m",
        "boxes.density_kg_m3",
        "boxes.friction",
        "support.kind",
        "support.half_extent_m",
        "support.wall_height_m",
        "drop.height_m",
        "drop.min_separation_m",
        "drop.max_solve_attempts",
        "settle.time_step_s",
        "settle.max_time_s",
        "settle.window_s",
        "settle.max_linear_speed_mps",
        "settle.max_angular_speed_radps",
        "settle.max_penetration_m",
        # both: the boxes' surfaces
        "materials.roughness",
        "materials.tape_probability",
        "materials.label_probability",
        # Blender: cameras, lights, render settings
        "camera.frames_per_scene",
        "camera.width",
        "camera.height",
        "camera.hfov_deg",
        "camera.distance_m",
        "camera.elevation_deg",
        "camera.azimuth_deg",
        "camera.look_at_jitter_m",
        "camera.look_at_object",
        "lighting.sun_strength",
        "lighting.sun_elevation_deg",
        "lighting.sun_azimuth_deg",
        "lighting.area_lights",
        "lighting.area_power_w",
        "lighting.world_strength",
        "lighting.world_color_jitter",
        "render.samples",
        "render.denoise",
        "render.sensor_depth",
        "render.max_bounces",
        "render.view_transform",
        "render.exposure",
    }
)


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
        f"{', '.join(repr(k) for k in unknown)} (misspelt? the keys are listed in "
        "python/boxpose_io/recipe_keys.py)"
    )
