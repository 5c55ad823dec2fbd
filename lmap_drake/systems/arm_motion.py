"""Joint trajectories of the ``ArmController``'s motions, without a Diagram:
the joint paths of a planned candidate (approach, then the action's
motion), and their timing under the speed bounds (the UR5 velocity limit,
``planner.speed_scale``, the approach's TCP pace, the pull speed). Every
trajectory goes through the optional ``trajectory_check`` (e.g. the
hardware ``SafetyChecker``) before it is returned. World frame W, metres,
radians, seconds.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.planning.motion import PlanActionPath, PlanApproach, TimeJointPath
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.robot import UR5_VELOCITY_LIMIT

ROTATION_SPEED = 0.5  # rad/s: the fastest the held leaf is turned (an arc or a twist)


class Refused(Exception):
    """A trajectory refused by ``trajectory_check``."""


class ArmMotions:
    """Plans and times the arm's joint paths. ``planner`` is the scenario's
    planner section (``speed_scale``, ``approach_speed``,
    ``pregrasp_distance``, ``pregrasp_opening``); ``pull_speed`` (m/s,
    before ``speed_scale``) paces the action's motion; ``max_joint_speed``
    (rad/s) bounds every joint (trajectories stay under 95 % of it);
    ``trajectory_check(times, qs)`` raises to refuse one (-> ``Refused``)."""

    def __init__(self, planner, robot: RobotModel, pull_speed: float = 0.03,
                 max_joint_speed: float = UR5_VELOCITY_LIMIT,
                 trajectory_check: Callable | None = None):
        self._planner = planner
        self._robot = robot
        self.speed_scale = float(planner.speed_scale)
        self._pull_speed = pull_speed * self.speed_scale
        self._approach_speed = planner.approach_speed * self.speed_scale
        self._pregrasp_opening = planner.pregrasp_opening
        self._max_joint_speed = max_joint_speed
        self._check = trajectory_check

    def Approach(self, c, q_hold: np.ndarray):
        """The approach (``planning.motion.ApproachPlan``) to candidate
        ``c``'s grasp from the held joints: the candidate's own, or planned
        here. Raises ``MotionError``."""
        X_WT = RigidTransform(RotationMatrix(c.action.R_WG), c.action.p_WG)
        normal = c.action.R_WG[:, 1]
        return c.approach or PlanApproach(self._robot, X_WT, q_hold, normal,
                                          self._planner.pregrasp_distance,
                                          self._pregrasp_opening)

    def ActionPath(self, action, q_grasp: np.ndarray) -> list:
        """Joint waypoints of ``action``'s motion from the grasp joints.
        Raises ``MotionError``."""
        return PlanActionPath(self._robot, action, q_grasp)

    def TimePath(self, t: float, q0, waypoints: list, fraction: float,
                 duration: float | None = None, min_segment: float = 0.05,
                 rest_at_first: bool = False):
        """A joint trajectory from ``q0`` through ``waypoints`` at
        ``fraction`` x speed_scale of the UR5 velocity limit, retimed so that
        no joint exceeds 95 % of ``max_joint_speed``; then checked."""
        limit = 0.95 * self._max_joint_speed
        f = min(fraction * self.speed_scale, limit / UR5_VELOCITY_LIMIT)
        traj = TimeJointPath(t, q0, waypoints, f, min_segment, duration, rest_at_first)
        for _ in range(4):
            times = np.arange(traj.start_time(), traj.end_time() + 0.005, 0.005)
            qs = np.array([traj.value(min(x, traj.end_time())).ravel() for x in times])
            speed = np.abs(np.diff(qs, axis=0)).max() / 0.005 if len(qs) > 1 else 0.0
            if speed <= limit:
                break
            stretched = (traj.end_time() - t) * speed / limit * 1.02
            traj = TimeJointPath(t, q0, waypoints, f, min_segment, stretched, rest_at_first)
        if self._check is not None:
            period = 0.01
            times = np.arange(traj.start_time(), traj.end_time() + 0.5 * period, period)
            times = np.minimum(times, traj.end_time())
            qs = np.array([traj.value(x).ravel() for x in times])
            try:
                self._check(times, qs)
            except Exception as err:  # noqa: BLE001 - SafetyRefusal and kin
                raise Refused(" ".join(str(err).split())) from err
        return traj

    def ApproachTiming(self, q0: np.ndarray, waypoints: list, speed: float | None = None
                       ) -> dict:
        """``TimePath`` arguments for the final approach (pre-grasp <->
        grasp, from ``q0``): each step at the TCP speed ``speed`` (m/s;
        None: ``planner.approach_speed``; its length from the TCP poses: the
        steps ``StraightenStep`` inserted near a wrist singularity are
        shorter) unless a joint would exceed 0.5 of its velocity limit,
        then as fast as that allows."""
        p = [self._robot.TcpPose(q, 0.0).translation() for q in [q0] + list(waypoints)]
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        v = self._approach_speed if speed is None else float(speed)
        return dict(fraction=0.5, min_segment=np.maximum(0.05, steps / v))

    @property
    def pull_speed(self) -> float:
        """m/s: the TCP's pace moving a held leaf."""
        return self._pull_speed

    def MotionDuration(self, actions: list) -> float:
        """Seconds to move the TCP along ``actions`` at the pull speed, and to
        turn it at most ``ROTATION_SPEED`` (a twist turns in place), >= 1 s."""
        return max(1.0, sum(max(a.path_length / self._pull_speed,
                                abs(a.angle) / (ROTATION_SPEED * self.speed_scale))
                            for a in actions))
