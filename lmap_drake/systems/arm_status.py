"""The ``ArmController``'s state and options, without a Diagram: the
modes, ``ControllerStatus`` (the abstract state, also the ``status``
output: mode, message, plans, estimates, per-stage seconds, one record per
fruit handled) and ``ControllerOptions``.

Options (``ControllerOptions``): the start joints and opening (on hardware:
the measured ones, so nothing moves at start), whether a grasp needs the
simulation's acknowledgement, ``plan_only`` (stop in ``planned`` after the
plan), ``confirm`` (wait in ``confirm_wait`` until the operator answers),
the joint speed bound (rad/s; trajectories are retimed to stay under 95 %
of it), ``planner.speed_scale`` (all motions), and ``trajectory_check``
(e.g. the hardware ``SafetyChecker``): every trajectory is sampled and
checked before it starts, and at planning time the whole pregrasp ->
approach -> pull motion is checked before anything moves.
"""
from __future__ import annotations

import copy
import dataclasses as dc
from typing import Callable

import numpy as np

from lmap_drake.planning.result import PlanResult
from lmap_drake.robot import UR5_VELOCITY_LIMIT
from lmap_drake.types import SceneEstimate

MODES = ("idle", "capture", "plan_requested", "confirm_wait", "pregrasp", "approach",
         "close_gripper", "grasp_wait", "pull", "hold", "observe", "release", "retreat",
         "back_off", "done", "planned", "aborted")
FINISHED = ("done", "planned", "aborted")
STALL_WINDOW = 0.3   # s: the pads count as stalled on the leaf after this long without closing


@dc.dataclass
class ControllerOptions:
    """How the controller drives its station (see the module docstring)."""
    initial_q: np.ndarray | None = None        # None: robot.initial_q
    initial_gripper: float | None = None       # None: robot.initial_gripper_width
    grasp_ack_required: bool = True            # simulation: the runner makes the grasp
    plan_only: bool = False
    confirm: bool = False
    max_joint_speed: float = UR5_VELOCITY_LIMIT
    trajectory_check: Callable | None = None   # (times, qs) -> None or raises
    release: bool = True                       # release the leaf and retreat at the end


@dc.dataclass
class ControllerStatus:
    """The controller's abstract state (copied with the Context)."""
    mode: str = "idle"
    t_mode: float = 0.0
    message: str = ""
    q_hold: np.ndarray = dc.field(default_factory=lambda: np.zeros(6))
    gripper_cmd: float = 0.085
    gripper_ramp: tuple | None = None   # (t0, w0, w1, speed m/s) while closing
    trajectory: object = None           # PiecewisePolynomial or None
    segments: list = dc.field(default_factory=list)   # pending (waypoints, fraction, duration)
    pull_path: list = dc.field(default_factory=list)
    captures: int = 0
    grasp_acknowledged: bool = False
    confirmed: bool | None = None       # the operator's answer in confirm_wait
    confirm_note: str = ""
    plan: PlanResult | None = None
    initial_estimate: SceneEstimate | None = None
    final_estimate: SceneEstimate | None = None
    stage_seconds: dict = dc.field(default_factory=dict)
    mode_log: list = dc.field(default_factory=list)
    failed_stage: str = ""              # set when a stage raised (status stage_error)
    pregrasp_path: list = dc.field(default_factory=list)   # joint waypoints to the pre-grasp
    pregrasp_opening: float = 0.0
    grasp_path: list = dc.field(default_factory=list)       # pre-grasp -> grasp joints
    released: bool = False              # the gripper was told to let the leaf go
    grasp_missed: str = ""              # hardware: why the closed gripper holds nothing
    t_released: float = 0.0
    grip_history: list = dc.field(default_factory=list)   # (t, opening) while closing
    continuations: list = dc.field(default_factory=list)  # PlanResults of the re-plans
    motion_paths: list = dc.field(default_factory=list)   # joint waypoints of each motion
    pending_motion: tuple | None = None  # (plan, joint path) waiting for the operator
    replan_log: list = dc.field(default_factory=list)     # "status: message" per re-plan
    replan_results: list = dc.field(default_factory=list)  # every re-plan's PlanResult
    # planner.targets: all -- one record per fruit handled (see ArmSequence._EndTarget)
    targets: list = dc.field(default_factory=list)
    t_target: float = 0.0               # when the current target's plan was requested
    captures_plan: int = 0              # captures when it was planned (its view: this - 1)
    # the force guard (planner.max_pull_force): the wrist force (N, station
    # frame) at the pre-grasp pose, the largest rise above it while
    # moving the held leaf (N), and why the guard stopped a motion ("": never)
    force_zero: np.ndarray | None = None
    force_peak: float = 0.0
    force_stop: str = ""
    force_stops: list = dc.field(default_factory=list)   # every stop of the episode
    retreat_out: list = dc.field(default_factory=list)   # the retreat's way out of the plant
    retreat_zero: np.ndarray | None = None   # the wrist force (N) when the retreat began
    retreat_peak: float = 0.0   # N: the largest rise on the ways out of the plant
    # (t s, rise N, "pull" | "retreat") at every guarded update: the picture
    force_trace: list = dc.field(default_factory=list)

    def __deepcopy__(self, memo):
        # Plans and estimates are read-only records: share them.
        out = copy.copy(self)
        out.q_hold = self.q_hold.copy()
        out.segments = list(self.segments)
        out.pull_path = list(self.pull_path)
        out.stage_seconds = dict(self.stage_seconds)
        out.mode_log = list(self.mode_log)
        out.grip_history = list(self.grip_history)
        out.continuations = list(self.continuations)
        out.replan_results = list(self.replan_results)
        out.targets = list(self.targets)
        out.motion_paths = list(self.motion_paths)
        out.force_stops = list(self.force_stops)
        out.force_trace = list(self.force_trace)
        return out

    @property
    def plans(self) -> list:
        """The plan and the continuations whose actions were executed."""
        return ([self.plan] if self.plan is not None else []) + list(self.continuations)

    @property
    def finished(self) -> bool:
        return self.mode in FINISHED


def GripperCommand(st: ControllerStatus, t: float) -> float:
    """The commanded opening (m) at time ``t``: on the closing ramp, or held."""
    if st.gripper_ramp is None:
        return st.gripper_cmd
    t0, w0, w1, speed = st.gripper_ramp
    return max(w1, w0 - speed * (t - t0))


def ReleaseOpening(planner, approach_opening: float, held_width: float = 0.0) -> float:
    """The opening (m) the pads open to when they let the held leaf go:
    ``planner.release_opening`` past ``held_width`` (m, the measured
    opening on the leaf), so each pad moves half of it away from the leaf,
    pushing whatever lies beside it no farther; never wider than
    ``approach_opening``, the opening the grasp was approached with
    (``release_opening`` 0: that opening)."""
    w = float(planner.release_opening)
    held = float(held_width) if np.isfinite(held_width) else 0.0
    return float(approach_opening) if w <= 0.0 else min(max(held, 0.0) + w,
                                                        float(approach_opening))


# The way out waits until the pads report the release opening (within
# PADS_OPEN_TOLERANCE), at most PADS_OPEN_TIMEOUT after the release: on
# the digital twin under load an episode backed out with the leaf still
# between the pads (the retreat guard stopped it at 10.5 N); whether the
# pads' lag caused it is not established (docs/explanation/
# planner-parameters.md, the release). A gripper that reports no opening
# (NaN) is not waited for beyond the release time.
PADS_OPEN_TOLERANCE = 0.001   # m
PADS_OPEN_TIMEOUT = 2.0       # s


def PadsOpened(width: float, commanded: float, since_release: float) -> bool:
    """Whether the way out may begin: the measured opening ``width`` (m)
    is within ``PADS_OPEN_TOLERANCE`` of ``commanded``, or unknown, or
    ``since_release`` (s) has reached ``PADS_OPEN_TIMEOUT``."""
    return (not np.isfinite(width) or width >= commanded - PADS_OPEN_TOLERANCE
            or since_release >= PADS_OPEN_TIMEOUT)
