"""Robot checks of the planner at a joint vector and along the executed
motion: self-collision, the margins to the fruits and branch
(``collision.RobotCollisionReason``) and to the observed leaves, with the
light brushing of leaves not grasped that the approach may make
(``LeafContact``); the IK of each action's end (and midway) pose
(``MotionChecks``) and of the path the controller will execute
(``ActionPathReason``). World frame W, metres."""
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
                    ctx: PlanningContext, cfg: PlannerConfig, self_margin: float = 0.0,
                    verdict_only: bool = False) -> str:
    """'' if the robot at ``q`` (surface samples ``points_W``, an array or
    per geometry) is clear of itself (arm against gripper or arm; distant
    links by ``self_margin``) and keeps the margin from the fruit and the
    branch, else the reason (``verdict_only``: see
    ``RobotCollisionReason``)."""
    pair = robot.SelfCollision(q, half_open, self_margin)
    if pair:
        return f"robot self-collision ({pair})"
    return RobotCollisionReason(points_W, ctx.fruit_sdf, ctx.branch_distance,
                                cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                cfg.robot_fruit_margin, verdict_only)


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


# Leaf points of other leaves this near a fruit (m, the fruits' SDF) are
# never brushed: a pushed leaf must not be pressed into a fruit.
BRUSH_FRUIT_CLEARANCE = 0.03
# A push d (m) at a lever L (m) from where a leaf joins its stem loads its
# petiole about k d / L^2 (``BrushPetioleForce``); k (N m) measured on the
# FEM leaf (``studies.brush``: the largest of its steady pushes), at
# most ``BRUSH_MAX_FORCE`` (N, a third of the plant-hazard limit) is
# allowed (``BrushAllowance``; docs: dense-canopy.md).
BRUSH_PETIOLE_STIFFNESS = 5.2
BRUSH_MAX_FORCE = 5.0


def BeamPetioleForce(displacement: float, lever: float, youngs_modulus: float = 10.0e6,
                     petiole_width: float = 0.006, thickness: float = 0.002) -> float:
    """The petiole's axial force estimate (N; the plant world's
    ``PetioleForce``, E A (stretch - 1)) of a leaf pushed ``displacement``
    (m) at ``lever`` (m) from where it joins its stem, as a beam: a
    cantilever clamped there, bending only in the petiole, pushed about
    its stiff axis (half-width c): a moment 3 E I d / L^2 at the clamp, a
    surface strain 3 d c / L^2, hence E A 3 d c / L^2 (k = 1.08 N m for the
    FEM leaf's E 10 MPa and 6 x 2 mm petiole). The FEM leaf measures 2-5
    times more (``BRUSH_PETIOLE_STIFFNESS``): the model's form, not its k."""
    c = 0.5 * max(petiole_width, thickness)
    strain = 3.0 * float(displacement) * c / float(lever) ** 2
    return float(youngs_modulus * petiole_width * thickness * strain)


def BrushPetioleForce(displacement, lever, stiffness: float = BRUSH_PETIOLE_STIFFNESS):
    """The petiole load (N) predicted for a push of ``displacement`` (m) at
    ``lever`` (m) from the stem: ``stiffness`` d / L^2 (the beam's form,
    ``BeamPetioleForce``, with the FEM leaf's measured k)."""
    return stiffness * np.asarray(displacement, float) / np.asarray(lever, float) ** 2


def BrushAllowance(branch_distance, bound: float) -> np.ndarray:
    """The push (m) allowed on leaf points ``branch_distance`` (m) from the
    branch: ``bound``, or less where a push that far would load the
    petiole more than ``BRUSH_MAX_FORCE`` (``BrushPetioleForce``): a
    1 cm push needs 10.2 cm, 5 mm 7.2 cm."""
    d = np.asarray(branch_distance, float)
    return np.minimum(bound, BRUSH_MAX_FORCE * d ** 2 / BRUSH_PETIOLE_STIFFNESS)


def LeafNormals(points_W: np.ndarray, tree=None, k: int = 10,
                radius: float = 0.012) -> np.ndarray:
    """Unit normals (N, 3) of a leaf point cloud: the least principal axis
    of each point's ``k`` nearest neighbours within ``radius`` (m); zeros
    where fewer than 5 are that near (an isolated point: no sheet)."""
    p = np.asarray(points_W, float).reshape(-1, 3)
    if len(p) < 5:
        return np.zeros_like(p)
    tree = cKDTree(p) if tree is None else tree
    d, i = tree.query(p, k=min(k, len(p)))
    nb = p[i]
    ok = d <= radius
    w = ok[..., None].astype(float)
    mean = (nb * w).sum(1) / np.maximum(w.sum(1), 1.0)
    x = (nb - mean[:, None]) * w
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", x, x))
    n = vec[:, :, 0]
    n[ok.sum(1) < 5] = 0.0
    return n


def SheetPush(pts, points_W: np.ndarray, normals: np.ndarray, margin: float,
              reach: float, step: float = 0.002) -> np.ndarray:
    """How far (m) each leaf point ``points_W`` must move along its leaf's
    normal (either sense, the nearer) to keep ``margin`` from the robot at
    the pose of ``pts`` (``SurfaceSamples``): a leaf is a sheet, so a link
    that pokes through it pushes it ahead until the link's far side, not
    only to the nearest face. Marched in ``step`` up to ``reach``
    (returned as ``reach`` + ``step`` when no free place is that near).
    Points without a normal (zeros): margin minus their signed distance."""
    p = np.asarray(points_W, float).reshape(-1, 3)
    n = np.asarray(normals, float).reshape(-1, 3)
    s = np.arange(0.0, reach + 0.5 * step, step)
    free_s = np.full((len(p), 2), reach + step)
    for k, sign in enumerate((1.0, -1.0)):
        line = p[:, None, :] + sign * s[None, :, None] * n[:, None, :]
        free = pts.SignedDistance(line.reshape(-1, 3), margin).reshape(len(p), len(s)) >= margin
        first = np.argmax(free, axis=1)
        found = free[np.arange(len(p)), first]
        free_s[found, k] = s[first[found]]
    push = free_s.min(axis=1)
    bare = ~np.any(n != 0.0, axis=1)
    if bare.any():
        push[bare] = np.maximum(0.0, margin - pts.SignedDistance(p[bare], margin))
    return push


def _OtherLeafPoints(ctx: PlanningContext) -> tuple | None:
    """None without a branch estimate, else (the other leaves' points
    (``ctx.other_leaves_W``), which of them may be brushed (not within
    ``BRUSH_FRUIT_CLEARANCE`` of a fruit), their distances to the branch):
    what both sets of ``_BrushObstacles`` share, computed once per context
    (cached on it)."""
    if hasattr(ctx, "_other_leaf_points"):
        return ctx._other_leaf_points
    other = np.asarray(ctx.other_leaves_W, float).reshape(-1, 3)
    branch = np.asarray(getattr(ctx, "branch_all_W", np.zeros((0, 3))), float).reshape(-1, 3)
    out = None
    if ctx.branch_distance is not None or len(branch):
        free = np.ones(len(other), bool)
        if len(other) and ctx.fruit_sdf is not None:
            d = np.asarray(ctx.fruit_sdf(other), float).reshape(-1)
            free &= np.nan_to_num(d, nan=-1.0) >= BRUSH_FRUIT_CLEARANCE
        d_branch = np.full(len(other), np.inf)
        if len(other) and ctx.branch_distance is not None:
            d_branch = np.asarray(ctx.branch_distance(other), float)
        if len(other) and len(branch):
            d_branch = np.minimum(d_branch, cKDTree(branch).query(other)[0])
        out = (other, free, d_branch)
    ctx._other_leaf_points = out
    return out


def _BrushedLeaves(ctx: PlanningContext) -> tuple:
    """(the other leaves' points that may be brushed, their KD-tree or
    None, normals, distances to the branch), once per context (cached on
    it; needs ``_OtherLeafPoints``)."""
    if not hasattr(ctx, "_brushed_leaves"):
        other, free, d_branch = _OtherLeafPoints(ctx)
        brushed = other[free]
        brushed_tree = cKDTree(brushed) if len(brushed) else None
        ctx._brushed_leaves = (brushed, brushed_tree, LeafNormals(brushed, brushed_tree),
                               d_branch[free])
    return ctx._brushed_leaves


def _BrushObstacles(ctx: PlanningContext, held: bool = True) -> tuple | None:
    """None without a branch estimate (no lever known: nothing is brushed),
    else (KD-tree or None of the leaf points the robot may not touch, their
    box, how many of them (the first) are the held leaf's; the points it
    may brush, their KD-tree, normals and distances to the branch): the
    held leaf (with ``held``; without, it moves with the gripper) and every
    point of another leaf within ``BRUSH_FRUIT_CLEARANCE`` of a fruit are
    not brushed; cached on ``ctx`` (the other leaves' part shared by both,
    ``_OtherLeafPoints``, ``_BrushedLeaves``)."""
    attr = "_brush_obstacles" if held else "_brush_obstacles_moving"
    if hasattr(ctx, attr):
        return getattr(ctx, attr)
    shared = _OtherLeafPoints(ctx)
    if shared is None:
        setattr(ctx, attr, None)
        return None
    other, free, _ = shared
    mine = np.asarray(ctx.leaf_W if held else np.zeros((0, 3)), float).reshape(-1, 3)
    strict = np.vstack([mine, other[~free]])
    tree = ((cKDTree(strict), (strict.min(0), strict.max(0))) if len(strict)
            else (None, (None, None)))
    cached = (tree[0], tree[1], len(mine)) + _BrushedLeaves(ctx)
    setattr(ctx, attr, cached)
    return cached


def LeafContact(ctx: PlanningContext, cfg: PlannerConfig, pts,
                held: bool = True) -> tuple[str, float]:
    """('' or the reason, the push (m) on the leaves brushed) of the robot's
    surface samples ``pts`` (a ``SurfaceSamples`` of one pose) against the
    observed leaves: every leaf (``held``: an approach pose) or the leaves
    not held (a moved pose). With ``planner.max_brush_displacement`` 0 (or
    no branch estimate), any leaf point within ``collision_margin`` is
    'robot-leaf'. Else the held leaf and the other leaves' points near a
    fruit (``_BrushObstacles``) keep that rule, and the other leaves'
    points may be pushed, each at most ``BrushAllowance`` (the key's value
    far enough from the branch): each point within the margin of the
    robot's geometry as far as its leaf must move along its normal to
    clear the robot by the margin (``SheetPush``: the robot's depth through
    the leaf plus the margin)."""
    margin, bound = cfg.collision_margin, cfg.max_brush_displacement
    obstacles = _BrushObstacles(ctx, held) if bound > 0.0 else None
    if obstacles is None:
        return ("robot-leaf" if TouchesLeaf(ctx, margin, pts, held) else ""), 0.0
    tree, box, n_held, brushed, brushed_tree, normals, d_branch = obstacles
    if tree is not None:
        near = NearBox(pts, box[0] - margin, box[1] + margin)
        if len(near):
            # (the search stops at ``margin``: farther samples come back inf)
            d, i = tree.query(near, distance_upper_bound=margin)
            k = int(np.argmin(d))
            if d[k] < margin:
                return ("robot-leaf" if i[k] < n_held
                        else "robot-leaf (another leaf) near a fruit"), 0.0
    if not len(brushed):
        return "", 0.0
    sd = pts.SignedDistance(brushed, margin, brushed_tree)
    touched = np.flatnonzero(sd < margin)
    if not len(touched):
        return "", 0.0
    # the deepest point per 4 mm cell (the push varies smoothly over a leaf)
    order = touched[np.argsort(sd[touched])]
    _, first = np.unique(np.floor(brushed[order] / 0.004).astype(np.int64), axis=0,
                         return_index=True)
    touched = order[first]
    reach = bound + margin + 0.01      # (so a refusal says by how much)
    push = SheetPush(pts, brushed[touched], normals[touched], margin, reach)
    allowed = BrushAllowance(d_branch[touched], bound)
    worst = int(np.argmax(push - allowed))
    p, a = float(push[worst]), float(allowed[worst])
    if p > a:
        much = f"{100 * p:.1f} cm" if p <= reach else f"over {100 * reach:.1f} cm"
        limit = (f"planner.max_brush_displacement {100 * bound:.1f} cm" if a >= bound
                 else f"{100 * a:.1f} cm allowed {100 * d_branch[touched][worst]:.1f} cm "
                      f"from the branch")
        return f"robot-leaf (another leaf) pushed {much} > {limit}", float(push.max())
    return "", float(push.max())


def OtherLeafReason(ctx: PlanningContext, cfg: PlannerConfig, pts) -> tuple[str, float]:
    """('' or why, the push (m) on leaves brushed): the robot's surface
    samples ``pts`` (at a moved pose, the gripper closed) come within
    ``planner.collision_margin`` of a leaf that is not the one held
    (``ctx.other_leaves_W``), or push one farther than
    ``planner.max_brush_displacement`` (``LeafContact``): the arm would
    push a neighbouring leaf along the motion and drag it on the way back."""
    why, push = LeafContact(ctx, cfg, pts, held=False)
    return ("robot-leaf (another leaf)" if why == "robot-leaf" else why), push


def MotionChecks(ctx: PlanningContext, cfg: PlannerConfig, cands: list[Candidate],
                 q_grasp: np.ndarray) -> list[Candidate]:
    """IK for each action's end pose (and an arc's midway pose), warm-started
    along each direction's distances from ``q_grasp`` (the joints holding
    the grasp), and robot-vs-fruit/branch checks there (gripper closed), and
    robot vs the leaves not held (``OtherLeafReason``; the largest push on
    them joins the approach's in ``brush_displacement``)."""
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
                r, pose_why, push = solved[key]
            else:
                r = robot.Ik(RigidTransform(RotationMatrix(R_end), p), seed, 0.0)
                pose_why, push = "", 0.0
                if r.success:
                    pts = robot.SurfacePointsByBody(r.q, 0.0)
                    pose_why = RobotPoseReason(robot, r.q, 0.0, pts, ctx, cfg)
                    if not pose_why:
                        pose_why, push = OtherLeafReason(ctx, cfg, pts)
                if key is not None:
                    solved[key] = (r, pose_why, push)
            if not r.success:
                why = f"IK failed ({'pulled pose' if a.family == 'pull' else 'along the ' + a.family})"
                break
            seed = r.q
            why = why or pose_why
            c.brush_displacement = max(c.brush_displacement, push)
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
        why = RobotCollisionReason(pts, ctx.fruit_sdf, ctx.branch_distance,
                                   cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                   cfg.robot_fruit_margin)
        if not why:
            why, push = OtherLeafReason(ctx, cfg, pts)
            c.brush_displacement = max(c.brush_displacement, push)
        if why:
            return f"{why} along the executed {c.action.family}"
    return ""
