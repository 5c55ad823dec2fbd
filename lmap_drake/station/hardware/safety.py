"""Command checks that stand between a planner and the real UR5.

Functional core (numpy only, no hardware, no Drake systems): every joint
command for the real arm goes through ``SafetyChecker.Check`` before it can
reach the ur_rtde client. A refused command raises a subclass of
``SafetyRefusal`` with a message that names the joint or axis, the value and
the limit.

Checks:

- finite, 6 values;
- joint limits of the UR5 (all joints +-2 pi, the elbow +-pi; read from the
  URDF through ``MakeControllerPlant``);
- joint speed: ``|q - q_prev| / dt <= joint_speed_limit`` per joint;
- workspace: every moving link inside the configured box in the robot base
  frame -- the elbow, the three wrists and the flange (origins of UR5 DH
  frames 2-6) and the TCP (the flange to ``tcp`` offset of the 2F-85 model,
  0.144 m along the flange z axis). So an elbow below the box's floor (e.g.
  below the table the robot stands on) is refused even when the TCP is in.
"""
from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform

from lmap_drake.station.hardware_config import UrConfig
from lmap_drake.robot import (UR5_JOINTS, UR5_VELOCITY_LIMIT, MakeControllerPlant,
                                      Ur5DhForwardKinematics, Ur5DhFrames)

# What CheckWorkspace checks: DH frame index -> name (then the TCP).
WORKSPACE_LINKS = {2: "elbow", 3: "wrist 1", 4: "wrist 2", 5: "wrist 3", 6: "flange"}


class HardwareAbort(RuntimeError):
    """The hardware episode must stop (protective or emergency stop, lost
    connection, or a refused command). The arm has been told to stop."""


class SafetyRefusal(HardwareAbort):
    """A command was refused before it reached the robot."""


class NonFiniteCommandRefusal(SafetyRefusal):
    """The command has the wrong size or holds NaN / inf."""


class JointLimitRefusal(SafetyRefusal):
    """A joint command lies outside the UR5 joint limits."""


class VelocityLimitRefusal(SafetyRefusal):
    """A joint command would move a joint faster than the speed limit."""


class WorkspaceRefusal(SafetyRefusal):
    """A joint command puts a link or the TCP outside the workspace box."""


_LIMITS_CACHE: dict = {}


def Ur5JointLimitsAndTcpOffset() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, upper) joint position limits (rad) of the six UR5 joints and
    the 4x4 pose of the gripper's ``tcp`` frame in the ``flange`` frame, read
    from the URDF models (cached)."""
    if not _LIMITS_CACHE:
        plant, ur5, _ = MakeControllerPlant(RigidTransform())
        lower, upper = [], []
        for name in UR5_JOINTS:
            joint = plant.GetJointByName(name, ur5)
            lower.append(joint.position_lower_limits()[0])
            upper.append(joint.position_upper_limits()[0])
        context = plant.CreateDefaultContext()
        X_FT = plant.CalcRelativeTransform(context, plant.GetFrameByName("flange"),
                                           plant.GetFrameByName("tcp"))
        _LIMITS_CACHE["value"] = (np.array(lower), np.array(upper), X_FT.GetAsMatrix4())
    lower, upper, X_FT = _LIMITS_CACHE["value"]
    return lower.copy(), upper.copy(), X_FT.copy()


def TcpPositionInBase(q: np.ndarray) -> np.ndarray:
    """Position (m) of the 2F-85 ``tcp`` frame in the UR base frame."""
    _, _, X_FT = Ur5JointLimitsAndTcpOffset()
    return (Ur5DhForwardKinematics(np.asarray(q, dtype=float)) @ X_FT)[:3, 3]


class SafetyChecker:
    """Checks joint commands against the limits of one ``UrConfig``."""

    def __init__(self, config: UrConfig):
        if not 0.0 < config.joint_speed_limit <= UR5_VELOCITY_LIMIT:
            raise ValueError(f"joint_speed_limit {config.joint_speed_limit} rad/s must be in "
                             f"(0, {UR5_VELOCITY_LIMIT:.4f}] (the UR5 joint limit)")
        self.lower, self.upper, self.X_FT = Ur5JointLimitsAndTcpOffset()
        self.speed_limit = float(config.joint_speed_limit)
        self.box_min = np.asarray(config.workspace_min, dtype=float)
        self.box_max = np.asarray(config.workspace_max, dtype=float)

    def CheckFinite(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise NonFiniteCommandRefusal(
                f"refused UR5 command {q.tolist()}: need 6 finite joint values (rad)")
        return q

    def CheckJointLimits(self, q) -> None:
        q = self.CheckFinite(q)
        bad = np.flatnonzero((q < self.lower) | (q > self.upper))
        if bad.size:
            i = int(bad[0])
            raise JointLimitRefusal(
                f"refused UR5 command: {UR5_JOINTS[i]} = {q[i]:.4f} rad is outside its limits "
                f"[{self.lower[i]:.4f}, {self.upper[i]:.4f}] rad")

    def CheckVelocity(self, q, q_prev, dt: float) -> None:
        q = self.CheckFinite(q)
        q_prev = self.CheckFinite(q_prev)
        if not dt > 0:
            raise VelocityLimitRefusal(f"refused UR5 command: time step {dt} s must be > 0")
        speed = np.abs(q - q_prev) / dt
        i = int(np.argmax(speed))
        if speed[i] > self.speed_limit * (1.0 + 1e-9):
            raise VelocityLimitRefusal(
                f"refused UR5 command: {UR5_JOINTS[i]} would move {abs(q[i] - q_prev[i]):.4f} rad "
                f"in {dt:.4f} s = {speed[i]:.3f} rad/s, above the joint speed limit "
                f"{self.speed_limit:.3f} rad/s (hardware.ur.joint_speed_limit)")

    def CheckWorkspace(self, q) -> None:
        q = self.CheckFinite(q)
        frames = Ur5DhFrames(q)
        points = [(name, frames[i][:3, 3]) for i, name in WORKSPACE_LINKS.items()]
        points.append(("TCP", (frames[6] @ self.X_FT)[:3, 3]))
        for name, p in points:
            bad = np.flatnonzero((p < self.box_min) | (p > self.box_max))
            if bad.size:
                axis = "xyz"[int(bad[0])]
                raise WorkspaceRefusal(
                    f"refused UR5 command: the {name} at {np.round(p, 4).tolist()} m (robot "
                    f"base frame) is outside the workspace box on {axis}: "
                    f"[{self.box_min.tolist()}, {self.box_max.tolist()}] m "
                    f"(hardware.ur.workspace_min/max)")

    def Check(self, q, q_prev=None, dt: float | None = None) -> np.ndarray:
        """All checks; returns q as a float array, raises SafetyRefusal.
        The speed check runs when ``q_prev`` and ``dt`` are given."""
        q = self.CheckFinite(q)
        self.CheckJointLimits(q)
        if q_prev is not None and dt is not None:
            self.CheckVelocity(q, q_prev, dt)
        self.CheckWorkspace(q)
        return q

    def CheckTrajectory(self, times, qs) -> None:
        """Checks every sample of a joint trajectory and the speed between
        consecutive samples (``qs`` is N x 6)."""
        qs = np.asarray(qs, dtype=float)
        for k in range(len(times)):
            if k == 0:
                self.Check(qs[k])
            else:
                self.Check(qs[k], qs[k - 1], float(times[k] - times[k - 1]))
