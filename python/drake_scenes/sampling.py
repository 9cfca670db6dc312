"""Random scenes drawn from a recipe: box count, sizes, masses, frictions, materials and the
initial (pre-projection) poses.

Every scene is drawn from its own seed, derived from (recipe seed, scene_id) alone, so a scene
does not depend on how the dataset was sharded, and a row's stored seed regenerates it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from boxpose_io.rotations import quat_to_matrix
from drake_scenes.plant import BoxBody, canonical_quat, support_top_z
from drake_scenes.recipe import Recipe

# Candidate positions drawn per box while looking for a free spot in the drop layer.
PLACEMENT_CANDIDATES = 64

# Cardboard base colour in linear RGB (≈ sRGB 0.69, 0.53, 0.37, kraft board); each box scales
# its brightness and shifts it toward yellow or red a little.
CARDBOARD_LINEAR_RGB = np.array([0.43, 0.25, 0.11])


@dataclass
class Material:
    base_color_rgb: np.ndarray  # (3,) linear RGB in [0, 1]
    roughness: float
    texture_seed: int
    has_tape: bool
    has_label: bool


@dataclass
class SceneSample:
    scene_id: int
    seed: int
    boxes: list[BoxBody]  # poses are the sampled (not yet projected) drop poses
    materials: list[Material]


def scene_seed(recipe_seed: int, scene_id: int) -> int:
    """A non-negative int64 seed that depends only on the recipe seed and the scene id."""
    state = np.random.SeedSequence([recipe_seed, scene_id]).generate_state(1, np.uint64)[0]
    return int(state >> np.uint64(1))


def bounding_radius(size_m) -> float:
    """Radius of the sphere around the box: its reach in any orientation."""
    return 0.5 * float(np.linalg.norm(size_m))


def uniform_quaternion(rng: np.random.Generator) -> np.ndarray:
    """Uniform random rotation (normalised 4D Gaussian), w >= 0."""
    q = rng.normal(size=4)
    return canonical_quat(q / np.linalg.norm(q))


def half_extents_xy(size_m, rotation: np.ndarray) -> np.ndarray:
    """Half extents of the box's axis-aligned bounding box in x and y."""
    return np.abs(rotation[:2]) @ (0.5 * np.asarray(size_m, float))


def half_height(size_m, quat_wxyz) -> float:
    """Height of the box centre above the box's lowest point, in the given orientation."""
    return 0.5 * float(np.abs(quat_to_matrix(quat_wxyz)[2]) @ np.asarray(size_m, float))


def centre_bounds(recipe: Recipe, size_m) -> tuple[np.ndarray, np.ndarray]:
    """Box of where a box's centre may be in the drop layer: over the support region with the
    whole box inside it whatever its orientation, its lowest point at most `drop.height_m` max
    above the support."""
    r = bounding_radius(size_m)
    hx, hy = recipe.support.half_extent_m
    top = support_top_z(recipe.support)
    lower = np.array([-(hx - r), -(hy - r), top])
    upper = np.array([hx - r, hy - r, top + recipe.drop.height_m[1] + r])
    return lower, upper


def sample_scene(recipe: Recipe, scene_id: int, num_boxes: int | None = None) -> SceneSample:
    """Draws scene `scene_id` of `recipe`; `num_boxes` overrides the recipe's count range."""
    seed = scene_seed(recipe.seed, scene_id)
    # Independent streams, so that (say) a change to material sampling leaves poses unchanged.
    physics_ss, pose_ss, material_ss = np.random.SeedSequence(seed).spawn(3)
    physics, pose_rng, material_rng = (
        np.random.default_rng(s) for s in (physics_ss, pose_ss, material_ss)
    )

    b = recipe.boxes
    n = num_boxes if num_boxes is not None else int(physics.integers(b.count[0], b.count[1] + 1))
    boxes, materials = [], []
    for _ in range(n):
        size = physics.uniform(b.size_min_m, b.size_max_m)
        density = physics.uniform(*b.density_kg_m3)
        friction = physics.uniform(*b.friction)

        quat = uniform_quaternion(pose_rng)
        centre = _place(recipe, size, quat, boxes, pose_rng)
        boxes.append(BoxBody(size, float(density * np.prod(size)), float(friction), quat, centre))
        materials.append(sample_material(recipe, material_rng))
    return SceneSample(scene_id, seed, boxes, materials)


def _place(
    recipe: Recipe, size, quat, placed: list[BoxBody], rng: np.random.Generator
) -> np.ndarray:
    """The centre of a new box: uniform over the region, its lowest point a uniform
    `drop.height_m` gap above the support.

    Random sequential placement: the first of PLACEMENT_CANDIDATES draws that clears every
    placed box (by `min_separation_m`) is taken. When the layer is too crowded for that (twenty
    clutter boxes cover about as much as the region), the box is stacked instead: the candidate
    with the lowest pile under it, dropped with its gap measured from the top of that pile, as
    if the boxes were poured in one after another. Either way the projection starts from a
    non-penetrating guess: from independent draws with deep overlaps, SNOPT solved 0 of 5
    twenty-box clutter scenes (measured).
    """
    rotation = quat_to_matrix(quat)
    lower, upper = centre_bounds(recipe, size)
    lowest_point_offset = half_height(size, quat)
    margin = recipe.drop.min_separation_m
    best, best_base = None, np.inf
    for _ in range(PLACEMENT_CANDIDATES):
        xy = rng.uniform(lower[:2], upper[:2])
        gap = rng.uniform(*recipe.drop.height_m)
        centre = np.array([*xy, lower[2] + gap + lowest_point_offset])
        if all(
            boxes_separated(
                centre,
                rotation,
                size,
                o.translation_m,
                quat_to_matrix(o.quat_wxyz),
                o.size_m,
                margin,
            )
            for o in placed
        ):
            return centre
        base = max(lower[2], _pile_top(xy, half_extents_xy(size, rotation), placed, margin))
        if base < best_base:
            best_base = base
            best = np.array([*xy, base + max(gap, 2 * margin) + lowest_point_offset])
    return best


def _pile_top(xy, half_xy, placed: list[BoxBody], margin: float) -> float:
    """Highest top of the placed boxes whose xy bounding boxes come within `margin` of this
    footprint: a box dropped above it clears them all."""
    top = -np.inf
    for o in placed:
        rotation = quat_to_matrix(o.quat_wxyz)
        if np.all(
            np.abs(np.asarray(o.translation_m[:2]) - xy)
            < half_xy + half_extents_xy(o.size_m, rotation) + margin
        ):
            top = max(top, o.translation_m[2] + half_height(o.size_m, o.quat_wxyz))
    return top


def boxes_separated(ca, Ra, size_a, cb, Rb, size_b, margin: float) -> bool:
    """Separating-axis test for two oriented boxes, with `margin` added to the projected radii:
    True when some axis separates them by at least the margin (so they are that far apart)."""
    ea, eb = 0.5 * np.asarray(size_a), 0.5 * np.asarray(size_b)
    t = np.asarray(cb, float) - np.asarray(ca, float)
    axes = [Ra[:, i] for i in range(3)] + [Rb[:, j] for j in range(3)]
    axes += [np.cross(Ra[:, i], Rb[:, j]) for i in range(3) for j in range(3)]
    for axis in axes:
        norm = np.linalg.norm(axis)
        if norm < 1e-9:  # parallel edges: the face axes already cover this direction
            continue
        axis = axis / norm
        ra = np.abs(Ra.T @ axis) @ ea
        rb = np.abs(Rb.T @ axis) @ eb
        if abs(t @ axis) > ra + rb + margin:
            return True
    return False


def sample_material(recipe: Recipe, rng: np.random.Generator) -> Material:
    m = recipe.materials
    brightness = rng.uniform(0.7, 1.25)
    warmth = rng.uniform(-0.15, 0.15)  # > 0 redder, < 0 yellower
    rgb = CARDBOARD_LINEAR_RGB * brightness * np.array([1 + warmth, 1.0, 1 - warmth])
    return Material(
        base_color_rgb=np.clip(rgb, 0.0, 1.0),
        roughness=float(rng.uniform(*m.roughness)),
        texture_seed=int(rng.integers(0, 2**63 - 1)),
        has_tape=bool(rng.random() < m.tape_probability),
        has_label=bool(rng.random() < m.label_probability),
    )
