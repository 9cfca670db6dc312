"""Drop and settle: simulate the projected scene until every box is at rest, and certify it.

`settle(boxes, recipe)` is also the entry point for benchmarks against other simulators
(see `python -m drake_scenes.bench_settle`).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus

from drake_scenes.plant import BoxBody, build_scene_plant, min_signed_distance, support_top_z
from drake_scenes.recipe import Recipe

# Rejection reasons, as counted in the generation summary.
NOT_SETTLED = "not settled in time"
PENETRATION = "penetration"
LEFT_SUPPORT = "box left the support region"


@dataclass
class Certificate:
    """Evidence that a settled scene is statically stable (columns of the `scenes` table)."""

    settle_time_s: float  # simulated time at which the rest window was complete
    max_linear_speed_mps: float  # largest body speed over the final window
    max_angular_speed_radps: float
    min_signed_distance_m: float  # between any two bodies, support included
    stable: bool
    rejection: str | None = None  # why not stable


@dataclass
class SettleResult:
    poses: list[tuple[np.ndarray, np.ndarray]]  # settled (quat_wxyz, translation_m) per box
    certificate: Certificate
    wall_time_s: float  # plant construction and simulation, on this machine
    simulated_steps: int = field(default=0)


class _RestMonitor:
    """Called by the simulator after every step: tracks box speeds and stops the simulation
    once every box has stayed under the thresholds for a whole window."""

    def __init__(self, scene, recipe: Recipe):
        s = recipe.settle
        self.plant = scene.plant
        self.window_s, self.max_v, self.max_w = (
            s.window_s,
            s.max_linear_speed_mps,
            s.max_angular_speed_radps,
        )
        # Generalized velocity of a free body: angular then linear velocity, both in world.
        starts = np.array([b.floating_velocities_start_in_v() for b in scene.bodies], dtype=int)
        self.angular_idx = starts[:, None] + np.arange(3)
        self.linear_idx = starts[:, None] + np.arange(3, 6)
        self.history: deque[tuple[float, float, float]] = deque()  # (t, max |v|, max |w|)
        self.rest_since: float | None = None
        self.steps = 0

    def __call__(self, root_context):
        t = root_context.get_time()
        v = self.plant.GetVelocities(self.plant.GetMyContextFromRoot(root_context))
        linear = float(np.linalg.norm(v[self.linear_idx], axis=1).max())
        angular = float(np.linalg.norm(v[self.angular_idx], axis=1).max())
        self.steps += 1
        self.history.append((t, linear, angular))
        while self.history[0][0] < t - self.window_s:
            self.history.popleft()
        if linear > self.max_v or angular > self.max_w:
            self.rest_since = None
        elif self.rest_since is None:
            self.rest_since = t
        return (
            EventStatus.ReachedTermination(None, "at rest")
            if self.at_rest
            else EventStatus.DidNothing()
        )

    @property
    def at_rest(self) -> bool:
        # rest_since > 0: the boxes start at rest (v = 0) before they fall; that does not count.
        return bool(self.rest_since) and self.history[-1][0] - self.rest_since >= self.window_s

    def window_max(self) -> tuple[float, float]:
        return max(h[1] for h in self.history), max(h[2] for h in self.history)


def as_box_body(obj) -> BoxBody:
    """A BoxBody from a BoxBody or from a row of the `objects` table (a dict or pandas row with
    size_m, mass_kg, friction, initial_world_box_quat_wxyz, initial_world_box_translation_m)."""
    if isinstance(obj, BoxBody):
        return obj
    return BoxBody(
        size_m=np.asarray(obj["size_m"], float),
        mass_kg=float(obj["mass_kg"]),
        friction=float(obj["friction"]),
        quat_wxyz=np.asarray(obj["initial_world_box_quat_wxyz"], float),
        translation_m=np.asarray(obj["initial_world_box_translation_m"], float),
    )


def settle(objects, recipe: Recipe | str) -> SettleResult:
    """Drops `objects` on the recipe's support and simulates until they are at rest or
    `settle.max_time_s` has passed; returns the settled poses, the certificate and the wall time.

    `objects`: BoxBody items, or `objects` table rows (initial pose = initial_world_box_*).
    `recipe`: a Recipe or the path of a recipe TOML (support, [settle] thresholds, time step).
    The poses should be non-penetrating (projection.project), as in a generated dataset.
    """
    recipe = recipe if isinstance(recipe, Recipe) else Recipe.load(recipe)
    boxes = [as_box_body(o) for o in objects]
    start = time.perf_counter()
    scene = build_scene_plant(boxes, recipe.support, recipe.settle.time_step_s)
    context = scene.new_context(boxes)
    simulator = Simulator(scene.diagram, context)
    monitor = _RestMonitor(scene, recipe)
    simulator.set_monitor(monitor)
    simulator.Initialize()
    simulator.AdvanceTo(recipe.settle.max_time_s)

    plant_context = scene.plant.GetMyContextFromRoot(context)
    poses = scene.poses(plant_context)
    max_v, max_w = monitor.window_max()
    certificate = Certificate(
        settle_time_s=context.get_time(),
        max_linear_speed_mps=max_v,
        max_angular_speed_radps=max_w,
        min_signed_distance_m=min_signed_distance(scene, context),
        stable=True,
    )
    certificate.rejection = _rejection(recipe, poses, certificate, monitor.at_rest)
    certificate.stable = certificate.rejection is None
    return SettleResult(poses, certificate, time.perf_counter() - start, monitor.steps)


def _rejection(recipe: Recipe, poses, cert: Certificate, at_rest: bool) -> str | None:
    s = recipe.settle
    if (
        not at_rest
        or cert.max_linear_speed_mps > s.max_linear_speed_mps
        or cert.max_angular_speed_radps > s.max_angular_speed_radps
    ):
        return NOT_SETTLED
    if cert.min_signed_distance_m < -s.max_penetration_m:
        return PENETRATION
    hx, hy = recipe.support.half_extent_m
    top = support_top_z(recipe.support)
    for _, translation in poses:
        x, y, z = translation
        # The centre must still be over the region and above the support surface.
        if abs(x) > hx or abs(y) > hy or z < top:
            return LEFT_SUPPORT
    return None
