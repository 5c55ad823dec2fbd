"""The paper's baselines: Random, Upward and Min-Overlap straight pulls
(``PlanBaseline``), without the LMAP checks and scores. World frame W,
metres, seconds."""
from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.deformation.action import Action, PullDirections
from lmap_drake.planning.approach import IkAndRobotChecks
from lmap_drake.planning.candidates import GraspCandidates
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.result import Candidate, PlanResult


def _BaselineCandidates(ctx: PlanningContext, cfg: PlannerConfig, distance: float,
                        directions: np.ndarray) -> list[tuple]:
    """IK-feasible (grasp, direction) actions at one ``distance``, without
    the LMAP checks. Returns (grasp, Candidate) pairs."""
    grasps, _ = GraspCandidates(ctx.leaf_W, np.zeros((0, 3)), ctx.p_WC, cfg.num_grasps,
                                cfg.grasp_inset, 0.0)
    out = []
    for g in grasps:
        actions = [Action(g.p_WG, g.R_WG, distance * u, grasp_id=g.grasp_id, direction_id=j)
                   for j, u in enumerate(directions)]
        cfg_nocheck = dc.replace(cfg, collision_margin=-np.inf)
        for c in IkAndRobotChecks(ctx, g, cfg_nocheck, actions):
            if c.q_pulled is not None and not c.reason:
                out.append((g, c))
    return out


def PlanBaseline(ctx: PlanningContext, cfg: PlannerConfig, method: str, distance: float,
                 seed: int = 0) -> PlanResult:
    """``random``: uniform over IK-feasible candidates (any grasp, any of the
    14 directions) at ``distance``. ``upward`` / ``min_overlap``: drop
    actions whose robot comes within the margin of visible fruit or branch
    points, take the grasp farthest from the branch, and pull along +z
    (upward) or along the direction whose projected robot overlaps the
    projected leaf least (min_overlap)."""
    t0 = time.perf_counter()
    if ctx.scene.semantic.leaf_points_W.shape[0] < 10:
        return PlanResult("no_feasible_action", method, message="no leaf points")
    if method == "random":
        cands = _BaselineCandidates(ctx, cfg, distance, PullDirections())
        if not cands:
            return PlanResult("no_feasible_action", method, message="no IK-feasible action")
        rng = np.random.default_rng(seed)
        chosen = cands[int(rng.integers(len(cands)))][1]
        return PlanResult("ok", method, chosen=chosen, candidates=[c for _, c in cands],
                          timings={"total_s": time.perf_counter() - t0})
    if method not in ("upward", "min_overlap"):
        raise ValueError(f"unknown baseline {method!r}")
    dirs = np.array([[0.0, 0.0, 1.0]]) if method == "upward" else PullDirections()
    cands = _BaselineCandidates(ctx, cfg, distance, dirs)
    safe = _AwayFromPlantPoints(ctx, cfg, cands)
    if not safe:
        return PlanResult("no_feasible_action", method, candidates=[c for _, c in cands],
                          message="every action comes near visible plant points")
    if len(ctx.branch_obs_W):
        far = lambda g: cKDTree(ctx.branch_obs_W).query(g.p_WG)[0]
    else:
        far = lambda g: 0.0
    best_grasp = max({id(g): g for g, _ in safe}.values(), key=far)
    mine = [c for g, c in safe if g is best_grasp]
    chosen = mine[0] if method == "upward" else _LeastOverlap(ctx, mine)
    return PlanResult("ok", method, chosen=chosen, candidates=[c for _, c in cands],
                      timings={"total_s": time.perf_counter() - t0})


def _AwayFromPlantPoints(ctx: PlanningContext, cfg: PlannerConfig, cands: list[tuple]
                         ) -> list[tuple]:
    """The (grasp, Candidate) pairs whose pulled robot keeps
    ``planner.collision_margin`` from the visible fruit and branch points;
    the others get their reason."""
    plant_pts = np.vstack([ctx.scene.semantic.fruit_points_W, ctx.branch_obs_W])
    tree = cKDTree(plant_pts) if len(plant_pts) else None
    safe = []
    for g, c in cands:
        pts = ctx.robot.SurfacePoints(c.q_pulled)
        if tree is not None and tree.query(pts, distance_upper_bound=cfg.collision_margin)[0].min() \
                < cfg.collision_margin:
            c.reason = "robot near visible plant points"
            continue
        safe.append((g, c))
    return safe


def _LeastOverlap(ctx: PlanningContext, cands: list[Candidate]) -> Candidate:
    """Min-Overlap: the candidate whose pulled robot, projected into the
    camera, overlaps the projected observed leaf least (in pixels)."""
    vis_cam = np.linalg.inv(np.asarray(ctx.X_WC, float))
    f = 300.0

    def pixels(p):
        p_C = p @ vis_cam[:3, :3].T + vis_cam[:3, 3]
        uv = np.round(f * p_C[:, :2] / np.maximum(p_C[:, 2:3], 1e-3)).astype(int)
        return set(map(tuple, uv))
    leaf_pix = pixels(ctx.leaf_W)
    return min(cands, key=lambda c: len(pixels(ctx.robot.SurfacePoints(c.q_pulled)) & leaf_pix))
