"""Joint-space motions for executing an action: the approach (via point in
front of the leaf -> ready -> pre-grasp -> grasp, Cartesian lines solved by
IK backwards from the grasp so the whole approach stays on one IK branch),
the straight pull, and time-parameterisation under the UR5 velocity limit.
World frame W, metres, radians, seconds."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.trajectories import PiecewisePolynomial

from lmap_drake.station.robot import UR5_VELOCITY_LIMIT


class MotionError(RuntimeError):
    """No joint path for a requested Cartesian motion (IK failed).
    ``index``: the failing pose's index in the requested list (None when
    unknown); ``staging``: in an approach, the failure lies beyond the
    pre-grasp (the ready pose, the via point or the line between them)."""

    def __init__(self, message: str, index: int | None = None, staging: bool = False):
        super().__init__(message)
        self.index, self.staging = index, staging


def CartesianPath(X0: RigidTransform, X1: RigidTransform, step: float = 0.02
                  ) -> list[RigidTransform]:
    """Poses from X0 (excluded) to X1 (included): straight line and slerp,
    spaced about ``step`` (m) or 10 deg apart."""
    d = float(np.linalg.norm(X1.translation() - X0.translation()))
    R0, R1 = X0.rotation(), X1.rotation()
    turn = R0.InvertAndCompose(R1).ToAngleAxis()   # R0^T R1, in X0's frame
    angle = turn.angle()
    n = max(1, int(np.ceil(max(d / step, angle / np.deg2rad(10)))))
    out = []
    for k in range(1, n + 1):
        f = k / n
        # the geodesic (slerp) from R0 to R1: R0 turned by f * angle about the axis
        R = R1 if k == n else R0.multiply(RotationMatrix(AngleAxis(f * angle, turn.axis())))
        out.append(RigidTransform(R, (1 - f) * X0.translation() + f * X1.translation()))
    return out


class ApproachBlocked(RuntimeError):
    """A solved pose of an approach failed the caller's check
    (``PlanApproach``'s ``check``); the message is the check's reason."""


def IkPath(robot, poses: list[RigidTransform], seed: np.ndarray, half_opening: float,
           check=None, memo: dict | None = None) -> list[np.ndarray]:
    """IK for each pose, each warm-started from the previous solution (the
    first may use random restarts). Raises MotionError naming the pose.
    ``check(k, q) -> str`` runs on each solution as it comes; a non-empty
    reason stops the path (``ApproachBlocked``). ``memo`` (a dict) keeps
    the solutions by pose and seed: the same request is solved once."""
    out = []
    for k, X in enumerate(poses):
        key = None if memo is None else (X.GetAsMatrix4().tobytes(),
                                         np.asarray(seed, float).tobytes(),
                                         float(half_opening), k == 0)
        r = None if key is None else memo.get(key)
        if r is None:
            r = robot.Ik(X, seed, half_opening, multistart=(k == 0))
            if key is not None:
                memo[key] = r
        if not r.success:
            raise MotionError(f"IK failed for the TCP pose at {X.translation().round(3)}: "
                              f"{r.reason}", index=k)
        if check is not None:
            why = check(k, r.q)
            if why:
                raise ApproachBlocked(why)
        out.append(r.q)
        seed = r.q
    return out


@dc.dataclass
class ApproachPlan:
    """Joint waypoints: ``via`` (joint move from the current joints), then
    Cartesian segments ``to_ready``, ``to_pregrasp``, ``to_grasp``."""
    via: np.ndarray
    to_ready: list[np.ndarray]
    to_pregrasp: list[np.ndarray]
    to_grasp: list[np.ndarray]
    opening: float = 0.0   # gripper opening (m) along the approach
    ready_extra: float = 0.0   # the ready pose's distance (m) behind the pre-grasp


def PlanApproach(robot, X_WT_grasp: RigidTransform, q_current: np.ndarray,
                 toward_camera_W: np.ndarray, pregrasp_distance: float = 0.05,
                 pregrasp_opening: float = 0.02, ready_extra: float = 0.08,
                 via_offset: float = 0.12, check=None, memo: dict | None = None
                 ) -> ApproachPlan:
    """The approach to a grasp: the pre-grasp sits ``pregrasp_distance``
    back along the approach axis (TCP z), a ready pose ``ready_extra``
    further back, and a via point ``via_offset`` from the ready pose toward
    the camera side of the leaf (``toward_camera_W``). Raises
    ``MotionError`` (with ``staging`` True when the pose without IK lies
    beyond the pre-grasp). ``check(segment, q) -> str`` runs on each pose
    as it is solved, from the grasp outward (``segment`` "grasp": the
    final approach after the pre-grasp; "staging": the pre-grasp, the ready
    pose, the via point and the lines between them); a reason stops the
    planning (``ApproachBlocked``). ``memo``: see ``IkPath``."""
    R = X_WT_grasp.rotation()
    z = R.col(2)

    def back(d):
        return RigidTransform(R, X_WT_grasp.translation() - d * z)
    X_pre, X_ready = back(pregrasp_distance), back(pregrasp_distance + ready_extra)
    X_via = RigidTransform(R, X_ready.translation() + via_offset * np.asarray(toward_camera_W))
    grasp_poses = CartesianPath(X_pre, X_WT_grasp, 0.0125)
    pre_poses = CartesianPath(X_ready, X_pre, 0.02)
    ready_poses = CartesianPath(X_via, X_ready, 0.02)
    backwards = ([X_WT_grasp] + grasp_poses[::-1][1:] + [X_pre] + pre_poses[::-1][1:]
                 + [X_ready] + ready_poses[::-1][1:] + [X_via])
    n_g = len(grasp_poses)
    check_k = None if check is None else (
        lambda k, q: check("grasp" if k < n_g else "staging", q))
    try:
        chain = IkPath(robot, backwards, q_current, 0.5 * pregrasp_opening, check_k,
                       memo)[::-1]
    except MotionError as err:      # backwards[len(grasp_poses)] is the pre-grasp
        err.staging = err.index is not None and err.index > len(grasp_poses)
        raise
    n_r, n_p = len(ready_poses), len(pre_poses)
    return ApproachPlan(via=chain[0], to_ready=chain[1:1 + n_r],
                        to_pregrasp=chain[1 + n_r:1 + n_r + n_p],
                        to_grasp=chain[1 + n_r + n_p:], opening=float(pregrasp_opening),
                        ready_extra=float(ready_extra))


def PlanPull(robot, X_WT_start: RigidTransform, dp_W: np.ndarray, q_start: np.ndarray,
             step: float = 0.01) -> list[np.ndarray]:
    """Joint waypoints moving the TCP by ``dp_W`` in a straight line, same
    orientation, about ``step`` apart (gripper closed)."""
    dp = np.asarray(dp_W, float)
    n = max(2, int(np.ceil(np.linalg.norm(dp) / step)))
    poses = [RigidTransform(X_WT_start.rotation(), X_WT_start.translation() + dp * k / n)
             for k in range(1, n + 1)]
    out, seed = [], q_start
    for X in poses:
        r = robot.Ik(X, seed, 0.0)
        if not r.success:
            raise MotionError(f"IK failed along the pull at {X.translation().round(3)}")
        out.append(r.q)
        seed = r.q
    return out


def PlanActionPath(robot, action, q_start: np.ndarray, step: float = 0.01
                   ) -> list[np.ndarray]:
    """Joint waypoints for an action's motion from the grasp (gripper
    closed): the straight pull or the arc about the hinge
    (``Action.Poses``), each IK warm-started from the previous. Raises
    ``MotionError`` when a waypoint has no IK solution or the arm would hit
    itself there."""
    out, seed = [], q_start
    for p, R in action.Poses(step):
        r = robot.Ik(RigidTransform(RotationMatrix(R), p), seed, 0.0)
        if not r.success:
            raise MotionError(f"IK failed along the {action.family} at {np.round(p, 3)}")
        pair = robot.SelfCollision(r.q)
        if pair:
            raise MotionError(f"the robot would hit itself ({pair}) along the "
                              f"{action.family} at {np.round(p, 3)}")
        out.append(r.q)
        seed = r.q
    return out


def TimeJointPath(t0: float, q0: np.ndarray, waypoints: list[np.ndarray],
                  speed_fraction: float = 0.5, min_segment: float = 0.25,
                  duration: float | None = None) -> PiecewisePolynomial:
    """Cubic joint trajectory from ``q0`` through ``waypoints`` starting at
    ``t0``, each segment long enough that no joint exceeds
    ``speed_fraction`` x the UR5 velocity limit (cubic peak speed is 1.5x
    the mean); with ``duration``, the segments are stretched to fill it."""
    qs = [np.asarray(q0, float)] + [np.asarray(q, float) for q in waypoints]
    seg = [max(min_segment, 1.5 * float(np.abs(b - a).max())
               / (speed_fraction * UR5_VELOCITY_LIMIT)) for a, b in zip(qs[:-1], qs[1:])]
    if duration is not None and sum(seg) < duration:
        seg = [s * duration / sum(seg) for s in seg]
    times = t0 + np.r_[0.0, np.cumsum(seg)]
    if len(qs) == 2:
        return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
            times, np.array(qs).T, np.zeros(6), np.zeros(6))
    return PiecewisePolynomial.CubicShapePreserving(times, np.array(qs).T, True)
