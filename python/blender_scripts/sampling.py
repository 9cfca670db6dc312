"""Every random draw of the Blender stage, in numpy (no bpy), so that ground truth and tests can
recompute them without Blender.

- Per frame, one stream seeded by `render_seed` (derived from the scene seed and frame_id): the
  camera first (hfov, distance, elevation, azimuth, look-at jitter), then the lighting. The same
  render_seed seeds the Cycles sampler.
- Per box, one stream seeded by the object's `texture_seed`: cardboard texture, tape, label.
- Per scene, one stream seeded by the scene seed: the support's appearance.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from blender_scripts.geometry import LABEL_CORNER_SIGNS, Camera, look_at
from blender_scripts.recipe import CameraSpec, LightingSpec
from boxpose_io.schema import TAPE_ALONG

_RENDER_TAG = 0x52454E44  # "REND"
_SUPPORT_TAG = 0x53555050  # "SUPP"


def derive_seed(*parts: int) -> int:
    """A non-negative 31-bit seed from integers (any sign), stable across numpy versions."""
    words = [int(p) & 0xFFFFFFFFFFFFFFFF for p in parts]
    return int(np.random.SeedSequence(words).generate_state(1, np.uint32)[0]) & 0x7FFFFFFF


def render_seed(scene_seed: int, frame_id: int) -> int:
    """Seed of frame `frame_id` of a scene: its camera and lighting draws and the Cycles sampler."""
    return derive_seed(scene_seed, _RENDER_TAG, frame_id)


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = lo_hi
    return float(rng.uniform(lo, hi)) if hi > lo else float(lo)


# ---------------------------------------------------------------------------------------------
# Camera and lighting (per frame)


def draw_camera(
    spec: CameraSpec, box_centres_world: np.ndarray, rng: np.random.Generator
) -> tuple[Camera, dict]:
    """The frame's camera: looks at the boxes' centroid plus uniform jitter from `distance`,
    `elevation` above the support plane (world z up) and `azimuth` about world z."""
    hfov = _uniform(rng, spec.hfov_deg)
    distance = _uniform(rng, spec.distance_m)
    elevation = _uniform(rng, spec.elevation_deg)
    azimuth = _uniform(rng, spec.azimuth_deg)
    j = spec.look_at_jitter_m
    jitter = rng.uniform(-j, j, 3) if j > 0 else np.zeros(3)
    centroid = np.mean(np.asarray(box_centres_world, dtype=np.float64).reshape(-1, 3), axis=0)
    target = centroid + jitter
    el, az = math.radians(elevation), math.radians(azimuth)
    centre = target + distance * np.array(
        [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    )
    camera = Camera.from_hfov(spec.width, spec.height, math.radians(hfov), look_at(centre, target))
    draw = {
        "hfov_deg": hfov,
        "distance_m": distance,
        "elevation_deg": elevation,
        "azimuth_deg": azimuth,
        "look_at_jitter_m": jitter.tolist(),
        "look_at_m": target.tolist(),
    }
    return camera, draw


def _direction(elevation_deg: float, azimuth_deg: float) -> list[float]:
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]


def draw_lighting(spec: LightingSpec, target: np.ndarray, rng: np.random.Generator) -> dict:
    """A sun, 0..n area lights aimed at the look-at point, and a tinted ambient world."""
    sun = {
        "strength": _uniform(rng, spec.sun_strength),
        # direction *towards* the sun, and its angular diameter (soft shadows)
        "direction": _direction(
            _uniform(rng, spec.sun_elevation_deg), _uniform(rng, spec.sun_azimuth_deg)
        ),
        "angle_deg": _uniform(rng, (2.0, 15.0)),
    }
    lo, hi = spec.area_lights
    areas = []
    for _ in range(int(rng.integers(lo, hi + 1))):
        power = _uniform(rng, spec.area_power_w)
        radius = _uniform(
            rng, (3.0, 4.5)
        )  # Cycles: 100 W at 2 m lights white paper to 1.8, a unit sun to 0.32
        direction = np.array(_direction(_uniform(rng, (35.0, 85.0)), _uniform(rng, (0.0, 360.0))))
        warmth = _uniform(rng, (-0.1, 0.1))
        areas.append(
            {
                "power_w": power,
                "size_m": _uniform(rng, (0.2, 0.8)),
                "location_m": (np.asarray(target) + radius * direction).tolist(),
                "target_m": np.asarray(target).tolist(),
                "color": [1.0 + warmth, 1.0, 1.0 - warmth],
            }
        )
    jit = spec.world_color_jitter
    world = {
        "strength": _uniform(rng, spec.world_strength),
        "color": np.clip(1.0 + rng.uniform(-jit, jit, 3), 0.0, None).tolist()
        if jit > 0
        else [1.0, 1.0, 1.0],
    }
    return {"sun": sun, "area": areas, "world": world}


# ---------------------------------------------------------------------------------------------
# Box appearance (per object, from texture_seed)

# Packing-tape colours (linear RGB) and roughness: tan, clear-ish (picks up the cardboard), white.
_TAPE_STYLES = [
    ([0.42, 0.25, 0.09], 0.25, 0.85),  # colour, roughness, opacity
    ([0.55, 0.42, 0.25], 0.15, 0.35),
    ([0.80, 0.80, 0.78], 0.35, 0.95),
]


@dataclass(frozen=True)
class Tape:
    axis: int  # the strip runs along this box axis (0 = x, 1 = y) across the +z face
    offset_m: float  # centre of the strip along the other horizontal axis
    width_m: float
    down_m: float  # how far the strip continues down the two end faces
    color: tuple[float, float, float]
    roughness: float
    opacity: float


@dataclass(frozen=True)
class Label:
    centre_m: tuple[float, float]  # on the +z face, box frame (x, y)
    half_m: tuple[float, float]  # half extents along the label's u, v axes
    rotated: bool  # False: u = box x, v = box y; True: u = box y, v = −box x
    pattern_seed: float  # offsets the printed pattern (text lines, barcode)

    def corners_box(self, size) -> np.ndarray:
        """The 4 label corners (4×3) in the box frame, on the +z face; corner k has sign pattern
        bit0 → u, bit1 → v (0 = −, 1 = +) in the label's own axes."""
        u = np.array([0.0, 1.0]) if self.rotated else np.array([1.0, 0.0])
        v = np.array([-1.0, 0.0]) if self.rotated else np.array([0.0, 1.0])
        c = np.array(self.centre_m)
        xy = (
            c
            + LABEL_CORNER_SIGNS[:, :1] * self.half_m[0] * u
            + LABEL_CORNER_SIGNS[:, 1:] * self.half_m[1] * v
        )
        return np.column_stack([xy, np.full(4, 0.5 * float(size[2]))])


@dataclass(frozen=True)
class BoxAppearance:
    noise_offset: tuple[float, float, float]  # shifts the procedural cardboard texture
    noise_scale: float
    fibre_scale: float
    color_variation: float  # amplitude of the brightness variation of the cardboard
    tape: Tape | None
    label: Label | None

    def as_dict(self) -> dict:
        return asdict(self)


def draw_appearance(
    texture_seed: int, size, has_tape: bool, has_label: bool, *, tape_along: str
) -> BoxAppearance:
    """The box's procedural look, a pure function of its objects row (texture_seed, size,
    has_tape, has_label) and its recipe's `materials.tape_along`.

    tape_along "random": the tape's axis and the label's turn are drawn. "long": both follow the
    longer side of the +z face (x when dx >= dy), as on a regular slotted carton, so the texture
    says which side is longer. The draws are made either way, so the stream stays aligned: "random"
    is the look of every dataset written before the key existed, and "long" changes only those two
    choices (and what follows from them: the strip's offset and the label's extents)."""
    if tape_along not in TAPE_ALONG:
        raise ValueError(f"tape_along must be one of {TAPE_ALONG}, got {tape_along!r}")
    rng = np.random.default_rng(derive_seed(texture_seed))
    dx, dy, dz = (float(s) for s in size)
    long_axis = 0 if dx >= dy else 1
    noise_offset = tuple(float(v) for v in rng.uniform(-100.0, 100.0, 3))
    noise_scale = _uniform(rng, (6.0, 14.0))
    fibre_scale = _uniform(rng, (150.0, 300.0))
    variation = _uniform(rng, (0.08, 0.2))
    tape = None
    if has_tape:
        axis = int(rng.integers(0, 2))
        if tape_along == "long":
            axis = long_axis
        across = dy if axis == 0 else dx  # extent perpendicular to the strip, on the +z face
        width = min(0.048, 0.35 * across)
        offset = _uniform(rng, (-0.1, 0.1)) * (across - width)
        color, roughness, opacity = _TAPE_STYLES[int(rng.integers(0, len(_TAPE_STYLES)))]
        tape = Tape(
            axis, offset, width, _uniform(rng, (0.3, 0.8)) * dz, tuple(color), roughness, opacity
        )
    label = None
    if has_label:
        rotated = bool(rng.integers(0, 2))
        if tape_along == "long":
            rotated = long_axis == 1  # u = box y when y is the longer side
        eu, ev = (dy, dx) if rotated else (dx, dy)  # face extent along the label's u and v axes
        hu = 0.5 * min(_uniform(rng, (0.35, 0.6)) * eu, 0.15)
        hv = 0.5 * min(_uniform(rng, (0.3, 0.55)) * ev, 0.10)
        # keep a margin of 10 % of the face around the label
        cu = _uniform(rng, (-1.0, 1.0)) * max(0.5 * eu - hu - 0.05 * eu, 0.0)
        cv = _uniform(rng, (-1.0, 1.0)) * max(0.5 * ev - hv - 0.05 * ev, 0.0)
        centre = (-cv, cu) if rotated else (cu, cv)  # u = y, v = −x  ⇒  x = −v, y = u
        label = Label(
            (float(centre[0]), float(centre[1])), (hu, hv), rotated, _uniform(rng, (0.0, 1000.0))
        )
    return BoxAppearance(noise_offset, noise_scale, fibre_scale, variation, tape, label)


# ---------------------------------------------------------------------------------------------
# Support appearance (per scene)

_SUPPORT_COLORS = {
    "floor": [
        [0.30, 0.30, 0.30],
        [0.45, 0.42, 0.38],
        [0.20, 0.22, 0.25],
        [0.55, 0.55, 0.52],
    ],  # concrete, greys
    "bin": [
        [0.05, 0.15, 0.45],
        [0.45, 0.05, 0.04],
        [0.25, 0.25, 0.27],
        [0.05, 0.25, 0.08],
    ],  # plastic crates
    "pallet": [[0.48, 0.34, 0.20], [0.40, 0.30, 0.18], [0.55, 0.42, 0.28]],  # pine
}


def draw_support_appearance(scene_seed: int, kind: str) -> dict:
    rng = np.random.default_rng(derive_seed(scene_seed, _SUPPORT_TAG))
    palette = _SUPPORT_COLORS.get(kind, _SUPPORT_COLORS["floor"])
    base = np.asarray(palette[int(rng.integers(0, len(palette)))]) * rng.uniform(0.85, 1.15)
    floor = np.asarray(
        _SUPPORT_COLORS["floor"][int(rng.integers(0, len(_SUPPORT_COLORS["floor"])))]
    )
    return {
        "color": np.clip(base, 0.0, 1.0).tolist(),
        "roughness": _uniform(rng, (0.4, 0.9)),
        "noise_offset": rng.uniform(-100.0, 100.0, 3).tolist(),
        "floor_color": floor.tolist(),  # the ground under a bin or pallet
    }
