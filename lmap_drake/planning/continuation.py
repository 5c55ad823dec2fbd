"""Re-planning from the held leaf: the held grasp after the motions so far
(``HeldGrasp``), the candidates continuing from it, their deformation
predicted on the leaf as observed now, and the selection with the motions'
compounded energy and turn (``PlanContinuation``). World frame W, metres."""
from __future__ import annotations

import dataclasses as dc
import time

import numpy as np

from lmap_drake.deformation.action import (Action, HingeAxes, MakeArcActions,
                                           MakeTwistActions, PullDirections)
from lmap_drake.planning.attachment import AttachLeaf
from lmap_drake.planning.candidates import DirectionsForGrasp
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext, VisibilitySurfaces
from lmap_drake.planning.energy import CompoundEnergyPerNode
from lmap_drake.planning.lmap import PredictLive
from lmap_drake.planning.result import Candidate, CandidateSet, DistanceId, PlanResult
from lmap_drake.planning.robot_checks import MotionChecks
from lmap_drake.planning.selection import SelectFromPredictions
from lmap_drake.planning.visibility import VisibilityModel
from lmap_drake.deformation.config import DeformationConfig


# How far (m) the observed leaf can end from the held grasp point because the
# gripper's pads (2.2 x 3.8 cm) hide it from the camera.
HELD_LEAF_HIDDEN = 0.02


@dc.dataclass
class HeldGrasp:
    """The leaf as the gripper holds it after ``motions`` executed motions:
    the first grasp pose (``p_WG0``, ``R_WG0``), the current TCP pose
    (``p_WG``, ``R_WG``, the last motion's planned end), the hinge the arcs
    swing about, and the predicted ARAP energy per leaf node of the motions
    so far (compounded, ``CompoundEnergyPerNode``: each continuation's
    energy is predicted from the leaf as observed before it; the petiole
    bending term is computed on the total turn from the first grasp)."""
    p_WG0: np.ndarray
    R_WG0: np.ndarray
    p_WG: np.ndarray
    R_WG: np.ndarray
    hinge_W: np.ndarray | None
    motions: int
    energy_per_node: float
    twist_rad: float = 0.0     # the executed twists' summed angle (rad)
    families: tuple = ()       # the executed motions' families, in order
    hinge_error_m: float | None = None  # m: how far the true attachment may be from hinge_W

    @staticmethod
    def After(plans: list) -> "HeldGrasp":
        """The held state after executing each plan's chosen action in turn
        (``plans[0]`` grasped the leaf)."""
        first, last = plans[0].chosen.action, plans[-1].chosen.action
        e = 0.0
        for p in plans:
            if np.isfinite(p.chosen.arap_energy):
                e = CompoundEnergyPerNode(e, p.chosen.arap_energy
                                          / max(1, p.chosen.num_leaf_nodes))
        twist = sum(abs(p.chosen.action.angle) for p in plans
                    if p.chosen.action.family == "twist")
        return HeldGrasp(first.p_WG, first.R_WG, last.p_WG + last.dp_W, last.R_WG_end,
                         plans[0].hinge_W, len(plans), e, twist,
                         tuple(p.chosen.action.family for p in plans),
                         plans[0].hinge_error_m)


def GenerateContinuation(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                         held: HeldGrasp) -> CandidateSet:
    """Candidates continuing from the held leaf (``ctx.scene``: the fused
    re-estimate, its leaf from the newest view; ``ctx.q_current``: the
    joints holding it): pulls and arcs from the current TCP pose, IK and
    robot checks from the current joints; the visibility now counts the
    robot as an occluder (it holds the leaf in front of the camera)."""
    timings = {"generation_collision_s": 0.0, "visibility_s": 0.0}
    if ctx.scene.fruit is None or len(ctx.scene.fruit.faces) == 0:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="no fruit estimate: nothing to reveal")
    t0 = time.perf_counter()
    vis = VisibilityModel(ctx.X_WC, VisibilitySurfaces(ctx.scene.fruit, cfg.visibility_shapes),
                          cfg.visibility_voxel, ctx.image_tan)
    seen_init = vis.Seen(np.vstack([ctx.leaf_W, ctx.occluders_W,
                                    ctx.robot.SurfacePoints(ctx.q_current)]))
    timings["visibility_s"] += time.perf_counter() - t0
    out = CandidateSet("ok", ctx.scene, visibility=vis, seen_init_mask=seen_init,
                       timings=timings, hinge_W=held.hinge_W,
                       hinge_error_m=held.hinge_error_m)
    n_init, n_max = vis.Count(seen_init), vis.Count(vis.max_seen)
    if n_max == 0:
        out.status, out.message = "no_fruit", "the fruit estimate is outside camera0's view"
        return out
    if n_init >= cfg.early_stop_fraction * n_max:
        out.status = "no_action_needed"
        out.message = f"fruit already {n_init / n_max:.0%} visible (predicted)"
        return out
    if len(ctx.leaf_W) < 10:
        out.status, out.message = "no_feasible_action", "the held leaf is not seen"
        return out
    t0 = time.perf_counter()
    p, R = held.p_WG, held.R_WG
    actions = []
    families = [f for f in cfg.action_families if f in cfg.continuation_families]
    if "pull" in families:
        dirs, ids = DirectionsForGrasp(p, ctx.branch_all_W, cfg.max_branch_angle_deg,
                                       PullDirections()[:cfg.num_directions])
        actions += [Action(p, R, s * u, grasp_id=0, direction_id=int(j))
                    for u, j in zip(dirs, ids) for s in cfg.distances]
    if held.hinge_W is not None and np.linalg.norm(p - held.hinge_W) > 0.02:
        if "arc" in families:
            actions += MakeArcActions(p, R, held.hinge_W, HingeAxes(p, held.hinge_W,
                                                                    cfg.num_arc_axes),
                                      np.deg2rad(np.asarray(cfg.arc_angles_deg, float)),
                                      grasp_id=0)
        if "twist" in families:
            actions += MakeTwistActions(p, R, held.hinge_W,
                                        np.deg2rad(np.asarray(cfg.twist_angles_deg, float)),
                                        grasp_id=0)
    cands = [Candidate(a, DistanceId(a, cfg)) for a in actions]
    out.candidates = MotionChecks(ctx, cfg, cands, np.asarray(ctx.q_current, float))
    timings["generation_collision_s"] += time.perf_counter() - t0
    out.scene, msg = AttachLeaf(ctx.scene, dcfg)
    out.message = msg
    return out


def PlanContinuation(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                     held: HeldGrasp, progress=None) -> PlanResult:
    """A further motion from the held leaf (``GenerateContinuation``), its
    deformation predicted on the leaf as observed now (the graph continues
    from the observed deformed leaf, the gripper as its handle), selected
    as the first motion is, with the energy cap applied to the motions'
    compounded energy per node (``CompoundEnergyPerNode``). Never raises on
    a bad scene."""
    progress = progress or (lambda m: None)
    if "pull" in held.families and not cfg.continue_after_pull:
        result = PlanResult("no_feasible_action", cfg.method,
                            message="no further motion after a straight pull "
                                    "(planner.continue_after_pull: false)")
        progress(f"continuation: {result.status} ({result.message})")
        return result
    # The pads hide the held leaf around the grasp from the camera: the
    # nearest observed leaf point can be up to about half a pad away.
    dcfg = dc.replace(dcfg, max_grasp_distance=dcfg.max_grasp_distance + HELD_LEAF_HIDDEN)
    cset = GenerateContinuation(ctx, cfg, dcfg, held)
    predictions = PredictLive(ctx, cset, dcfg)
    result = SelectFromPredictions(ctx, cset, predictions, cfg,
                                   energy_offset_per_node=held.energy_per_node,
                                   hinge_reference_W=held.p_WG0,
                                   min_gain=cfg.min_replan_gain,
                                   twist_offset_rad=held.twist_rad,
                                   rotation_reference=held.R_WG0)
    result.timings["total_s"] = sum(v for k, v in result.timings.items() if k != "total_s")
    progress(f"continuation: {result.status}" + (f" ({result.message})" if result.message else ""))
    return result
