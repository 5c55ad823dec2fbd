"""LMAP action candidates (paper Sec. III-C-1): grasp points on the convex
hull of the PCA-projected leaf, moved inward; gripper orientation from the
leaf normal; the 14 pull directions filtered by the branch-angle rule; each
grasp's motions (pulls, arcs, twists). Stage 1 (``GenerateCandidates``):
the grasp set with its IK and robot checks, retried with other gripper
orientations, grasps nearer the branch and deeper inside the blade when too
few pass, and the initial visibility. World frame W, metres."""
from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from lmap_drake.deformation.action import (Action, AxisAngleMatrix, HingeAxes, MakeArcActions,
                                           MakeTwistActions, PullDirections)
from lmap_drake.planning.approach import GraspApproach, GraspSurelyBlocked, IkAndRobotChecks
from lmap_drake.planning.attachment import AttachLeaf, EstimateHinge, UnseenPetiole
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext, SurfacesOf
from lmap_drake.planning.energy import MEASURED_PULL_MAX, LeverPullDistance
from lmap_drake.planning.result import Candidate, CandidateSet
from lmap_drake.planning.visibility import VisibilityModel
from lmap_drake.deformation.config import DeformationConfig


class PlanningError(ValueError):
    """The planner cannot work on this input (e.g. too few leaf points)."""


@dc.dataclass
class LeafFrame:
    """PCA frame of the leaf points: ``center`` (3), ``axes`` (3x3, columns:
    major, minor, normal), the normal pointing toward the camera."""
    center: np.ndarray
    axes: np.ndarray

    def To2d(self, p_W: np.ndarray) -> np.ndarray:
        return (p_W - self.center) @ self.axes[:, :2]


def LeafPca(leaf_points_W: np.ndarray, p_WC: np.ndarray) -> LeafFrame:
    if len(leaf_points_W) < 10:
        raise PlanningError(f"need at least 10 leaf points, got {len(leaf_points_W)}")
    c = leaf_points_W.mean(axis=0)
    _, _, Vt = np.linalg.svd(leaf_points_W - c, full_matrices=False)
    axes = Vt.T.copy()
    if axes[:, 2] @ (p_WC - c) < 0:
        axes[:, 2] *= -1
    axes[:, 1] = np.cross(axes[:, 2], axes[:, 0])
    return LeafFrame(c, axes)


@dc.dataclass
class Grasp:
    """A grasp pose: TCP at ``p_WG`` with orientation ``R_WG`` (columns x, y,
    z: pads' width direction, closing direction = leaf normal, approach =
    inward along the leaf)."""
    p_WG: np.ndarray
    R_WG: np.ndarray
    grasp_id: int


def GraspCandidates(leaf_points_W: np.ndarray, branch_points_W: np.ndarray,
                    p_WC: np.ndarray, num_grasps: int = 15, inset: float = 0.01,
                    min_branch_distance: float = 0.06) -> tuple[list[Grasp], list[dict]]:
    """``num_grasps`` points evenly spaced along the perimeter of the convex
    hull of the PCA-projected leaf, moved ``inset`` inward. Grasps within
    ``min_branch_distance`` of a branch point are dropped (recorded)."""
    frame = LeafPca(leaf_points_W, p_WC)
    uv = frame.To2d(leaf_points_W)
    hull = ConvexHull(uv)
    poly = uv[hull.vertices]
    seg = np.roll(poly, -1, axis=0) - poly
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.r_[0, np.cumsum(seg_len)]
    targets = (np.arange(num_grasps) + 0.5) / num_grasps * cum[-1]
    tree = cKDTree(uv)
    branch_tree = cKDTree(branch_points_W) if len(branch_points_W) else None
    grasps, dropped = [], []
    center2 = poly.mean(axis=0)
    for k, s in enumerate(targets):
        i = int(np.searchsorted(cum, s, side="right") - 1)
        i = min(i, len(poly) - 1)
        p2 = poly[i] + seg[i] * (s - cum[i]) / max(seg_len[i], 1e-12)
        n_out = np.array([seg[i, 1], -seg[i, 0]]) / max(seg_len[i], 1e-12)
        if n_out @ (p2 - center2) < 0:
            n_out = -n_out
        q2 = p2 - inset * n_out
        # lift to 3D: mean of the nearest leaf points around the inset point
        _, idx = tree.query(q2, k=min(8, len(uv)))
        p_W = leaf_points_W[np.atleast_1d(idx)].mean(axis=0)
        if branch_tree is not None and branch_tree.query(p_W)[0] < min_branch_distance:
            dropped.append({"grasp_id": k, "reason": "within "
                            f"{min_branch_distance * 100:.0f} cm of the branch"})
            continue
        # Pads close across the leaf where it is grasped: the local normal
        # (PCA of the leaf points within 2 cm), approach inward in that plane.
        y = _LocalNormal(leaf_points_W, p_W, frame.axes[:, 2])
        z = -(frame.axes[:, :2] @ n_out)
        z = z - (z @ y) * y
        z /= np.linalg.norm(z)
        x = np.cross(y, z)
        grasps.append(Grasp(p_W, np.c_[x, y, z], k))
    return grasps, dropped


def _LocalNormal(points: np.ndarray, p: np.ndarray, toward: np.ndarray,
                 radius: float = 0.02) -> np.ndarray:
    """Unit normal of the points within ``radius`` of ``p`` (least-variance
    direction), oriented like ``toward``; ``toward`` if too few points."""
    near = points[np.linalg.norm(points - p, axis=1) < radius]
    if len(near) < 8:
        return toward
    _, _, Vt = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)
    n = Vt[2]
    return n if n @ toward >= 0 else -n


def DirectionsForGrasp(p_WG: np.ndarray, branch_points_W: np.ndarray,
                       max_angle_deg: float = 120.0,
                       directions: np.ndarray | None = None, tree=None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The pull directions (and their indices into ``PullDirections()``) whose
    angle to the line from the grasp point to the nearest branch point is
    below ``max_angle_deg``: the leaf is not pulled away from its branch.
    ``tree``: a ``cKDTree`` of ``branch_points_W``, when already built."""
    D = PullDirections() if directions is None else np.asarray(directions, float)
    if len(branch_points_W) == 0:
        return D, np.arange(len(D))
    tree = cKDTree(branch_points_W) if tree is None else tree
    nearest = branch_points_W[tree.query(p_WG)[1]]
    to_branch = nearest - p_WG
    to_branch /= max(np.linalg.norm(to_branch), 1e-12)
    keep = np.flatnonzero(D @ to_branch > np.cos(np.deg2rad(max_angle_deg)))
    return D[keep], keep


# Second-chance grasp orientations: the approach turned by these angles
# (deg) about the pads' closing axis, i.e. within the blade's plane, still
# crossing the leaf's edge; each also turned 180 deg about the approach axis.
# 70 deg comes in nearly from the leaf's side: for leaves on the far side of
# a plant that point away from the robot, whose approach from beyond the
# edge the arm cannot reach (four_fruits: a fruit 0.44 -> 0.98 visible).
APPROACH_TILTS_DEG = (0.0, 35.0, -35.0, 70.0, -70.0)


def GraspAlternatives(R_WG: np.ndarray) -> list[np.ndarray]:
    """Other gripper orientations for a grasp whose own approach failed, pads
    still closing across the leaf (G's y axis along the leaf normal): the
    2F-85 turned 180 deg about its approach axis (it is symmetric; the wrist
    then sits the other way), and the approach tilted by
    ``APPROACH_TILTS_DEG`` in the blade's plane (about G's y axis)."""
    R_WG = np.asarray(R_WG, float)
    out = []
    for tilt in APPROACH_TILTS_DEG:
        R = R_WG @ AxisAngleMatrix([0.0, 1.0, 0.0], np.deg2rad(tilt))
        out += [R, R @ np.diag([-1.0, -1.0, 1.0])]
    return out[1:]                      # not the orientation already tried


def AlternativeLabels() -> list[tuple]:
    """(tilt deg, turned 180 deg) of each ``GraspAlternatives`` rotation."""
    return [(float(t), turned) for t in APPROACH_TILTS_DEG for turned in (False, True)][1:]


# Grasp ids of the deeper grasp sets: DEEPER_GRASP_IDS x (k + 1) + i for the
# i-th grasp of the k-th of ``planner.deeper_grasp_insets``.
DEEPER_GRASP_IDS = 100


def PullDistances(cfg: PlannerConfig, p_WG: np.ndarray, hinge_W: np.ndarray | None
                  ) -> list[float]:
    """The straight pulls' distances (m) from grasp ``p_WG``:
    ``planner.distances`` and, when it falls between two of them and at
    least 5 mm from each, the longest pull the grasp's lever allows
    (``LeverPullDistance``, floored to the millimetre; not past
    ``MEASURED_PULL_MAX``, the ceiling of ``MaxPullDistance``). Without it a grasp
    whose cap is 4.7 cm stopped at the 4 cm pull: in ``four_fruits`` 0.71 of
    its fruit predicted, 0.91 at the 6 cm the cap refused."""
    ds = sorted(float(d) for d in cfg.distances)
    cap = LeverPullDistance(cfg, p_WG, hinge_W)
    if ds and np.isfinite(cap) and cap <= MEASURED_PULL_MAX:
        cap = float(np.floor(cap * 1000.0)) / 1000.0
        if ds[0] < cap < ds[-1] and min(abs(cap - d) for d in ds) >= 0.005:
            ds = sorted(ds + [cap])
    return ds


def GraspActions(ctx: PlanningContext, cfg: PlannerConfig, g, pivot, angles, all_dirs
                 ) -> list[Action]:
    """Every configured motion (pulls, arcs, twists) from grasp ``g``."""
    actions = []
    if "pull" in cfg.action_families:
        dirs, dir_ids = DirectionsForGrasp(g.p_WG, ctx.branch_all_W,
                                           cfg.max_branch_angle_deg, all_dirs, ctx.branch_tree)
        actions += [Action(g.p_WG, g.R_WG, s * u, grasp_id=g.grasp_id, direction_id=int(j))
                    for u, j in zip(dirs, dir_ids) for s in PullDistances(cfg, g.p_WG, pivot)]
    if pivot is not None and np.linalg.norm(g.p_WG - pivot) > 0.02:
        if "arc" in cfg.action_families:
            actions += MakeArcActions(g.p_WG, g.R_WG, pivot,
                                      HingeAxes(g.p_WG, pivot, cfg.num_arc_axes), angles,
                                      grasp_id=g.grasp_id)
        if "twist" in cfg.action_families:
            actions += MakeTwistActions(g.p_WG, g.R_WG, pivot,
                                        np.deg2rad(np.asarray(cfg.twist_angles_deg, float)),
                                        grasp_id=g.grasp_id)
    return actions


def _InitialVisibility(ctx: PlanningContext, cfg: PlannerConfig) -> CandidateSet:
    """Stage 1's start: the fruit estimate's visibility model and what of it
    is seen now (with ``ctx.seen_before_W``), in a set without candidates
    (status 'ok'), or an early status: no usable fruit estimate, nothing of
    it in view, 'no_action_needed' (already ``early_stop_fraction``
    visible), no leaf points to grasp."""
    timings = {"generation_collision_s": 0.0, "visibility_s": 0.0}
    if ctx.scene.fruit is None:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="no fruit estimate: nothing to reveal")
    if not np.all(np.isfinite(ctx.scene.fruit.vertices_W)) or len(ctx.scene.fruit.faces) == 0:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="the fruit estimate is empty or not finite")
    t0 = time.perf_counter()
    vis = VisibilityModel(ctx.X_WC, SurfacesOf(ctx, cfg.visibility_shapes),
                          cfg.visibility_voxel, ctx.image_tan)
    seen_init = vis.Seen(np.vstack([ctx.leaf_W, ctx.occluders_W]))
    if ctx.seen_before_W is not None:
        seen_init = seen_init | vis.Observed(ctx.seen_before_W)
    timings["visibility_s"] += time.perf_counter() - t0
    out = CandidateSet("ok", ctx.scene, visibility=vis, seen_init_mask=seen_init,
                       timings=timings)
    n_init, n_max = vis.Count(seen_init), vis.Count(vis.max_seen)
    if n_max == 0:
        out.status = "no_fruit"
        out.message = ("the fruit estimate is outside camera0's view: no part of it could "
                       "be seen, so no action can reveal it")
        return out
    if n_init >= cfg.early_stop_fraction * n_max:
        out.status, out.message = "no_action_needed", f"fruit already {n_init / n_max:.0%} visible"
        return out
    if len(ctx.leaf_W) < 10:
        out.status, out.message = "no_feasible_action", "no leaf points to grasp"
    return out


def GenerateCandidates(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                       progress=None) -> CandidateSet:
    """Paper Sec. III-C-1 (generation and collision checking) plus the
    initial and maximum visibility. Never raises on a bad scene."""
    progress = progress or (lambda m: None)
    out = _InitialVisibility(ctx, cfg)
    if out.status != "ok":
        return out
    t0 = time.perf_counter()
    try:
        grasps, out.dropped_grasps = GraspCandidates(
            ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps, cfg.grasp_inset,
            cfg.min_branch_distance)
    except (PlanningError, ValueError) as err:
        out.status, out.message = "no_feasible_action", f"no grasp candidates: {err}"
        return out
    all_dirs = PullDirections()[:cfg.num_directions]
    pivot = EstimateHinge(ctx.leaf_W, ctx.branch_all_W, dcfg)
    out.hinge_W = pivot
    if pivot is not None:
        out.hinge_error_m = max(cfg.hinge_error, UnseenPetiole(ctx.leaf_W, pivot, dcfg))
    angles = np.deg2rad(np.asarray(cfg.arc_angles_deg, float))
    failed = []
    for g in grasps:
        actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
        cands = IkAndRobotChecks(ctx, g, cfg, actions)
        if all(c.approach is None for c in cands):
            failed.append((g, actions))
        out.candidates += cands
    if len({c.action.grasp_id for c in out.candidates if c.feasible}) < cfg.min_usable_grasps:
        _SecondChanceGrasps(ctx, cfg, out, failed, grasps, pivot, angles, all_dirs)
    out.timings["generation_collision_s"] += time.perf_counter() - t0
    out.scene, msg = AttachLeaf(ctx.scene, dcfg)
    out.message = msg
    progress(f"{len(out.candidates)} candidates from {len(grasps)} grasps, "
             f"{len(out.LiveActions())} pass IK and robot checks")
    return out


def _SecondChanceGrasps(ctx: PlanningContext, cfg: PlannerConfig, out: CandidateSet,
                        failed: list, grasps: list, pivot, angles, all_dirs) -> None:
    """Fewer than ``planner.min_usable_grasps`` grasps gave a feasible
    action (a small leaf near the branch, a leaf edge the arm reaches
    awkwardly): the grasps whose approach failed are retried with the other
    orientations (``GraspAlternatives``), and grasps dropped for lying
    within ``min_branch_distance`` of the branch, but at least half of it
    away, are tried too (the robot-branch checks still apply). A grasp's
    first orientation whose approach passes replaces its candidates.
    Still short, the grasp set is made again deeper inside the blade (each
    of ``planner.deeper_grasp_insets`` in turn, ids ``DEEPER_GRASP_IDS`` x
    (k + 1) + i), each grasp in its first orientation whose approach passes
    (``DeeperGrasps``)."""
    tried = {g.grasp_id for g in grasps}
    near, _ = GraspCandidates(ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps,
                              cfg.grasp_inset, 0.5 * cfg.min_branch_distance)
    extra = []
    for g in near:
        if g.grasp_id in tried:
            continue
        actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
        cands = IkAndRobotChecks(ctx, g, cfg, actions)
        out.candidates += cands
        out.dropped_grasps = [d for d in out.dropped_grasps if d["grasp_id"] != g.grasp_id]
        if all(c.approach is None for c in cands):
            extra.append((g, actions))
    for g, actions in failed + extra:
        cands = _FirstApproach(ctx, cfg, g, actions, GraspAlternatives(g.R_WG),
                               AlternativeLabels())
        if cands:
            out.candidates = [c for c in out.candidates
                              if c.action.grasp_id != g.grasp_id] + cands
    DeeperGrasps(ctx, cfg, out, pivot, angles, all_dirs)


def _FirstApproach(ctx: PlanningContext, cfg: PlannerConfig, g, actions: list[Action],
                   rotations: list[np.ndarray], labels: list) -> list[Candidate] | None:
    """The candidates of grasp ``g``'s ``actions`` turned to the first of
    ``rotations`` (R_WG; ``labels``: their record orientations) whose
    approach passes, or None when none does."""
    for R, label in zip(rotations, labels):
        turned = Grasp(g.p_WG, R, g.grasp_id)
        # (a failed orientation's reason is not kept: its verdict suffices;
        # one whose fingers surely meet a fruit or the branch is not solved)
        if GraspSurelyBlocked(ctx, turned, cfg):
            continue
        approach = GraspApproach(ctx, turned, cfg, verdict_only=True)
        if approach[0] is None:
            continue            # (the actions are turned only for an approach that passes)
        cands = IkAndRobotChecks(ctx, turned, cfg, [dc.replace(a, R_WG=R) for a in actions],
                                 approach)
        for c in cands:
            c.orientation = label
        return cands
    return None


def DeeperGrasps(ctx: PlanningContext, cfg: PlannerConfig, out: CandidateSet,
                 pivot, angles, all_dirs) -> None:
    """While fewer than ``planner.min_usable_grasps`` grasps give a feasible
    action, the grasp set again at each of ``planner.deeper_grasp_insets``
    (m inside the leaf's outline instead of ``grasp_inset``): on a crowded
    plant every grasp 1 cm inside the rim can fail a robot check by a few
    millimetres (``four_fruits``: 15 grasps 2-3 mm from a run where 2 had
    passed, none passing), and one a centimetre deeper comes in past what
    the fingers met. Each grasp keeps its first orientation
    (``GraspAlternatives``, the given one first) whose approach passes;
    grasps whose every orientation fails are not added (the rejection
    counts stay those of the rim's grasps)."""
    for k, inset in enumerate(cfg.deeper_grasp_insets):
        if len({c.action.grasp_id for c in out.candidates if c.feasible}) >= cfg.min_usable_grasps:
            return
        try:
            deep, _ = GraspCandidates(ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps,
                                      float(inset), cfg.min_branch_distance)
        except (PlanningError, ValueError):
            continue
        for g in deep:
            g = Grasp(g.p_WG, g.R_WG, DEEPER_GRASP_IDS * (k + 1) + g.grasp_id)
            actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
            cands = _FirstApproach(ctx, cfg, g, actions, [g.R_WG] + GraspAlternatives(g.R_WG),
                                   [None] + AlternativeLabels())
            out.candidates += cands or []
