"""Non-penetration projection (paper, step 1): move the sampled drop poses to the nearest
configuration where every pair of bodies, support included, is at least `min_separation_m`
apart, with every box still over the support region and inside the drop layer.

A nonlinear program over the boxes' free-body positions q (per box: unit quaternion, then
translation):  min (q − q_sampled)ᵀ W (q − q_sampled)  s.t.  signed distances ≥ min_separation,
‖quaternion‖ = 1, centre bounds. Solved with SNOPT, IPOPT as the fallback, and retried from
jittered initial guesses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.multibody.inverse_kinematics import (
    AddUnitQuaternionConstraintOnPlant,
    InverseKinematics,
    UnitQuaternionConstraint,
)
from pydrake.solvers import IpoptSolver, SnoptSolver, SolverOptions

from drake_scenes.plant import BoxBody, build_scene_plant, canonical_quat, min_signed_distance
from drake_scenes.recipe import Recipe
from drake_scenes.sampling import centre_bounds

# Cost weights on (q − q_sampled)². Unit weights: weighting translation 10× or 100× more (to
# prefer sliding a box over turning it) made SNOPT stall (info 41) on 1 resp. 4 of 10 tiny
# scenes that it solved with unit weights (measured).
TRANSLATION_WEIGHT_PER_M2 = 1.0
QUATERNION_WEIGHT = 1.0
# Signed distances within this influence margin of the bound enter the constraint (Drake's
# MinimumDistanceLowerBoundConstraint smooths over it).
INFLUENCE_DISTANCE_OFFSET_M = 0.01
# Constraint violation allowed when checking a solver's point (quaternion norm, bounds, the
# smoothed distance penalty).
FEASIBILITY_TOLERANCE = 1e-6
# A solution is only accepted if the independently recomputed distance is this close to the bound.
ACCEPT_TOLERANCE_M = 1e-4
# Jitter of retry k: translation σ = k × this (m), quaternion σ = k × JITTER_QUATERNION.
JITTER_TRANSLATION_M = 0.02
JITTER_QUATERNION = 0.1

SOLVER_FAILURE = "solver failure"


@dataclass
class ProjectionResult:
    success: bool
    boxes: list[BoxBody]  # projected poses (the sampled ones when success is False)
    solver: str  # "SNOPT" or "IPOPT": the one that succeeded, else the last tried
    status: str  # solver result and solver-specific code
    attempts: int
    min_signed_distance_m: float


def _solver_options() -> SolverOptions:
    """Options that make runs reproducible and bounded: no timing-dependent stopping rules."""
    options = SolverOptions()
    snopt, ipopt = SnoptSolver.id(), IpoptSolver.id()
    options.SetOption(snopt, "Major iterations limit", 1000)
    options.SetOption(snopt, "Iterations limit", 100000)
    options.SetOption(snopt, "Major feasibility tolerance", 1e-6)
    options.SetOption(snopt, "Major optimality tolerance", 1e-5)
    options.SetOption(ipopt, "max_iter", 500)
    options.SetOption(ipopt, "tol", 1e-6)
    options.SetOption(ipopt, "print_level", 0)
    options.SetOption(ipopt, "max_cpu_time", 1e20)  # no wall-clock dependence
    return options


def _status(result) -> str:
    details = result.get_solver_details()
    code = f"info {details.info}" if hasattr(details, "info") else f"status {details.status}"
    return f"{result.get_solution_result().name} ({code})"


def project(
    boxes: list[BoxBody], recipe: Recipe, jitter_rng: np.random.Generator
) -> ProjectionResult:
    """Projects the sampled poses of `boxes`; retries up to `drop.max_solve_attempts` times."""
    scene = build_scene_plant(boxes, recipe.support)
    plant = scene.plant
    root_context = scene.new_context(boxes)
    plant_context = plant.GetMyMutableContextFromRoot(root_context)

    # with_joint_limits=False: free bodies have no joint limits; our bounds are added below.
    ik = InverseKinematics(plant, plant_context, with_joint_limits=False)
    prog, q = ik.get_mutable_prog(), ik.q()
    # InverseKinematics already constrains every free body's quaternion to unit norm; add them
    # ourselves should a Drake version stop doing so (never twice: duplicates slow SNOPT down).
    if sum(
        isinstance(b.evaluator(), UnitQuaternionConstraint) for b in prog.GetAllConstraints()
    ) < len(boxes):
        AddUnitQuaternionConstraintOnPlant(plant, q, prog)
    ik.AddMinimumDistanceLowerBoundConstraint(
        recipe.drop.min_separation_m, INFLUENCE_DISTANCE_OFFSET_M
    )

    q_sampled = plant.GetPositions(plant_context).copy()
    weights = np.ones(plant.num_positions())
    for body, box in zip(scene.bodies, boxes, strict=True):
        start = body.floating_positions_start()
        weights[start : start + 4] = QUATERNION_WEIGHT
        weights[start + 4 : start + 7] = TRANSLATION_WEIGHT_PER_M2
        lower, upper = centre_bounds(recipe, box.size_m)
        # A box stacked by the sampler may start above the drop layer: never push it higher.
        upper[2] = max(upper[2], box.translation_m[2])
        prog.AddBoundingBoxConstraint(lower, upper, q[start + 4 : start + 7])
        # Unit quaternion components lie in [-1, 1]; bounding them keeps IPOPT (an interior-point
        # method that warns about unbounded variables) from wandering.
        prog.AddBoundingBoxConstraint(-np.ones(4), np.ones(4), q[start : start + 4])
    prog.AddQuadraticErrorCost(np.diag(weights), q_sampled, q)

    options = _solver_options()
    solvers = [("SNOPT", SnoptSolver()), ("IPOPT", IpoptSolver())]
    bound = recipe.drop.min_separation_m
    solver_name, status, distance = "SNOPT", "not solved", -np.inf
    for attempt in range(1, recipe.drop.max_solve_attempts + 1):
        guess = q_sampled if attempt == 1 else _jittered(q_sampled, scene, attempt - 1, jitter_rng)
        for solver_name, solver in solvers:
            result = solver.Solve(prog, guess, options)
            status = _status(result)
            x = result.GetSolution(q)
            # Accept what verifiably satisfies every constraint. SNOPT often ends with info 41
            # ("current point cannot be improved") on a feasible point a hair from optimal: that
            # is a valid non-penetrating drop pose, and the status string keeps the distinction.
            if not prog.CheckSatisfied(prog.GetAllConstraints(), x, FEASIBILITY_TOLERANCE):
                continue
            projected = _with_positions(boxes, scene, x)
            scene.set_poses(plant_context, projected)
            distance = min_signed_distance(scene, root_context)
            if distance >= bound - ACCEPT_TOLERANCE_M:
                if not result.is_success():
                    status += ", feasible point accepted"
                return ProjectionResult(True, projected, solver_name, status, attempt, distance)
            status += f", but min distance {distance:.2e} m"
    return ProjectionResult(
        False, boxes, solver_name, status, recipe.drop.max_solve_attempts, distance
    )


def _jittered(q: np.ndarray, scene, scale: int, rng: np.random.Generator) -> np.ndarray:
    q = q.copy()
    for body in scene.bodies:
        start = body.floating_positions_start()
        quat = q[start : start + 4] + rng.normal(0, JITTER_QUATERNION * scale, 4)
        q[start : start + 4] = quat / np.linalg.norm(quat)
        q[start + 4 : start + 7] += rng.normal(0, JITTER_TRANSLATION_M * scale, 3)
    return q


def _with_positions(boxes: list[BoxBody], scene, q: np.ndarray) -> list[BoxBody]:
    out = []
    for body, box in zip(scene.bodies, boxes, strict=True):
        start = body.floating_positions_start()
        quat = q[start : start + 4] / np.linalg.norm(q[start : start + 4])
        out.append(
            BoxBody(
                box.size_m,
                box.mass_kg,
                box.friction,
                canonical_quat(quat),
                q[start + 4 : start + 7].copy(),
            )
        )
    return out
