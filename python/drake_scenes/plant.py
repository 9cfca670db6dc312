"""The physical scene as a Drake MultibodyPlant: a welded support and free-floating boxes.

Shared by the non-penetration projection (geometry only) and the drop-and-settle simulation.
World frame: z up, the support region is the rectangle |x| <= hx, |y| <= hy centred on the
origin, and boxes rest on the support's top surface at z = `support_top_z(spec)`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    Box,
    ProximityProperties,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (
    AddMultibodyPlantSceneGraph,
    ApplyMultibodyPlantConfig,
    CoulombFriction,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import RigidBody, SpatialInertia
from pydrake.systems.framework import Context, Diagram, DiagramBuilder

from boxpose_io import BIN_WALL_THICKNESS_M, PALLET_HEIGHT_M, SUPPORT_FRICTION
from drake_scenes.recipe import SupportSpec

# The ground is a thick box, not a HalfSpace: Drake has no Box–HalfSpace signed distance, which
# the projection's minimum-distance constraint and the certificate both need (docs/design.md,
# "Toolchain facts").
GROUND_THICKNESS_M = 0.2
# The ground reaches this far beyond the support region, so that a box that slides out of the
# region stays on it and is rejected by the region check instead of falling forever.
GROUND_MARGIN_M = 1.0
# Bin wall thickness, pallet height (a pallet is a slab exactly the size of the support region)
# and support friction are the dataset contract's (rust/data/src/support.rs, via schema.json);
# the boxes' own friction comes from the recipe (Drake combines the two).

# Contact: hydroelastic with compliant boxes gives area contact between flat faces, so stacked
# and resting boxes sit still; point contact (one point per box pair) makes them rock.
# Modulus: a box resting on an edge sinks in until the pressure carries its weight. Measured on
# six 5-box clutter drops: 1e7 Pa let boxes sink up to 1.1 mm (and 2.8 mm in a 20-box pile, over
# the recipes' 2 mm limit); 3e7 Pa kept them under 0.22 mm and settled as fast.
BOX_HYDROELASTIC_MODULUS_PA = 3e7
# Hunt–Crossley dissipation: high enough that drops do not bounce for long.
HUNT_CROSSLEY_DISSIPATION_S_PER_M = 5.0


@dataclass
class BoxBody:
    """What the physics needs of one box; poses are T_world_box (quaternion w, x, y, z)."""

    size_m: np.ndarray  # (3,)
    mass_kg: float
    friction: float
    quat_wxyz: np.ndarray  # (4,)
    translation_m: np.ndarray  # (3,)


@dataclass
class ScenePlant:
    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    bodies: list[RigidBody]  # one per box, in object_id order

    def new_context(self, boxes: list[BoxBody]) -> Context:
        """A diagram context with every box at its pose in `boxes`, at rest."""
        context = self.diagram.CreateDefaultContext()
        self.set_poses(self.plant.GetMyMutableContextFromRoot(context), boxes)
        return context

    def set_poses(self, plant_context: Context, boxes: list[BoxBody]) -> None:
        for body, box in zip(self.bodies, boxes, strict=True):
            pose = RigidTransform(
                Quaternion(normalized(box.quat_wxyz)), np.asarray(box.translation_m, float)
            )
            self.plant.SetFreeBodyPose(plant_context, body, pose)

    def poses(self, plant_context: Context) -> list[tuple[np.ndarray, np.ndarray]]:
        """(quat_wxyz, translation_m) of every box, the quaternion with w >= 0."""
        out = []
        for body in self.bodies:
            pose = self.plant.EvalBodyPoseInWorld(plant_context, body)
            out.append(
                (canonical_quat(pose.rotation().ToQuaternion().wxyz()), pose.translation().copy())
            )
        return out


def normalized(q) -> Quaternion:
    q = np.asarray(q, float)
    return q / np.linalg.norm(q)


def canonical_quat(q: np.ndarray) -> np.ndarray:
    """q and -q are the same rotation; store the one with w >= 0 so rows compare exactly."""
    q = np.asarray(q, float)
    return -q if q[0] < 0 else q.copy()


def support_top_z(spec: SupportSpec) -> float:
    return PALLET_HEIGHT_M if spec.kind == "pallet" else 0.0


def support_boxes(spec: SupportSpec) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The support as (name, size, centre) boxes welded to the world."""
    hx, hy = spec.half_extent_m
    t = GROUND_THICKNESS_M
    parts = [
        (
            "ground",
            np.array([2 * (hx + GROUND_MARGIN_M), 2 * (hy + GROUND_MARGIN_M), t]),
            np.array([0, 0, -t / 2]),
        ),
    ]
    if spec.kind == "bin":
        h, w = spec.wall_height_m, BIN_WALL_THICKNESS_M
        # Inner faces on the region's edges; walls along x overlap the corners.
        parts += [
            ("wall_+x", np.array([w, 2 * (hy + w), h]), np.array([hx + w / 2, 0, h / 2])),
            ("wall_-x", np.array([w, 2 * (hy + w), h]), np.array([-hx - w / 2, 0, h / 2])),
            ("wall_+y", np.array([2 * hx, w, h]), np.array([0, hy + w / 2, h / 2])),
            ("wall_-y", np.array([2 * hx, w, h]), np.array([0, -hy - w / 2, h / 2])),
        ]
    elif spec.kind == "pallet":
        p = PALLET_HEIGHT_M
        parts.append(("pallet", np.array([2 * hx, 2 * hy, p]), np.array([0, 0, p / 2])))
    return parts


def build_scene_plant(
    boxes: list[BoxBody], support: SupportSpec, time_step_s: float = 0.0
) -> ScenePlant:
    """A plant with `support` welded to the world and one free body per box (not yet posed).

    `time_step_s` 0 gives a continuous plant (enough for geometry queries); the settle
    simulation passes the recipe's step for a discrete (SAP) plant.
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step_s)
    if time_step_s > 0:
        ApplyMultibodyPlantConfig(
            MultibodyPlantConfig(
                time_step=time_step_s,
                contact_model="hydroelastic_with_fallback",
                discrete_contact_approximation="sap",
            ),
            plant,
        )

    for name, size, centre in support_boxes(support):
        props = ProximityProperties()
        AddContactMaterial(
            dissipation=HUNT_CROSSLEY_DISSIPATION_S_PER_M,
            friction=CoulombFriction(SUPPORT_FRICTION, SUPPORT_FRICTION),
            properties=props,
        )
        AddRigidHydroelasticProperties(props)
        plant.RegisterCollisionGeometry(
            plant.world_body(), RigidTransform(centre), Box(*size), name, props
        )

    bodies = []
    for i, box in enumerate(boxes):
        size = np.asarray(box.size_m, float)
        body = plant.AddRigidBody(f"box_{i}", SpatialInertia.SolidBoxWithMass(box.mass_kg, *size))
        props = ProximityProperties()
        AddContactMaterial(
            dissipation=HUNT_CROSSLEY_DISSIPATION_S_PER_M,
            friction=CoulombFriction(box.friction, box.friction),
            properties=props,
        )
        AddCompliantHydroelasticProperties(float(size.min()), BOX_HYDROELASTIC_MODULUS_PA, props)
        plant.RegisterCollisionGeometry(body, RigidTransform(), Box(*size), f"box_{i}", props)
        bodies.append(body)

    plant.Finalize()
    return ScenePlant(builder.Build(), plant, scene_graph, bodies)


def min_signed_distance(scene: ScenePlant, context: Context) -> float:
    """Smallest signed distance over every pair of bodies the plant lets collide (support
    included); negative is penetration. +inf when there is no pair."""
    query = scene.plant.get_geometry_query_input_port().Eval(
        scene.plant.GetMyContextFromRoot(context)
    )
    pairs = query.ComputeSignedDistancePairwiseClosestPoints(np.inf)
    return min((p.distance for p in pairs), default=np.inf)
