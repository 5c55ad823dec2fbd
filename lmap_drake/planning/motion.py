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

from lmap_drake.robot import UR5_VELOCITY_LIMIT


class MotionError(RuntimeError):
    """No joint path for a requested Cartesian motion (IK failed).
    ``index``: the failing pose's index in the requested list (None when
    unknown); ``staging``: in an approach, the failure lies beyond the
    pre-grasp (the ready pose, the via point or the line between them)."""

    def __init__(self, message: str, index: int | None = None, staging: bool = False):
        super().__init__(message)
        self.index, self.staging = index, staging


def InterpolatePose(X0: RigidTransform, X1: RigidTransform, f: float) -> RigidTransform:
    """The pose a fraction ``f`` of the way from X0 to X1: the straight line
    and the geodesic (slerp), X0's rotation turned by f x the angle of R0^T
    R1 about its axis."""
    turn = X0.rotation().InvertAndCompose(X1.rotation()).ToAngleAxis()
    R = X0.rotation().multiply(RotationMatrix(AngleAxis(f * turn.angle(), turn.axis())))
    return RigidTransform(R, (1 - f) * X0.translation() + f * X1.translation())


def CartesianPath(X0: RigidTransform, X1: RigidTransform, step: float = 0.02
                  ) -> list[RigidTransform]:
    """Poses from X0 (excluded) to X1 (included): straight line and slerp,
    spaced about ``step`` (m) or 10 deg apart."""
    d = float(np.linalg.norm(X1.translation() - X0.translation()))
    angle = X0.rotation().InvertAndCompose(X1.rotation()).ToAngleAxis().angle()
    n = max(1, int(np.ceil(max(d / step, angle / np.deg2rad(10)))))
    return [InterpolatePose(X0, X1, k / n) for k in range(1, n)] + [X1]


class ApproachBlocked(RuntimeError):
    """A solved pose of an approach failed the caller's check
    (``PlanApproach``'s ``check``); the message is the check's reason."""


# How far the TCP may leave a Cartesian line between two joint waypoints
# (joint interpolation is not a line): near a wrist singularity (wrist 2
# near 0) one 12.5 mm step of an approach swung wrists 1 and 3 by 1 rad and
# the open pads swept 1.9 cm sideways into the leaf they were to grasp
# (``random_multi_9191_002``). Such a step is cut into 2, 4, ... shorter
# ones (``StraightenStep``) until each keeps these.
PATH_TOLERANCE = 0.002        # m, of the TCP from the line
PATH_ANGLE_TOLERANCE = 3.0    # deg, of the TCP's orientation from the slerp
PATH_MAX_BISECTIONS = 6       # halvings: a 12.5 mm step down to 0.2 mm


def PathDeviation(robot, q0: np.ndarray, q1: np.ndarray, X0: RigidTransform,
                  X1: RigidTransform, half_opening: float,
                  fractions=(0.25, 0.5, 0.75)) -> tuple[float, float]:
    """How far the TCP leaves the Cartesian segment X0 -> X1 along the joint
    line q0 -> q1: (largest distance (m) from the segment, largest angle
    (deg) from the slerp at the same fraction)."""
    a, b = X0.translation(), X1.translation()
    ab = b - a
    L2 = float(ab @ ab)
    dist = angle = 0.0
    for f in fractions:
        X = robot.TcpPose(np.asarray(q0) + f * (np.asarray(q1) - np.asarray(q0)), half_opening)
        p = X.translation()
        u = 0.0 if L2 == 0.0 else float(np.clip((p - a) @ ab / L2, 0.0, 1.0))
        dist = max(dist, float(np.linalg.norm(p - (a + u * ab))))
        R_err = InterpolatePose(X0, X1, f).rotation().InvertAndCompose(X.rotation())
        angle = max(angle, float(np.degrees(R_err.ToAngleAxis().angle())))
    return dist, angle


def StraightenStep(robot, X0: RigidTransform, X1: RigidTransform, q0: np.ndarray,
                   q1: np.ndarray, half_opening: float, check=None
                   ) -> tuple[list[np.ndarray], np.ndarray]:
    """(joint waypoints to insert between ``q0`` at X0 and the step's end,
    the end's joints) such that the TCP keeps ``PATH_TOLERANCE`` and
    ``PATH_ANGLE_TOLERANCE`` of the Cartesian segment X0 -> X1: ([], q1)
    when the joint line q0 -> q1 already does. Otherwise the segment is cut
    into 2, 4, ... equal steps solved by continuation from ``q0`` (each
    warm-started from the last, so the IK follows q0's branch through a
    fast wrist turn instead of jumping to another one at X1) until every
    step keeps the tolerances; the end's joints are then the
    continuation's. Raises ``MotionError`` when ``PATH_MAX_BISECTIONS``
    halvings do not straighten it or a pose has no IK solution;
    ``check(q) -> str`` runs on each inserted pose (``ApproachBlocked``)."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    dist, angle = PathDeviation(robot, q0, q1, X0, X1, half_opening)
    if dist <= PATH_TOLERANCE and angle <= PATH_ANGLE_TOLERANCE:
        return [], q1
    for level in range(1, PATH_MAX_BISECTIONS + 1):
        n = 2 ** level
        poses = [InterpolatePose(X0, X1, i / n) for i in range(1, n)] + [X1]
        qs, seed = [], q0
        for X in poses:
            r = robot.Ik(X, seed, half_opening)
            if not r.success:
                raise MotionError(f"IK failed for the TCP pose at {X.translation().round(3)}: "
                                  f"{r.reason}")
            qs.append(np.asarray(r.q, float))
            seed = r.q
        dist, angle = map(max, zip(*(PathDeviation(robot, a, b, Xa, Xb, half_opening)
                                     for a, b, Xa, Xb in zip([q0] + qs[:-1], qs,
                                                             [X0] + poses[:-1], poses))))
        if dist <= PATH_TOLERANCE and angle <= PATH_ANGLE_TOLERANCE:
            if check is not None:
                for q in qs[:-1]:
                    why = check(q)
                    if why:
                        raise ApproachBlocked(why)
            return qs[:-1], qs[-1]
    raise MotionError(f"the joint path leaves the Cartesian line by {100 * dist:.1f} cm and "
                      f"{angle:.0f} deg near {X1.translation().round(3)} however finely it is "
                      f"solved (a wrist singularity)")


def IkPath(robot, poses: list[RigidTransform], seed: np.ndarray, half_opening: float,
           check=None, memo: dict | None = None, groups: bool = False) -> list:
    """IK for each pose, each warm-started from the previous solution (the
    first may use random restarts), straightened by ``StraightenStep``
    (waypoints inserted between consecutive poses, the pose's own joints
    then those of the continuation). Raises MotionError naming the pose.
    ``check(k, q) -> str`` runs on each solution as it comes (an inserted
    one between poses k - 1 and k as ``check(k - 1, q)``); a non-empty
    reason stops the path (``ApproachBlocked``). ``memo`` (a dict) keeps
    the solutions by pose and seed: the same request is solved once, for
    any ``half_opening`` (the ``tcp`` frame sits on the gripper's base, not
    on a finger: the IK and the path's deviation do not depend on it). With
    ``groups``, one list per pose: the waypoints inserted before it, then
    its own."""
    out = []
    q_prev = None
    for k, X in enumerate(poses):
        key = None if memo is None else (X.GetAsMatrix4().tobytes(),
                                         np.asarray(seed, float).tobytes(), k == 0)
        got = None if key is None else memo.get(key)
        if got is None:
            r = robot.Ik(X, seed, half_opening, multistart=(k == 0))
            if not r.success:
                raise MotionError(f"IK failed for the TCP pose at {X.translation().round(3)}: "
                                  f"{r.reason}", index=k)
            got = ([], np.asarray(r.q, float))
            if q_prev is not None:
                try:
                    got = StraightenStep(robot, poses[k - 1], X, q_prev, r.q, half_opening)
                except MotionError as err:
                    raise MotionError(str(err), index=k) from err
            if key is not None:
                memo[key] = got
        inserted, q = got
        if check is not None:
            for q_in in inserted:
                why = check(k - 1, q_in)
                if why:
                    raise ApproachBlocked(why)
            why = check(k, q)
            if why:
                raise ApproachBlocked(why)
        out.append(list(inserted) + [q])
        q_prev = seed = q
    return out if groups else [q for g in out for q in g]


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
    # the largest push (m) of another leaf along it (``planner.max_brush_displacement``)
    brush_displacement: float = 0.0


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
        G = IkPath(robot, backwards, q_current, 0.5 * pregrasp_opening, check_k, memo,
                   groups=True)
    except MotionError as err:      # backwards[len(grasp_poses)] is the pre-grasp
        err.staging = err.index is not None and err.index > len(grasp_poses)
        raise
    # Forward, each pose with the waypoints inserted on the way to it (solved
    # backwards: those before the next pose of the backward chain, reversed).
    N = len(G) - 1
    chain = [G[N][-1:]] + [G[k + 1][:-1][::-1] + G[k][-1:] for k in range(N - 1, -1, -1)]
    n_r, n_p = len(ready_poses), len(pre_poses)

    def flat(items):
        return [q for item in items for q in item]
    return ApproachPlan(via=chain[0][0], to_ready=flat(chain[1:1 + n_r]),
                        to_pregrasp=flat(chain[1 + n_r:1 + n_r + n_p]),
                        to_grasp=flat(chain[1 + n_r + n_p:]), opening=float(pregrasp_opening),
                        ready_extra=float(ready_extra))


def PlanPull(robot, X_WT_start: RigidTransform, dp_W: np.ndarray, q_start: np.ndarray,
             step: float = 0.01) -> list[np.ndarray]:
    """Joint waypoints moving the TCP by ``dp_W`` in a straight line, same
    orientation, about ``step`` apart (gripper closed), with those
    ``StraightenStep`` inserts."""
    dp = np.asarray(dp_W, float)
    n = max(2, int(np.ceil(np.linalg.norm(dp) / step)))
    poses = [RigidTransform(X_WT_start.rotation(), X_WT_start.translation() + dp * k / n)
             for k in range(1, n + 1)]
    out, seed, X_prev = [], np.asarray(q_start, float), X_WT_start
    for X in poses:
        r = robot.Ik(X, seed, 0.0)
        if not r.success:
            raise MotionError(f"IK failed along the pull at {X.translation().round(3)}")
        inserted, q = StraightenStep(robot, X_prev, X, seed, r.q, 0.0)
        out += inserted + [q]
        seed, X_prev = q, X
    return out


def PlanActionPath(robot, action, q_start: np.ndarray, step: float = 0.01
                   ) -> list[np.ndarray]:
    """Joint waypoints for an action's motion from the grasp (gripper
    closed): the straight pull or the arc about the hinge
    (``Action.Poses``), each IK warm-started from the previous, with those
    ``StraightenStep`` inserts. Raises
    ``MotionError`` when a waypoint has no IK solution or the arm would hit
    itself there."""
    def self_collision(q):
        pair = robot.SelfCollision(q)
        return f"the robot would hit itself ({pair}) along the {action.family}" if pair else ""
    out, seed = [], np.asarray(q_start, float)
    X_prev = robot.TcpPose(seed)
    for p, R in action.Poses(step):
        X = RigidTransform(RotationMatrix(R), p)
        r = robot.Ik(X, seed, 0.0)
        if not r.success:
            raise MotionError(f"IK failed along the {action.family} at {np.round(p, 3)}")
        try:
            inserted, q = StraightenStep(robot, X_prev, X, seed, r.q, 0.0, self_collision)
        except ApproachBlocked as err:
            raise MotionError(f"{err} near {np.round(p, 3)}") from err
        why = self_collision(q)
        if why:
            raise MotionError(f"{why} at {np.round(p, 3)}")
        out += inserted + [q]
        seed, X_prev = q, X
    return out


def TimeJointPath(t0: float, q0: np.ndarray, waypoints: list[np.ndarray],
                  speed_fraction: float = 0.5, min_segment: float = 0.25,
                  duration: float | None = None, rest_at_first: bool = False
                  ) -> PiecewisePolynomial:
    """Cubic joint trajectory from ``q0`` through ``waypoints`` starting at
    ``t0``, each segment long enough that no joint exceeds
    ``speed_fraction`` x the UR5 velocity limit (cubic peak speed is 1.5x
    the mean) and none shorter than ``min_segment`` (s; one for all or one
    per segment); with ``duration``, the segments are stretched to fill it.
    ``rest_at_first``: the arm comes to rest at the first waypoint, so the
    move there stays on the straight joint line (a free move checked on
    that line, ``approach.FreeMoveFractions``); through the first waypoint
    each joint's speed would come from its next segments and the joints
    would leave the line (0.82 rad in ``random_multi_2525_007``)."""
    qs = [np.asarray(q0, float)] + [np.asarray(q, float) for q in waypoints]
    mins = np.broadcast_to(np.asarray(min_segment, float), (len(qs) - 1,))
    seg = [max(float(m), 1.5 * float(np.abs(b - a).max()) / (speed_fraction * UR5_VELOCITY_LIMIT))
           for m, a, b in zip(mins, qs[:-1], qs[1:])]
    if duration is not None and sum(seg) < duration:
        seg = [s * duration / sum(seg) for s in seg]
    times = t0 + np.r_[0.0, np.cumsum(seg)]
    if rest_at_first and len(qs) > 2:
        first = _RestToRest(times[:2], qs[:2])
        first.ConcatenateInTime(_RestToRest(times[1:], qs[1:]))
        return first
    return _RestToRest(times, qs)


def _RestToRest(times: np.ndarray, qs: list[np.ndarray]) -> PiecewisePolynomial:
    """Cubic through joint vectors ``qs`` at ``times``, at rest at both ends
    (two points: the straight joint line; more: shape-preserving)."""
    if len(qs) == 2:
        return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
            times, np.array(qs).T, np.zeros(6), np.zeros(6))
    return PiecewisePolynomial.CubicShapePreserving(times, np.array(qs).T, True)
