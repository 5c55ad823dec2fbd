"""The approach to a grasp: via point -> ready pose -> pre-grasp -> grasp
(``motion.PlanApproach``) with the robot checked along it (``_ApproachChecks``),
the ready pose moved closer when the arm cannot reach it, the pads opened
narrower when the open pads would hit the fruit; then the IK and robot
checks of each action from the grasp (``IkAndRobotChecks``). World frame W,
metres."""
from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.deformation.action import Action
from lmap_drake.planning.collision import MESH_BOUND_GUARD, MeshSets, NearBox
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.motion import ApproachBlocked, ApproachPlan, MotionError, PlanApproach
from lmap_drake.planning.result import Candidate, DistanceId
from lmap_drake.planning.robot_checks import LeafContact, MotionChecks, RobotPoseReason
from lmap_drake.planning.robot_model import SELF_MARGIN
from lmap_drake.robot_models import PAD_LEN, PAD_WIDTH


class _ApproachChecks:
    """Robot checks along an approach with the pads ``half_open`` (m) apart:
    fruit, branch and the grasped leaf keep the margin from the robot (in
    the final approach the leaf must therefore pass between the open
    pads), the other leaves too or, with ``planner.max_brush_displacement``,
    are pushed at most that far (``LeafContact``; ``brush``: the
    largest push of the poses checked, m), and links three or more joints
    apart keep ``SELF_MARGIN`` (the approach's joint moves are fast and
    sampled). ``Pose(segment, q)`` is
    ``PlanApproach``'s check: "grasp" poses are the final approach, the
    others lie on the way to the pre-grasp; ``FreeMove`` samples the joint
    move from the current joints to the via point. Results are kept by
    joint vector and opening in ``memo`` (a ready pose closer to the
    pre-grasp repeats the approach's first poses). ``verdict_only``: a
    failed check's reason only up to its parenthesis
    (``RobotCollisionReason``)."""

    def __init__(self, ctx: PlanningContext, cfg: PlannerConfig, half_open: float,
                 memo: dict | None = None, verdict_only: bool = False):
        self.ctx, self.cfg, self.half_open = ctx, cfg, float(half_open)
        self.memo = {} if memo is None else memo
        self.verdict_only = verdict_only
        self.brush = 0.0

    def _Reason(self, q: np.ndarray) -> str:
        """'' or the robot's reason at ``q`` without where: '...', or
        'robot-leaf ...'."""
        key = (np.asarray(q, float).tobytes(), self.half_open)
        if key not in self.memo:
            robot, cfg = self.ctx.robot, self.cfg
            pts = robot.SurfacePointsByBody(q, self.half_open)
            why = RobotPoseReason(robot, q, self.half_open, pts, self.ctx, cfg, SELF_MARGIN,
                                  self.verdict_only)
            self.memo[key] = (why, 0.0) if why else LeafContact(self.ctx, cfg, pts)
        why, push = self.memo[key]
        if not why:
            self.brush = max(self.brush, push)
        return why

    def Pose(self, segment: str, q: np.ndarray) -> str:
        why = self._Reason(q)
        if not why:
            return ""
        if segment == "grasp":
            return why + (" during the approach (leaf not between the pads)"
                          if why == "robot-leaf" else " during the approach")
        return why + " on the way to the pre-grasp"

    def FreeMove(self, via: np.ndarray) -> str:
        q0 = self.ctx.q_current
        fractions = FreeMoveFractions(self.ctx.robot, q0, via, self.half_open)
        for f in fractions[::-1]:      # (the via point itself is checked)
            why = self.Pose("staging", q0 + f * (via - q0))
            if why:
                return why
        return ""


FREE_MOVE_STEP = 0.01    # m: the largest move of the robot between two checked poses


def FreeMoveFractions(robot, q0: np.ndarray, q1: np.ndarray, half_open: float,
                      step: float = FREE_MOVE_STEP, max_samples: int = 400) -> np.ndarray:
    """Fractions in (0, 1) of the joint move q0 -> q1 at which to check the
    robot so that no point of its geometries' boxes moves more than
    ``step`` (m) between two consecutive checks (a rigid motion moves a
    box's points at most as far as its farthest corner; the joint line is
    refined until the corners keep the step). Eight evenly spaced samples
    let the wrist skip 10 cm past a neighbouring leaf on a long move (the
    retreat's last move brushed one at 1.3 m/s in ``three_fruits_default``)."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    n = 8
    while True:
        f = np.linspace(0.0, 1.0, n)
        C = np.stack([robot.SurfacePointsByBody(q0 + x * (q1 - q0), half_open).corners
                      for x in f])
        moved = float(np.linalg.norm(np.diff(C, axis=0), axis=-1).max())
        if moved <= step or n >= max_samples:
            return f[1:-1]
        n = min(max_samples, int(np.ceil((n - 1) * moved / step)) + 1)


def NarrowOpening(leaf_W: np.ndarray, grasp, cfg: PlannerConfig) -> float:
    """The smallest pre-grasp opening (m) for ``grasp`` that keeps the
    collision margin plus 3 mm from the observed leaf on both pads: twice
    the leaf's local half-thickness along the closing direction (95th
    percentile of the leaf points within 1.5 cm of the grasp point, which
    includes the sensor noise) plus margins; never wider than
    ``pregrasp_opening``, never below 1.5 cm."""
    y = grasp.R_WG[:, 1]
    near = leaf_W[np.linalg.norm(leaf_W - grasp.p_WG, axis=1) < 0.015]
    half = float(np.percentile(np.abs((near - grasp.p_WG) @ y), 95)) if len(near) >= 5 else 0.005
    opening = 2.0 * (half + cfg.collision_margin + 0.003)
    return float(np.clip(opening, 0.015, cfg.pregrasp_opening))


def _Approach(ctx: PlanningContext, cfg: PlannerConfig, grasp, ready: float,
              memo: dict | None = None, verdict_only: bool = False):
    """The approach to ``grasp`` with its ready pose ``ready`` (m) behind the
    pre-grasp (an ``ApproachPlan``), or why there is none: the configured
    opening first; if the open pads hit the fruit close behind the leaf (or
    the leaf), the narrowest opening that still lets the observed leaf pass
    between them. ``memo`` (a dict, one per grasp orientation) keeps IK
    solutions and pose checks for the next ready distance; ``verdict_only``:
    see ``GraspApproach``."""
    why = ""
    memo = memo if memo is not None else {}
    for opening in dict.fromkeys([cfg.pregrasp_opening,
                                  NarrowOpening(ctx.leaf_W, grasp, cfg)]):
        # each pose is checked as soon as it is solved, from the grasp
        # outward: a blocked approach stops before the rest of its IK
        checks = (_ApproachChecks(ctx, cfg, 0.5 * opening, memo.setdefault("checks", {}),
                                  verdict_only)
                  if np.isfinite(cfg.collision_margin) else None)
        try:
            approach = PlanApproach(ctx.robot,
                                    RigidTransform(RotationMatrix(grasp.R_WG), grasp.p_WG),
                                    ctx.q_current,
                                    grasp.R_WG[:, 1], cfg.pregrasp_distance, opening,
                                    ready_extra=ready,
                                    check=None if checks is None else checks.Pose,
                                    memo=memo.setdefault("ik", {}))
            why = "" if checks is None else checks.FreeMove(approach.via)
            approach.brush_displacement = 0.0 if checks is None else checks.brush
        except MotionError as err:
            return f"IK failed ({'staging' if err.staging else 'approach'}): {err}"
        except ApproachBlocked as err:
            why = str(err)
        if not why:
            return approach
        if not why.startswith(("robot-fruit", "robot-leaf")):
            break
    return why


# How far (m) a gripper sample may lie from where the target TCP pose puts
# it once IK has solved that pose: the IK's position acceptance
# (``ik.SolveTcpIk``: 10 x 1e-4 m) plus ``IK_ROTATION_SLACK`` rad at the
# sample's lever (``GraspSurelyBlocked``).
IK_POSITION_SLACK = 1.001e-3
IK_ROTATION_SLACK = 5e-3


def GraspSurelyBlocked(ctx: PlanningContext, grasp, cfg: PlannerConfig) -> bool:
    """Whether every approach to ``grasp`` (``GraspApproach``) fails at the
    grasp pose itself whatever joints the IK finds there: for each opening
    ``_Approach`` may try, a sample of the gripper (the geometries rigid
    with the TCP, ``RobotModel.GripperSamplesInTcp``) at the target TCP
    pose lies nearer to a vertex of a fruit hypothesis mesh than its
    margin (``collision_margin`` for the fingers, ``robot_fruit_margin``
    for the rest, as ``RobotCollisionReason``) less the IK's slack
    (position and rotation at the sample's lever), or nearer to the branch
    than ``collision_margin`` less it. A vertex lies on the surface and
    distances to surfaces are 1-Lipschitz, so at the solved pose that
    sample is within its margin and the robot check of the grasp pose
    fails (the same verdict, without the IK and the check; False when it
    cannot tell)."""
    m = cfg.collision_margin
    meshes = MeshSets(ctx.fruit_sdf)
    if not np.isfinite(m) or (not meshes and ctx.branch_distance is None):
        return False
    body_m = (cfg.robot_fruit_margin if cfg.robot_fruit_margin is not None
              and cfg.robot_fruit_margin > m else m)
    R, p = np.asarray(grasp.R_WG, float), np.asarray(grasp.p_WG, float)
    for opening in dict.fromkeys([cfg.pregrasp_opening, NarrowOpening(ctx.leaf_W, grasp, cfg)]):
        blocked = False
        for p_T, margin in zip(ctx.robot.GripperSamplesInTcp(0.5 * opening), (m, body_m)):
            if not len(p_T):
                continue
            slack = (IK_POSITION_SLACK + MESH_BOUND_GUARD
                     + IK_ROTATION_SLACK * float(np.linalg.norm(p_T, axis=1).max()))
            p_W = p_T @ R.T + p
            if any(mesh.AnyNearer(p_W, margin - slack) for mesh in meshes):
                blocked = True
                break
            bound = m - slack
            if ctx.branch_distance is not None and bound > 0.0:
                near = (p_W if ctx.branch_box is None else
                        NearBox(p_W, ctx.branch_box[0] - bound, ctx.branch_box[1] + bound))
                if len(near) and float(np.min(ctx.branch_distance(near))) < bound:
                    blocked = True
                    break
        if not blocked:
            return False
    return True


# Another leaf's points between the open pads at the grasp pose: closing,
# the pads pinch that leaf too, and the action then drags a leaf its model
# does not hold (gh_random_6363_004: a neighbour squeezed as the pads
# closed spiked its petiole to 17.8 N). Points within OFF_BLADE of the
# grasped blade's plane are not counted: a piece of the same leaf split off
# as another instance, or a blade lying flush, which the pads hold anyway.
# MIN_POINTS: a few stray (flying) pixels do not count as a leaf.
BETWEEN_PADS_OFF_BLADE = 0.003     # m
BETWEEN_PADS_MIN_POINTS = 5


def LeafBetweenPads(other_leaves_W: np.ndarray, p_WG: np.ndarray, R_WG: np.ndarray,
                    half_open: float, pushed_ahead: float = 0.0, hidden_reach: float = 0.0,
                    p_WC: np.ndarray | None = None) -> int:
    """How many of ``other_leaves_W`` (m, world) lie in the volume the pads
    close through at the grasp pose (``p_WG``, ``R_WG``: y the closing
    axis, z the approach): within the pads' footprint (x, z), at most
    ``half_open`` (m) from the grasped blade along y and more than
    ``BETWEEN_PADS_OFF_BLADE`` off it. Points within ``pushed_ahead`` (m)
    of the pads' tips are left out: a leaf across the tips is pushed ahead
    of them (the approach's brush check bounds that push), not pinched.

    ``hidden_reach`` (m, with the camera's position ``p_WC``): points behind
    the grasped blade as the camera sees it, at a depth the pads close
    through, count up to this far beyond the footprint too: that leaf goes
    on under the held blade, where the camera cannot see it, and may pass
    between the pads (``planner.hidden_leaf_reach``)."""
    return PadCounts(other_leaves_W, p_WG, R_WG, half_open, pushed_ahead, hidden_reach,
                     p_WC)[1]


def PadCounts(other_leaves_W: np.ndarray, p_WG: np.ndarray, R_WG: np.ndarray,
              half_open: float, pushed_ahead: float = 0.0, hidden_reach: float = 0.0,
              p_WC: np.ndarray | None = None) -> tuple[int, int]:
    """(``LeafBetweenPads`` without ``hidden_reach``, with it): the points
    seen where the pads close, and those plus the ones that may pass
    under the held blade; one transform of the points for both."""
    pts = np.asarray(other_leaves_W, float).reshape(-1, 3)
    if not len(pts):
        return 0, 0
    p_WG = np.asarray(p_WG, float)
    p_G = (pts - p_WG) @ np.asarray(R_WG, float)
    depth = (np.abs(p_G[:, 1]) <= half_open) & (np.abs(p_G[:, 1]) > BETWEEN_PADS_OFF_BLADE)

    def Footprint(reach: float) -> np.ndarray:
        return ((np.abs(p_G[:, 0]) <= 0.5 * PAD_WIDTH + reach)
                & (p_G[:, 2] >= -0.5 * PAD_LEN - reach)
                & (p_G[:, 2] <= 0.5 * PAD_LEN - pushed_ahead + reach))

    seen = depth & Footprint(0.0)
    inside = seen
    if hidden_reach > 0.0 and p_WC is not None:
        to_camera = np.asarray(p_WC, float) - p_WG
        to_camera /= max(float(np.linalg.norm(to_camera)), 1e-12)
        behind = (pts - p_WG) @ to_camera < -BETWEEN_PADS_OFF_BLADE
        inside = seen | (depth & behind & Footprint(hidden_reach))
    return int(seen.sum()), int(inside.sum())


def GraspApproach(ctx: PlanningContext, grasp, cfg: PlannerConfig, verdict_only: bool = False
                  ) -> tuple[ApproachPlan | None, str]:
    """The approach to ``grasp`` (IK chain via, ready, pre-grasp, grasp; see
    ``planning.motion.PlanApproach``) with robot checks along it: (the
    plan, "") or (None, why there is none). It does not depend on the
    actions from the grasp. ``verdict_only`` (where only whether it
    passes is kept, e.g. another orientation of a grasp): a robot-fruit
    check stops at its first distance below the margin, so the reason
    gives no distance (the same plan, or none, either way)."""
    # If the arm cannot reach the ready pose or hits something on the way
    # to the pre-grasp, a ready pose closer to the pre-grasp
    # (``ready_distances``): on the far side of a plant the default one
    # can lie beyond the arm's reach.
    why = ""
    memo: dict = {}
    for ready in cfg.ready_distances:
        got = _Approach(ctx, cfg, grasp, ready, memo, verdict_only)
        if isinstance(got, ApproachPlan):
            half = 0.5 * (got.opening or cfg.pregrasp_opening)
            ahead = min(cfg.max_brush_displacement, 0.5 * PAD_LEN)
            others = getattr(ctx, "other_leaves_W", np.zeros((0, 3)))
            seen, n = PadCounts(others, grasp.p_WG, grasp.R_WG, half, ahead,
                                cfg.hidden_leaf_reach, getattr(ctx, "p_WC", None))
            if seen >= BETWEEN_PADS_MIN_POINTS:
                return None, (f"another leaf between the pads ({seen} of its points where "
                              "the pads close)")
            if n >= BETWEEN_PADS_MIN_POINTS:
                return None, (f"another leaf may pass between the pads under the held one "
                              f"({n} of its points behind it, within "
                              f"planner.hidden_leaf_reach of the pads)")
            return got, ""
        why = got
        if not why.startswith("IK failed (staging)") and "on the way to the pre-grasp" not in why:
            break
    return None, why


def IkAndRobotChecks(ctx: PlanningContext, grasp, cfg: PlannerConfig,
                     actions: list[Action], approach: tuple | None = None) -> list[Candidate]:
    """The approach (``GraspApproach``; ``approach``: its result, when
    already known) with robot checks along it, then IK for each pulled pose
    (warm-started along each direction's distances) and robot-vs-fruit/branch
    checks there."""
    cands = [Candidate(a, DistanceId(a, cfg)) for a in actions]
    approach, why = approach if approach is not None else GraspApproach(ctx, grasp, cfg)
    if why:
        for c in cands:
            c.reason = why
        return cands
    for c in cands:
        c.approach = approach
        c.q_pregrasp, c.q_grasp = approach.to_pregrasp[-1], approach.to_grasp[-1]
        c.brush_displacement = approach.brush_displacement
    return MotionChecks(ctx, cfg, cands, approach.to_grasp[-1])
