"""``ArmController``: the episode's state machine (paper Sec. III-D) as a
Drake LeafSystem.

    idle -> plan_requested -> pregrasp -> approach -> close_gripper ->
    grasp_wait -> pull -> hold -> observe -> done          (or aborted)

Input ports:

- ``plan`` (abstract ``PlanResult``): evaluated once, in ``plan_requested``
  (this pulls Perception -> ShapeCompletion -> ActionCandidates ->
  DeformationPrediction -> ActionSelection).
- ``semantic_scene``, ``scene_estimate`` (abstract): evaluated just before
  the plan, only to time those stages (Table IV).
- ``final_estimate`` (abstract ``SceneEstimate``): evaluated in ``observe``
  (re-estimation on the fused views).
- ``ur5.state_estimated`` (12: q rad, v rad/s), ``gripper.state_measured``
  (2: opening m, rate m/s).

Output ports:

- ``ur5.position`` (6, rad): the commanded joints (the active trajectory,
  or the held position).
- ``gripper.position`` (1, m): commanded opening.
- ``capture`` (1): how many views Perception should have fused (1 before
  planning, 2 after the action).
- ``status`` (abstract ``ControllerStatus``): mode, message, plan, final
  estimate, per-stage seconds.

Trajectories are cubic in joint space, timed so no joint exceeds a fraction
of the UR5 velocity limit (pi rad/s). The episode aborts cleanly (holds
position, ``aborted`` with a message) when the planner finds no feasible
action, the fruit is not seen, IK fails for the approach or the pull, or a
stage it evaluates raises (``stage_error: <stage>: ...``, ``failed_stage``); it
skips the manipulation (``done``, ``no_action_needed``) when the fruit is
already visible enough. In simulation the grasp is made by the episode
runner (it rebuilds the station with the leaf fixed between the pads, see
``lmap_drake.plants.simworld``), which then calls ``AcknowledgeGrasp``; on
hardware ``grasp_ack_required=False`` lets the controller continue alone.
"""
from __future__ import annotations

import copy
import dataclasses as dc
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from lmap_drake.planning.lmap import PlanResult
from lmap_drake.planning.motion import MotionError, PlanApproach, PlanPull, TimeJointPath
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.types import SceneEstimate, SemanticScene

MODES = ("idle", "plan_requested", "pregrasp", "approach", "close_gripper", "grasp_wait",
         "pull", "hold", "observe", "done", "aborted")


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
    segments: list = dc.field(default_factory=list)   # pending joint-waypoint lists
    pull_path: list = dc.field(default_factory=list)
    captures: int = 0
    grasp_acknowledged: bool = False
    plan: PlanResult | None = None
    initial_estimate: SceneEstimate | None = None
    final_estimate: SceneEstimate | None = None
    stage_seconds: dict = dc.field(default_factory=dict)
    mode_log: list = dc.field(default_factory=list)
    failed_stage: str = ""              # set when a stage raised (status stage_error)

    def __deepcopy__(self, memo):
        # Plans and estimates are read-only records: share them.
        out = copy.copy(self)
        out.q_hold = self.q_hold.copy()
        out.segments = list(self.segments)
        out.pull_path = list(self.pull_path)
        out.stage_seconds = dict(self.stage_seconds)
        out.mode_log = list(self.mode_log)
        return out

    @property
    def finished(self) -> bool:
        return self.mode in ("done", "aborted")


class _StageFailure(Exception):
    def __init__(self, stage: str, error: Exception):
        super().__init__(stage)
        self.stage, self.error = stage, error


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
                 pull_speed: float = 0.03, grasp_ack_required: bool = True,
                 progress=None):
        super().__init__()
        self._scenario = scenario
        self._robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        self._settle, self._hold, self._pull_speed = settle_time, hold_time, pull_speed
        self._ack_required = grasp_ack_required
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
        self._g = self.DeclareVectorInputPort("gripper.state_measured", 2)
        initial = ControllerStatus(q_hold=np.asarray(scenario.robot.initial_q, float),
                                   gripper_cmd=scenario.robot.initial_gripper_width)
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

    def _calc_gripper(self, context, output) -> None:
        st = context.get_abstract_state(self._state).get_value()
        if st.gripper_ramp is None:
            output.SetFromVector([st.gripper_cmd])
            return
        t0, w0, w1, speed = st.gripper_ramp
        output.SetFromVector([max(w1, w0 - speed * (context.get_time() - t0))])

    def _calc_capture(self, context, output) -> None:
        output.SetFromVector([context.get_abstract_state(self._state).get_value().captures])

    def _calc_status(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._state).get_value())

    # --- helpers ---------------------------------------------------------------
    def Status(self, context) -> ControllerStatus:
        return context.get_abstract_state(self._state).get_value()

    def AcknowledgeGrasp(self, context) -> None:
        """Called by the simulation runner once the grasp exists."""
        st = copy.deepcopy(self.Status(context))
        st.grasp_acknowledged = True
        context.get_mutable_abstract_state(self._state).set_value(st)

    def _enter(self, st: ControllerStatus, mode: str, t: float, message: str = "") -> None:
        st.mode, st.t_mode = mode, t
        if message:
            st.message = message
        st.mode_log.append((round(t, 3), mode))
        self.progress(f"{mode}" + (f": {message}" if message else ""))

    def _start_path(self, st: ControllerStatus, t: float, waypoints: list, speed: float,
                    duration: float | None = None) -> None:
        q0 = st.trajectory.value(t).ravel() if st.trajectory is not None else st.q_hold
        st.trajectory = TimeJointPath(t, q0, waypoints, speed, 0.05, duration)
        st.q_hold = np.asarray(waypoints[-1], float)

    def _traj_done(self, st: ControllerStatus, t: float) -> bool:
        return st.trajectory is None or t >= st.trajectory.end_time()

    # --- the state machine -------------------------------------------------
    def _update(self, context, state) -> EventStatus:
        st = copy.deepcopy(context.get_abstract_state(self._state).get_value())
        t = context.get_time()
        before = st.mode
        try:
            self._step(context, st, t)
        except MotionError as err:
            st.trajectory = None
            st.q_hold = self._x.Eval(context)[:6].copy()
            self._enter(st, "aborted", t, f"IK failure: {err}")
        except _StageFailure as err:
            self._Fail(context, st, t, err.stage, err.error)
        except Exception as err:  # noqa: BLE001 - never an exception out of the Diagram
            self._Fail(context, st, t, f"arm_controller ({st.mode})", err)
        state.get_mutable_abstract_state(self._state).set_value(st)
        return EventStatus.Succeeded() if st.mode != before else EventStatus.DidNothing()

    def _step(self, context, st: ControllerStatus, t: float) -> None:
        mode = st.mode
        if mode == "idle":
            st.captures = 1
            if t - st.t_mode >= self._settle:
                self._enter(st, "plan_requested", t)
        elif mode == "plan_requested":
            self._Plan(context, st, t)
        elif mode == "pregrasp":
            if self._traj_done(st, t):
                self._start_path(st, t, st.segments.pop(0), 0.15)
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
            width, rate = self._g.Eval(context)
            t0, w0, w1, speed = st.gripper_ramp
            commanded = max(w1, w0 - speed * (t - t0))
            stalled = width > commanded + 0.001 and abs(rate) < 0.25 * speed
            if commanded <= w1 + 1e-9 or stalled or t - t0 > 2.0:
                st.gripper_ramp = None
                st.gripper_cmd = max(w1, float(width) - 0.0005)
                self._enter(st, "grasp_wait", t, f"closed at {width * 1000:.1f} mm")
        elif mode == "grasp_wait":
            if st.grasp_acknowledged or not self._ack_required:
                chosen = st.plan.chosen
                duration = max(1.0, chosen.action.distance / self._pull_speed)
                self._start_path(st, t, st.pull_path, 0.3, duration)
                self._enter(st, "pull", t)
        elif mode == "pull":
            if self._traj_done(st, t):
                self._enter(st, "hold", t)
        elif mode == "hold":
            if t - st.t_mode >= self._hold:
                st.captures = 2
                self._enter(st, "observe", t)
        elif mode == "observe":
            if t - st.t_mode >= 0.05:  # Perception fuses the new view on a step
                t0 = time.perf_counter()
                st.final_estimate = _Stage("shape_reestimation", self._final.Eval, context)
                st.stage_seconds["reestimation_s"] = time.perf_counter() - t0
                self._enter(st, "done", t, "action executed; shape re-estimated on the "
                            "fused views")

    def _Fail(self, context, st: ControllerStatus, t: float, stage: str, err) -> None:
        """Holds the arm and aborts with status stage_error naming the stage."""
        st.trajectory, st.gripper_ramp = None, None
        st.q_hold = self._x.Eval(context)[:6].copy()
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
            st.final_estimate = st.initial_estimate
            self._enter(st, "done", t, "no action needed: " + plan.message)
            return
        if plan.status != "ok":
            if plan.status == "stage_error":
                st.failed_stage = plan.message.split(":")[0]
            self._enter(st, "aborted", t, f"{plan.status}: {plan.message}")
            return
        c = plan.chosen
        X_WT = RigidTransform(RotationMatrix(c.action.R_WG), c.action.p_WG)
        normal = c.action.R_WG[:, 1]
        q_now = self._x.Eval(context)[:6]
        approach = c.approach or PlanApproach(self._robot, X_WT, q_now, normal,
                                              self._scenario.planner.pregrasp_distance,
                                              self._pregrasp_opening)
        st.pull_path = PlanPull(self._robot, X_WT, c.action.dp_W, approach.to_grasp[-1])
        st.gripper_cmd = approach.opening or self._pregrasp_opening
        st.segments = [approach.to_grasp]
        self._start_path(st, t, [approach.via] + approach.to_ready + approach.to_pregrasp, 0.5)
        self._enter(st, "pregrasp", t, f"grasp {c.action.grasp_id}, direction "
                    f"{c.action.direction_id}, {c.action.distance * 100:.0f} cm")
