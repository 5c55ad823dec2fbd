"""``ArmController``: the episode's state machine (paper Sec. III-D) as a
Drake LeafSystem, the same on the simulated and the hardware station.

    idle -> capture -> plan_requested [-> confirm_wait] -> pregrasp ->
    approach -> close_gripper -> grasp_wait -> pull -> hold -> observe
    [-> [confirm_wait ->] pull -> hold -> observe, up to planner.max_replans]
    -> release -> retreat -> done            (or planned, or aborted)

With ``planner.targets: all`` (several fruits) the ``plan`` input is
``PlantPlanning``'s plan for the next fruit; after ``retreat`` the fruit's
record joins ``status.targets`` and the controller captures a new view and
plans again (a fruit without a feasible action is recorded and skipped),
until the plan says no action is needed (every fruit visible or handled).

``pull`` executes the chosen motion, a straight pull or a hinge arc
(``planning.motion.PlanActionPath``). After ``observe`` (re-estimation on the
fused views) the ``continuation`` input (``ContinuationPlanning``: a further
motion from the held leaf, planned on the newest view) is evaluated while
re-plans are left; when it has an action, that motion runs from the held
pose (after the operator's yes with ``confirm``; a no releases the leaf).
Release: the arm carries the held leaf back along every executed motion to
where it was grasped, then the gripper opens (no spring-back); retreat: the
approach in reverse (grasp -> pre-grasp -> ready -> via), then the start pose.

Input ports:

- ``plan`` (abstract ``PlanResult``): evaluated once, in ``plan_requested``
  (this pulls Perception -> ShapeCompletion -> ActionCandidates ->
  DeformationPrediction -> ActionSelection on the captured view 0).
- ``semantic_scene``, ``scene_estimate`` (abstract): evaluated just before
  the plan, only to time those stages (Table IV).
- ``final_estimate`` (abstract ``SceneEstimate``): evaluated in ``observe``
  (re-estimation on the fused views).
- ``continuation`` (abstract ``PlanResult``, optional): evaluated in
  ``observe`` while ``planner.max_replans`` allows another motion.
- ``ur5.state_estimated`` (12: q rad, v rad/s), ``gripper.state_measured``
  (3: opening m, rate m/s, object flag: 1 the gripper stopped on an object,
  NaN unknown), ``views_fused`` (1: views Perception has fused).

Output ports:

- ``ur5.position`` (6, rad): the commanded joints (the active trajectory,
  or the held position).
- ``gripper.position`` (1, m): commanded opening.
- ``capture`` (1): how many views the episode wants captured (1 before
  planning, 2 after the action); see ``systems.view_recorder``.
- ``status`` (abstract ``ControllerStatus``): mode, message, plan, final
  estimate, per-stage seconds.

Options (``ControllerOptions``): the start joints and opening (on hardware:
the measured ones, so nothing moves at start), whether a grasp needs the
simulation's acknowledgement, ``plan_only`` (stop in ``planned`` after the
plan), ``confirm`` (wait in ``confirm_wait`` until ``Confirm`` is called),
the joint speed bound (rad/s; trajectories are retimed to stay under 95 %
of it), ``planner.speed_scale`` (all motions), and ``trajectory_check``
(e.g. the hardware ``SafetyChecker``): every trajectory is sampled and
checked before it starts, and at planning time the whole pregrasp ->
approach -> pull motion is checked before anything moves.

The episode aborts cleanly (holds the measured position and leaves the
gripper as it is: a held leaf is never dropped by surprise; ``aborted``
with a message) when the planner finds no feasible action, the fruit is not
seen, IK fails, a trajectory is refused, or a stage raises (``stage_error:
<stage>: ...``, ``failed_stage``); it skips the manipulation (``done``,
``no_action_needed``) when the fruit is already visible enough. In
simulation the grasp is made by the episode runner (it rebuilds the station
with the leaf fixed between the pads, see ``lmap_drake.plants.simworld``),
which then calls ``AcknowledgeGrasp``; on hardware the gripper closes until
it stalls on the leaf and the controller continues alone. A hardware
gripper that reaches the end of its ramp (or 2 s) without reporting an
object holds nothing: it opens, the arm retreats and the target ends
``grasp missed`` (``aborted`` for a single fruit; the next fruit of a plant).
"""
from __future__ import annotations

import copy
import dataclasses as dc
import time
from typing import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from lmap_drake.planning.result import PlanResult
from lmap_drake.planning.motion import MotionError, PlanActionPath, PlanApproach, TimeJointPath
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.station.robot import UR5_VELOCITY_LIMIT
from lmap_drake.scenario import Scenario
from lmap_drake.types import SceneEstimate, SemanticScene

MODES = ("idle", "capture", "plan_requested", "confirm_wait", "pregrasp", "approach",
         "close_gripper", "grasp_wait", "pull", "hold", "observe", "release", "retreat",
         "done", "planned", "aborted")
FINISHED = ("done", "planned", "aborted")
STALL_WINDOW = 0.3   # s: the pads count as stalled on the leaf after this long without closing
ROTATION_SPEED = 0.5  # rad/s: the fastest the held leaf is turned (an arc or a twist)


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
    # planner.targets: all -- one record per fruit handled (see _EndTarget)
    targets: list = dc.field(default_factory=list)
    t_target: float = 0.0               # when the current target's plan was requested
    captures_plan: int = 0              # captures when it was planned (its view: this - 1)

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
        return out

    @property
    def plans(self) -> list:
        """The plan and the continuations whose actions were executed."""
        return ([self.plan] if self.plan is not None else []) + list(self.continuations)

    @property
    def finished(self) -> bool:
        return self.mode in FINISHED


class _StageFailure(Exception):
    def __init__(self, stage: str, error: Exception):
        super().__init__(stage)
        self.stage, self.error = stage, error


class _Refused(Exception):
    """A trajectory refused by ``trajectory_check``."""


def _Stage(stage: str, evaluate, context):
    """``evaluate(context)``; an exception becomes a _StageFailure naming
    the stage (Perception, ShapeCompletion, the planner stages)."""
    try:
        return evaluate(context)
    except MotionError:
        raise
    except Exception as err:  # noqa: BLE001
        raise _StageFailure(stage, err) from err


class ArmController(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, robot: RobotModel | None = None,
                 period: float = 0.02, settle_time: float = 0.3, hold_time: float = 0.5,
                 pull_speed: float = 0.03, options: ControllerOptions | None = None,
                 progress=None):
        super().__init__()
        self._scenario = scenario
        self._robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        self._options = options = options or ControllerOptions()
        self._speed_scale = float(scenario.planner.speed_scale)
        self._settle, self._hold = settle_time, hold_time
        self._pull_speed = pull_speed * self._speed_scale
        self._approach_speed = scenario.planner.approach_speed * self._speed_scale
        self._release_time = 0.5
        self.progress = progress or (lambda msg: None)
        cfg = scenario.planner
        self._pregrasp_opening = cfg.pregrasp_opening
        self._plan = self.DeclareAbstractInputPort(
            "plan", AbstractValue.Make(PlanResult("no_fruit", "lmap")))
        self._sem = self.DeclareAbstractInputPort(
            "semantic_scene", AbstractValue.Make(SemanticScene()))
        self._est = self.DeclareAbstractInputPort(
            "scene_estimate", AbstractValue.Make(SceneEstimate(SemanticScene())))
        self._final = self.DeclareAbstractInputPort(
            "final_estimate", AbstractValue.Make(SceneEstimate(SemanticScene())))
        self._x = self.DeclareVectorInputPort("ur5.state_estimated", 12)
        self._g = self.DeclareVectorInputPort("gripper.state_measured", 3)
        self._views = self.DeclareVectorInputPort("views_fused", 1)
        self._cont = self.DeclareAbstractInputPort(
            "continuation", AbstractValue.Make(PlanResult("no_fruit", "lmap")))
        self._max_replans = int(cfg.max_replans)
        self._multi = cfg.targets == "all"
        q0 = options.initial_q if options.initial_q is not None else scenario.robot.initial_q
        w0 = (options.initial_gripper if options.initial_gripper is not None
              else scenario.robot.initial_gripper_width)
        self._q_start = np.asarray(q0, float).copy()
        initial = ControllerStatus(q_hold=self._q_start.copy(), gripper_cmd=float(w0))
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self.DeclareVectorOutputPort("ur5.position", 6, self._calc_q,
                                     prerequisites_of_calc={
                                         self.time_ticket(),
                                         self.abstract_state_ticket(self._state)})
        self.DeclareVectorOutputPort("gripper.position", 1, self._calc_gripper,
                                     prerequisites_of_calc={
                                         self.time_ticket(),
                                         self.abstract_state_ticket(self._state)})
        self.DeclareVectorOutputPort("capture", 1, self._calc_capture,
                                     prerequisites_of_calc={
                                         self.abstract_state_ticket(self._state)})
        self.DeclareAbstractOutputPort(
            "status", lambda: AbstractValue.Make(ControllerStatus()), self._calc_status,
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    # --- outputs -------------------------------------------------------------
    def _calc_q(self, context, output: BasicVector) -> None:
        st = context.get_abstract_state(self._state).get_value()
        if st.trajectory is not None:
            t = min(context.get_time(), st.trajectory.end_time())
            output.SetFromVector(st.trajectory.value(t).ravel())
        else:
            output.SetFromVector(st.q_hold)

    @staticmethod
    def _GripperCommand(st: ControllerStatus, t: float) -> float:
        if st.gripper_ramp is None:
            return st.gripper_cmd
        t0, w0, w1, speed = st.gripper_ramp
        return max(w1, w0 - speed * (t - t0))

    def _calc_gripper(self, context, output) -> None:
        st = context.get_abstract_state(self._state).get_value()
        output.SetFromVector([self._GripperCommand(st, context.get_time())])

    def _calc_capture(self, context, output) -> None:
        output.SetFromVector([context.get_abstract_state(self._state).get_value().captures])

    def _calc_status(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._state).get_value())

    # --- helpers ---------------------------------------------------------------
    def Status(self, context) -> ControllerStatus:
        return context.get_abstract_state(self._state).get_value()

    def _Modify(self, context, **fields) -> None:
        st = copy.deepcopy(self.Status(context))
        for k, v in fields.items():
            setattr(st, k, v)
        context.get_mutable_abstract_state(self._state).set_value(st)

    def AcknowledgeGrasp(self, context) -> None:
        """Called by the simulation runner once the grasp exists."""
        self._Modify(context, grasp_acknowledged=True)

    def Confirm(self, context, accepted: bool, note: str = "") -> None:
        """The operator's answer while the controller waits in
        ``confirm_wait``; it acts on it at its next update."""
        self._Modify(context, confirmed=bool(accepted), confirm_note=note)

    def _enter(self, st: ControllerStatus, mode: str, t: float, message: str = "") -> None:
        st.mode, st.t_mode = mode, t
        if message:
            st.message = message
        st.mode_log.append((round(t, 3), mode))
        self.progress(f"{mode}" + (f": {message}" if message else ""))

    def _TimePath(self, t: float, q0, waypoints: list, fraction: float,
                  duration: float | None = None, min_segment: float = 0.05):
        """A joint trajectory from ``q0`` through ``waypoints`` at
        ``fraction`` x speed_scale of the UR5 velocity limit, retimed so that
        no joint exceeds 95 % of ``max_joint_speed``; then checked."""
        limit = 0.95 * self._options.max_joint_speed
        f = min(fraction * self._speed_scale, limit / UR5_VELOCITY_LIMIT)
        traj = TimeJointPath(t, q0, waypoints, f, min_segment, duration)
        for _ in range(4):
            times = np.arange(traj.start_time(), traj.end_time() + 0.005, 0.005)
            qs = np.array([traj.value(min(x, traj.end_time())).ravel() for x in times])
            speed = np.abs(np.diff(qs, axis=0)).max() / 0.005 if len(qs) > 1 else 0.0
            if speed <= limit:
                break
            stretched = (traj.end_time() - t) * speed / limit * 1.02
            traj = TimeJointPath(t, q0, waypoints, f, min_segment, stretched)
        if self._options.trajectory_check is not None:
            period = 0.01
            times = np.arange(traj.start_time(), traj.end_time() + 0.5 * period, period)
            times = np.minimum(times, traj.end_time())
            qs = np.array([traj.value(x).ravel() for x in times])
            try:
                self._options.trajectory_check(times, qs)
            except Exception as err:  # noqa: BLE001 - SafetyRefusal and kin
                raise _Refused(" ".join(str(err).split())) from err
        return traj

    def _start_path(self, st: ControllerStatus, t: float, waypoints: list, fraction: float,
                    duration: float | None = None, min_segment: float = 0.05) -> None:
        q0 = st.trajectory.value(t).ravel() if st.trajectory is not None else st.q_hold
        st.trajectory = self._TimePath(t, q0, waypoints, fraction, duration, min_segment)
        st.q_hold = np.asarray(waypoints[-1], float)

    def _ApproachTiming(self, q0: np.ndarray, waypoints: list) -> dict:
        """``_TimePath`` arguments for the final approach (pre-grasp <->
        grasp, from ``q0``): each step at the TCP speed
        ``planner.approach_speed`` (its length from the TCP poses: the steps
        ``StraightenStep`` inserted near a wrist singularity are shorter)
        unless a joint would exceed 0.5 of its velocity limit, then as fast
        as that allows."""
        p = [self._robot.TcpPose(q, 0.0).translation() for q in [q0] + list(waypoints)]
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        return dict(fraction=0.5, min_segment=np.maximum(0.05, steps / self._approach_speed))

    def _traj_done(self, st: ControllerStatus, t: float) -> bool:
        return st.trajectory is None or t >= st.trajectory.end_time()

    def _pull_duration(self, st: ControllerStatus, all_motions: bool = False) -> float:
        """Seconds for the current motion (or for all executed motions, to
        carry the leaf back) at the pull speed."""
        plans = st.plans if all_motions else st.plans[-1:]
        return self._MotionDuration([p.chosen.action for p in plans])

    def _MotionDuration(self, actions: list) -> float:
        """Seconds to move the TCP along ``actions`` at the pull speed, and to
        turn it at most ``ROTATION_SPEED`` (a twist turns in place), >= 1 s."""
        return max(1.0, sum(max(a.path_length / self._pull_speed,
                                abs(a.angle) / (ROTATION_SPEED * self._speed_scale))
                            for a in actions))

    # --- the state machine -------------------------------------------------
    def _update(self, context, state) -> EventStatus:
        st = copy.deepcopy(context.get_abstract_state(self._state).get_value())
        t = context.get_time()
        before = st.mode
        try:
            self._step(context, st, t)
        except MotionError as err:
            self._Stop(context, st, t)
            self._enter(st, "aborted", t, f"IK failure: {err}")
        except _Refused as err:
            self._Stop(context, st, t)
            self._enter(st, "aborted", t, f"refused by the safety checks in {before}: {err}")
        except _StageFailure as err:
            self._Fail(context, st, t, err.stage, err.error)
        except Exception as err:  # noqa: BLE001 - never an exception out of the Diagram
            self._Fail(context, st, t, f"arm_controller ({st.mode})", err)
        state.get_mutable_abstract_state(self._state).set_value(st)
        return EventStatus.Succeeded()

    def _views_fused(self, context) -> int:
        return int(self._views.Eval(context)[0]) if self._views.HasValue(context) else 1 << 30

    def _step(self, context, st: ControllerStatus, t: float) -> None:
        mode = st.mode
        if mode == "idle":
            if t - st.t_mode >= self._settle:
                st.captures = 1
                self._enter(st, "capture", t)
        elif mode == "capture":
            if self._views_fused(context) >= max(st.captures, 1):
                st.t_target, st.captures_plan = t, max(st.captures, 1)
                self._enter(st, "plan_requested", t)
        elif mode == "plan_requested":
            self._Plan(context, st, t)
        elif mode == "confirm_wait":
            if st.confirmed is True and st.pending_motion is not None:
                (plan, path), st.pending_motion = st.pending_motion, None
                self._StartContinuation(st, t, plan, path, "confirmed by the operator")
            elif st.confirmed is True:
                self._StartMotion(st, t, "confirmed by the operator")
            elif st.confirmed is False and st.pending_motion is not None:
                st.pending_motion = None
                self._StartRelease(st, t, "continuation not confirmed by the operator")
            elif st.confirmed is False:
                self._enter(st, "aborted", t, "not confirmed by the operator"
                            + (f" ({st.confirm_note})" if st.confirm_note else "")
                            + "; nothing moved")
        elif mode == "pregrasp":
            if self._traj_done(st, t):
                path = st.segments.pop(0)
                self._start_path(st, t, path, **self._ApproachTiming(st.q_hold, path))
                self._enter(st, "approach", t)
        elif mode == "approach":
            if self._traj_done(st, t):
                st.trajectory = None
                # Close slowly (gripper_close_speed), like the 2F-85 at low
                # speed, so the pads meet the leaf gently.
                st.gripper_ramp = (t, st.gripper_cmd, self._scenario.planner.grasp_close_width,
                                   self._scenario.planner.gripper_close_speed)
                self._enter(st, "close_gripper", t)
        elif mode == "close_gripper":
            # Closed on the leaf when the pads stall (or reach the commanded
            # opening); then hold that opening.
            # Stalled on the leaf: what the gripper reports (the 2F-85's
            # object detection), or, when it cannot tell (simulation), the
            # pads closed less than 0.3 mm over the last STALL_WINDOW s while
            # the command is more than 1 mm tighter.
            width, rate, on_object = self._g.Eval(context)
            t0, w0, w1, speed = st.gripper_ramp
            commanded = max(w1, w0 - speed * (t - t0))
            st.grip_history = [(tt, ww) for tt, ww in st.grip_history
                               if t - tt <= STALL_WINDOW + 1e-9] + [(t, float(width))]
            old_t, old_w = st.grip_history[0]
            if np.isfinite(on_object):
                # The gripper tells: it stalled on the leaf, or its pads
                # stand at the end of the ramp with nothing between them.
                stalled = on_object >= 0.5
                if not stalled and t - t0 <= 2.0 and not (
                        commanded <= w1 + 1e-9 and width <= w1 + 0.0005 and abs(rate) < 0.001):
                    return                      # still closing
                if not stalled:
                    self._GraspMissed(st, t, width)
                    return
            else:
                stalled = (t - old_t >= STALL_WINDOW - 1e-9 and old_w - width < 0.0003
                           and width > commanded + 0.001)
            if commanded <= w1 + 1e-9 or stalled or t - t0 > 2.0:
                # Stalled on the leaf: hold just inside the measured opening.
                # Otherwise the fingers may still lag the ramp: a request
                # above its last one would open a gripper that already holds
                # a thin leaf (the twin lets go; so would a 2F-85).
                st.gripper_ramp = None
                hold = float(width) - 0.0005
                st.gripper_cmd = max(w1, hold if stalled else min(commanded, hold))
                self._enter(st, "grasp_wait", t, f"closed at {max(0.0, width) * 1000:.1f} mm")
        elif mode == "grasp_wait":
            if st.grasp_acknowledged or not self._options.grasp_ack_required:
                self._start_path(st, t, st.pull_path, 0.3, self._pull_duration(st))
                st.motion_paths = [st.pull_path]
                self._enter(st, "pull", t, st.plan.chosen.action.Describe())
        elif mode == "pull":
            if self._traj_done(st, t):
                self._enter(st, "hold", t)
        elif mode == "hold":
            if t - st.t_mode >= self._hold:
                st.captures += 1
                self._enter(st, "observe", t)
        elif mode == "observe":
            if self._views_fused(context) >= st.captures:
                t0 = time.perf_counter()
                st.final_estimate = _Stage("shape_reestimation", self._final.Eval, context)
                st.stage_seconds["reestimation_s"] = (
                    st.stage_seconds.get("reestimation_s", 0.0) + time.perf_counter() - t0)
                if not self._Continue(context, st, t):
                    self._StartRelease(st, t, "shape re-estimated on the fused views")
        elif mode == "release":
            if not st.released and self._traj_done(st, t):
                st.trajectory = None
                st.gripper_cmd = st.pregrasp_opening
                st.released, st.t_released = True, t
            elif st.released and t - st.t_released >= self._release_time / self._speed_scale:
                self._Retreat(st, t)
        elif mode == "retreat":
            if self._traj_done(st, t):
                if st.segments:
                    waypoints, fraction = st.segments.pop(0)
                    self._start_path(st, t, waypoints, fraction)
                else:
                    st.trajectory = None
                    if st.grasp_missed:
                        end, why, st.grasp_missed = "aborted", st.grasp_missed, ""
                        outcome = why + "; arm retreated"
                        message = why + "; gripper opened and arm retreated"
                    else:
                        message = ("action executed; shape re-estimated on the fused views; "
                                   "leaf released and arm retreated")
                        end, outcome = "done", "revealed: " + message
                    if self._multi:         # the next fruit, from a fresh view
                        self._EndTarget(st, t, outcome)
                        st.captures += 1
                        self._enter(st, "capture", t, f"{len(st.targets)} fruit(s) handled; "
                                    "looking again for the next one")
                    else:
                        self._enter(st, end, t, message)

    def _Stop(self, context, st: ControllerStatus, t: float) -> None:
        """Holds the measured joints; the gripper keeps its current command
        (a ramp freezes where it is): a held leaf is never dropped."""
        st.gripper_cmd = self._GripperCommand(st, t)
        st.trajectory, st.gripper_ramp = None, None
        st.q_hold = self._x.Eval(context)[:6].copy()

    def _Fail(self, context, st: ControllerStatus, t: float, stage: str, err) -> None:
        """Holds the arm and aborts with status stage_error naming the stage."""
        self._Stop(context, st, t)
        st.failed_stage = stage
        self._enter(st, "aborted", t, f"stage_error: {stage}: {type(err).__name__}: "
                    f"{' '.join(str(err).split())}")

    def _Plan(self, context, st: ControllerStatus, t: float) -> None:
        t0 = time.perf_counter()
        _Stage("perception", self._sem.Eval, context)
        t1 = time.perf_counter()
        st.initial_estimate = _Stage("shape_completion", self._est.Eval, context)
        t2 = time.perf_counter()
        plan = _Stage("planning", self._plan.Eval, context)
        t3 = time.perf_counter()
        st.plan = plan
        st.stage_seconds.update(segmentation_s=t1 - t0, shape_completion_s=t2 - t1,
                                planning_s=t3 - t2)
        st.stage_seconds.update({k: v for k, v in plan.timings.items()})
        if plan.status == "no_action_needed":
            if not st.targets:
                st.final_estimate = st.initial_estimate
            self._enter(st, "done", t, "no action needed: " + plan.message)
            return
        if self._multi and plan.target is not None and plan.status == "no_feasible_action":
            # this fruit cannot be revealed: recorded, on to the next one
            st.final_estimate = st.initial_estimate
            self._EndTarget(st, t, f"{plan.status}: {plan.message}")
            st.t_target = t
            self._enter(st, "plan_requested", t, f"fruit {plan.target.get('fruit_id')}: no "
                        "feasible action; planning the next fruit")
            return
        if plan.status != "ok":
            if plan.status == "stage_error":
                st.failed_stage = plan.message.split(":")[0]
            self._enter(st, "aborted", t, f"{plan.status}: {plan.message}")
            return
        c = plan.chosen
        try:
            approach = self._PathsFor(st, t, c)
        except (MotionError, _Refused) as err:
            if not (self._multi and plan.target is not None):
                raise
            # this fruit's chosen motion cannot be executed: recorded, on to
            # the next fruit (nothing has moved)
            st.final_estimate = st.initial_estimate
            self._EndTarget(st, t, f"no_executable_path: {' '.join(str(err).split())}")
            st.t_target = t
            self._enter(st, "plan_requested", t, f"fruit {plan.target.get('fruit_id')}: the "
                        f"chosen motion cannot be executed ({err}); planning the next fruit")
            return
        summary = (f"grasp {c.action.grasp_id}, direction {c.action.direction_id}, "
                   f"{c.action.Describe()}")
        if self._options.plan_only:
            self._enter(st, "planned", t, f"plan only: {summary}; nothing moved")
        elif self._options.confirm:
            st.confirmed = None
            self._enter(st, "confirm_wait", t, summary)
        else:
            self._StartMotion(st, t, summary)

    def _PathsFor(self, st: ControllerStatus, t: float, c):
        """The joint paths of candidate ``c`` from the held joints (approach,
        action), stored in ``st`` and checked by timing them; raises
        ``MotionError`` (no IK or self-collision along them) or ``_Refused``
        (the trajectory check). Returns the approach."""
        X_WT = RigidTransform(RotationMatrix(c.action.R_WG), c.action.p_WG)
        normal = c.action.R_WG[:, 1]
        approach = c.approach or PlanApproach(self._robot, X_WT, st.q_hold, normal,
                                              self._scenario.planner.pregrasp_distance,
                                              self._pregrasp_opening)
        st.pull_path = PlanActionPath(self._robot, c.action, approach.to_grasp[-1])
        st.segments = [approach.to_grasp]
        st.grasp_path = list(approach.to_grasp)
        st.pregrasp_path = [approach.via] + approach.to_ready + approach.to_pregrasp
        st.pregrasp_opening = approach.opening or self._pregrasp_opening
        # The whole motion is checked before anything moves (timing does not
        # depend on the start time, so the checks hold at execution).
        pre = self._TimePath(t, st.q_hold, st.pregrasp_path, 0.5)
        app = self._TimePath(pre.end_time(), st.pregrasp_path[-1], approach.to_grasp,
                             **self._ApproachTiming(st.pregrasp_path[-1], approach.to_grasp))
        self._TimePath(app.end_time(), approach.to_grasp[-1], st.pull_path, 0.3,
                       self._pull_duration(st))
        return approach

    def _EndTarget(self, st: ControllerStatus, t: float, outcome: str) -> None:
        """Closes the current fruit's record (``targets``: its plan and
        target, the continuations, estimates before and after, the time
        window, the captures so far) and clears the per-target state."""
        st.targets = st.targets + [{
            "target": st.plan.target if st.plan is not None else None, "outcome": outcome,
            "plan": st.plan, "continuations": list(st.continuations),
            "replan_log": list(st.replan_log), "replan_results": list(st.replan_results),
            "initial_estimate": st.initial_estimate, "final_estimate": st.final_estimate,
            "t_start": st.t_target, "t_end": t, "captures": st.captures,
            "motions": len(st.motion_paths), "view_plan": st.captures_plan - 1,
            "view_after": st.captures - 1 if st.motion_paths else None,
            "stage_seconds": dict(st.stage_seconds)}]
        st.continuations, st.replan_results, st.replan_log = [], [], []
        st.motion_paths, st.pull_path, st.segments = [], [], []
        st.grasp_path, st.pregrasp_path, st.grip_history = [], [], []
        st.released, st.t_released, st.grasp_acknowledged = False, 0.0, False
        st.confirmed, st.pending_motion, st.gripper_ramp = None, None, None

    def _StartRelease(self, st: ControllerStatus, t: float, message: str) -> None:
        """Back along every executed motion, still holding, so the leaf
        returns to rest in the gripper instead of springing back when let
        go (then ``release`` opens the gripper); without ``release`` the
        episode ends holding the leaf."""
        n = len(st.motion_paths)
        if not self._options.release:
            self._enter(st, "done", t, f"{n} motion(s) executed; {message}")
            return
        back = [q for path in st.motion_paths[::-1] for q in path[::-1]][1:]
        self._start_path(st, t, back + [st.grasp_path[-1]], 0.3,
                         self._pull_duration(st, all_motions=True)
                         / self._scenario.planner.return_speed_scale)
        self._enter(st, "release", t, f"{n} motion(s) executed; {message}; "
                    "returning the leaf, then releasing it")

    def _Continue(self, context, st: ControllerStatus, t: float) -> bool:
        """After observing: plan a further motion from the held leaf (at most
        ``planner.max_replans``); start it (or ask the operator) and return
        True, or return False to release. A continuation that cannot be
        planned or timed is not an error: the episode releases the leaf."""
        if len(st.continuations) >= self._max_replans:
            return False
        t0 = time.perf_counter()
        if not self._cont.HasValue(context):      # (this evaluates the port when connected)
            return False
        plan = _Stage("continuation_planning", self._cont.Eval, context)
        st.stage_seconds["replanning_s"] = (st.stage_seconds.get("replanning_s", 0.0)
                                            + time.perf_counter() - t0)
        st.replan_log = st.replan_log + [f"{plan.status}: {plan.message}"]
        st.replan_results = st.replan_results + [plan]
        if plan.status != "ok":
            self.progress(f"no further motion: {plan.message or plan.status}")
            return False
        a = plan.chosen.action
        try:
            path = PlanActionPath(self._robot, a, st.q_hold)
            self._TimePath(t, st.q_hold, path, 0.3, self._MotionDuration([a]))
        except (MotionError, _Refused) as err:
            self.progress(f"no further motion: {err}")
            return False
        summary = f"continuation {len(st.continuations) + 1}: {a.Describe()}"
        if self._options.confirm:
            st.confirmed, st.pending_motion = None, (plan, path)
            self._enter(st, "confirm_wait", t, summary)
        else:
            self._StartContinuation(st, t, plan, path, summary)
        return True

    def _StartContinuation(self, st: ControllerStatus, t: float, plan: PlanResult,
                           path: list, message: str) -> None:
        st.continuations = st.continuations + [plan]
        st.pull_path = path
        st.motion_paths = st.motion_paths + [path]
        self._start_path(st, t, path, 0.3, self._pull_duration(st))
        self._enter(st, "pull", t, message)

    def _StartMotion(self, st: ControllerStatus, t: float, message: str) -> None:
        st.gripper_cmd = st.pregrasp_opening
        self._start_path(st, t, st.pregrasp_path, 0.5)
        self._enter(st, "pregrasp", t, message)

    def _GraspMissed(self, st: ControllerStatus, t: float, width: float) -> None:
        """On hardware the gripper closed without reporting the leaf (no
        stall): nothing is held, so nothing is pulled. The gripper opens and
        the arm retreats; the target ends ``grasp missed`` (the episode
        aborts with that message, or the next fruit is planned)."""
        st.gripper_ramp = None
        st.gripper_cmd = st.pregrasp_opening
        w1 = self._scenario.planner.grasp_close_width
        st.grasp_missed = (f"grasp missed: the gripper closed to {max(0.0, width) * 1000:.1f} mm "
                           "without reporting the leaf between its pads; nothing was moved"
                           + (f" (the pads stop at planner.grasp_close_width, {w1 * 1000:.1f} "
                              "mm: a thinner leaf is never met, set it lower)"
                              if w1 > 0 and width <= w1 + 0.0005 else ""))
        self.progress(st.grasp_missed + "; opening and retreating")
        self._Retreat(st, t)

    def _Retreat(self, st: ControllerStatus, t: float) -> None:
        """The approach in reverse (all of it checked at planning time):
        back out to the pre-grasp pose, through the ready and via poses,
        then the joint move to the episode's start pose."""
        out = st.grasp_path[::-1][1:] + [st.pregrasp_path[-1]]
        st.segments = [(st.pregrasp_path[::-1][1:], 0.5), ([self._q_start.copy()], 0.5)]
        self._start_path(st, t, out, **self._ApproachTiming(st.q_hold, out))
        self._enter(st, "retreat", t)
