"""Robot checks of the planner at a joint vector and along the executed
motion: self-collision, the margins to the fruits and branch
(``collision.RobotCollisionReason``) and to the observed leaves; the IK of
each action's end (and midway) pose (``MotionChecks``) and of the path the
controller will execute (``ActionPathReason``). World frame W, metres."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from scipy.spatial import cKDTree

from lmap_drake.planning.collision import NearBox, RobotCollisionReason
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.motion import MotionError, PlanActionPath
from lmap_drake.planning.result import Candidate


def RobotPoseReason(robot, q: np.ndarray, half_open: float, points_W: np.ndarray,
                    ctx: PlanningContext, cfg: PlannerConfig, self_margin: float = 0.0
                    ) -> str:
    """'' if the robot at ``q`` (surface samples ``points_W``, an array or
    per geometry) is clear of itself (arm against gripper or arm; distant
    links by ``self_margin``) and keeps the margin from the fruit and the
    branch, else the reason."""
    pair = robot.SelfCollision(q, half_open, self_margin)
    if pair:
        return f"robot self-collision ({pair})"
    return RobotCollisionReason(points_W, ctx.fruit_sdf, ctx.branch_distance,
                                cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                cfg.robot_fruit_margin)


def _LeafObstacles(ctx: PlanningContext, held: bool = True) -> tuple:
    """(KD-tree of the observed leaf points or None, their box (lo, hi)),
    built once per planning context (cached on it): every leaf (the
    approach's obstacles), or with ``held`` False only the leaves not held
    (``ctx.other_leaves_W``, the moved poses' obstacles)."""
    attr = "_leaf_obstacles" if held else "_other_leaf_obstacles"
    cached = getattr(ctx, attr, None)
    if cached is None:
        leaves_W = (np.vstack([ctx.leaf_W, ctx.other_leaves_W]) if held
                    else ctx.other_leaves_W)
        cached = ((cKDTree(leaves_W), (leaves_W.min(0), leaves_W.max(0))) if len(leaves_W)
                  else (None, None))
        setattr(ctx, attr, cached)
    return cached


class NearCells:
    """Which points may lie within ``margin`` (m) of ``points_W``: a grid
    of cells a little larger than ``margin`` over their box, the cells
    holding a point and their 26 neighbours marked. A point within
    ``margin`` of one of them lies in a marked cell (a cheap, exact
    pre-filter for the KD-tree; a plant's leaves fill a box the arm is
    mostly inside, while few of its samples come near a leaf)."""

    MAX_CELLS = 20_000_000

    def __init__(self, points_W: np.ndarray, margin: float):
        from scipy.ndimage import binary_dilation
        self.marked = None
        p = np.asarray(points_W, float).reshape(-1, 3)
        if not margin > 0 or len(p) == 0:
            return
        self.cell = 1.001 * float(margin)
        self.lo = p.min(0) - 2 * self.cell
        idx = np.floor((p - self.lo) / self.cell).astype(np.int64)
        self.shape = idx.max(0) + 3
        if np.prod(self.shape) <= self.MAX_CELLS:
            grid = np.zeros(self.shape, bool)
            grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
            self.marked = binary_dilation(grid, np.ones((3, 3, 3), bool))

    def Maybe(self, q_W: np.ndarray) -> np.ndarray:
        """A bool per point of ``q_W`` (N, 3): it may lie within the margin
        (True everywhere when the grid would be too large)."""
        q = np.asarray(q_W, float).reshape(-1, 3)
        if self.marked is None:
            return np.ones(len(q), bool)
        idx = np.floor((q - self.lo) / self.cell).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < self.shape), axis=1)
        out = np.zeros(len(q), bool)
        i = idx[inside]
        out[inside] = self.marked[i[:, 0], i[:, 1], i[:, 2]]
        return out


def TouchesLeaf(ctx: PlanningContext, margin: float, pts, held: bool = True) -> bool:
    """Whether the robot's surface samples ``pts`` come within ``margin``
    of an observed leaf (``_LeafObstacles``: every leaf, or with ``held``
    False the leaves not held); only samples near the leaves' box, and
    there in cells near a leaf point (``NearCells``), are queried."""
    tree, box = _LeafObstacles(ctx, held)
    if tree is None:
        return False
    near = NearBox(pts, box[0] - margin, box[1] + margin)
    if not len(near):
        return False
    attr = ("_leaf_cells" if held else "_other_leaf_cells", float(margin))
    cells = getattr(ctx, "_near_cells", {}).get(attr)
    if cells is None:
        cells = NearCells(tree.data, margin)
        ctx._near_cells = {**getattr(ctx, "_near_cells", {}), attr: cells}
    near = near[cells.Maybe(near)]
    # the search stops at ``margin``: farther samples come back inf
    return bool(len(near)) and bool(
        np.any(tree.query(near, distance_upper_bound=margin)[0] < margin))


def OtherLeafReason(ctx: PlanningContext, cfg: PlannerConfig, pts) -> str:
    """'' or why the robot's surface samples ``pts`` (at a moved pose, the
    gripper closed) come within ``planner.collision_margin`` of a leaf that
    is not the one held (``ctx.other_leaves_W``): the arm would push a
    neighbouring leaf along the motion and drag it on the way back."""
    return ("robot-leaf (another leaf)"
            if TouchesLeaf(ctx, cfg.collision_margin, pts, held=False) else "")


def MotionChecks(ctx: PlanningContext, cfg: PlannerConfig, cands: list[Candidate],
                 q_grasp: np.ndarray) -> list[Candidate]:
    """IK for each action's end pose (and an arc's midway pose), warm-started
    along each direction's distances from ``q_grasp`` (the joints holding
    the grasp), and robot-vs-fruit/branch checks there (gripper closed), and
    robot vs the leaves not held (``OtherLeafReason``)."""
    robot = ctx.robot
    seeds: dict[int, np.ndarray] = {}
    solved: dict[tuple, tuple] = {}
    for c in sorted(cands, key=lambda c: (c.action.direction_id, c.action.distance)):
        c.q_grasp = q_grasp if c.q_grasp is None else c.q_grasp
        seed = seeds.get(c.action.direction_id, q_grasp)
        a = c.action
        # An arc also turns the wrist: its midway pose is checked too (the
        # arcs of one axis come in increasing angles, so consecutive ends
        # and midpoints sample the whole sweep).
        # (Arc poses already solved for this axis, e.g. the 30-degree end as
        # the 60-degree arc's midway pose, are reused.)
        poses = [(a.angle, a.p_WG + a.dp_W, a.R_WG_end)]
        if a.family != "pull":
            mid = dc.replace(a, angle=0.5 * a.angle, dp_W=None)
            poses.insert(0, (mid.angle, mid.p_WG + mid.dp_W, mid.R_WG_end))
        why = ""
        for angle, p, R_end in poses:
            key = (a.direction_id, round(angle, 9)) if a.family != "pull" else None
            if key in solved:
                r, pose_why = solved[key]
            else:
                r = robot.Ik(RigidTransform(RotationMatrix(R_end), p), seed, 0.0)
                pose_why = ""
                if r.success:
                    pts = robot.SurfacePointsByBody(r.q, 0.0)
                    pose_why = (RobotPoseReason(robot, r.q, 0.0, pts, ctx, cfg)
                                or OtherLeafReason(ctx, cfg, pts))
                if key is not None:
                    solved[key] = (r, pose_why)
            if not r.success:
                why = f"IK failed ({'pulled pose' if a.family == 'pull' else 'along the ' + a.family})"
                break
            seed = r.q
            why = why or pose_why
        if why.startswith("IK failed"):
            c.reason = why
            continue
        seeds[c.action.direction_id] = r.q
        c.q_pulled = r.q
        if why:
            c.reason = why
    return cands


def ActionPathReason(ctx: PlanningContext, cfg: PlannerConfig, c: Candidate) -> str:
    """'' or why candidate ``c``'s motion fails along the joint path the
    controller will execute (``PlanActionPath`` from its grasp joints,
    straightened near a wrist singularity, so it may differ from the end
    and midway poses the candidate checks solved on their own): no IK,
    self-collision, or a waypoint within the margins of a fruit, a branch
    or a leaf not held."""
    if c.q_grasp is None:
        return ""
    try:
        path = PlanActionPath(ctx.robot, c.action, c.q_grasp)
    except MotionError as err:
        return f"executed path: {' '.join(str(err).split())}"
    for q in path:
        pts = ctx.robot.SurfacePointsByBody(q, 0.0)
        why = (RobotCollisionReason(pts, ctx.fruit_sdf, ctx.branch_distance,
                                    cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                    cfg.robot_fruit_margin)
               or OtherLeafReason(ctx, cfg, pts))
        if why:
            return f"{why} along the executed {c.action.family}"
    return ""
