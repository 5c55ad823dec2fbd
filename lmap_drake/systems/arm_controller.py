"""``ArmController``: the episode's state machine (paper Sec. III-D,
``systems.arm_sequence``) as a Drake LeafSystem, the same on the simulated
and the hardware station. Its periodic update steps the ``ArmSequence`` on
the abstract ``ControllerStatus``, reading the input ports only when the
mode asks (so the planning stages run when a plan is requested).

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
- ``ur5.wrist_force`` (3, N; optional): the station's wrist force, read
  at the pre-grasp pose (the zero), while the held leaf moves and while the
  gripper backs out of the plant (the force guard, ``systems.arm_guard``);
  unconnected, there is no guard.

Output ports:

- ``ur5.position`` (6, rad): the commanded joints (the active trajectory,
  or the held position).
- ``gripper.position`` (1, m): commanded opening.
- ``capture`` (1): how many views the episode wants captured (1 before
  planning, 2 after the action); see ``systems.view_recorder``.
- ``status`` (abstract ``ControllerStatus``): mode, message, plan, final
  estimate, per-stage seconds.

Options: ``ControllerOptions`` (``systems.arm_status``). In simulation
the episode runner calls ``AcknowledgeGrasp`` once it has made the grasp;
with ``confirm`` the operator's answer comes through ``Confirm``.
"""
from __future__ import annotations

import copy

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from lmap_drake.planning.result import PlanResult
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.systems.arm_sequence import ArmSequence
from lmap_drake.systems.arm_status import ControllerOptions, ControllerStatus, GripperCommand
from lmap_drake.types import SceneEstimate, SemanticScene


class ArmController(LeafSystem):
    """See the module docstring. ``period`` (s) of the update;
    ``settle_time`` (s) before the first capture, ``hold_time`` (s) after
    each motion before observing; ``pull_speed`` (m/s, times
    ``planner.speed_scale``) of the action's motion."""

    def __init__(self, scenario: Scenario, robot: RobotModel | None = None,
                 period: float = 0.02, settle_time: float = 0.3, hold_time: float = 0.5,
                 pull_speed: float = 0.03, options: ControllerOptions | None = None,
                 progress=None):
        super().__init__()
        robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        options = options or ControllerOptions()
        plan0 = AbstractValue.Make(PlanResult("no_fruit", "lmap"))
        estimate0 = AbstractValue.Make(SceneEstimate(SemanticScene()))
        self._ports = {
            "plan": self.DeclareAbstractInputPort("plan", plan0),
            "semantic_scene": self.DeclareAbstractInputPort(
                "semantic_scene", AbstractValue.Make(SemanticScene())),
            "scene_estimate": self.DeclareAbstractInputPort("scene_estimate", estimate0),
            "final_estimate": self.DeclareAbstractInputPort("final_estimate", estimate0),
            "ur5.state_estimated": self.DeclareVectorInputPort("ur5.state_estimated", 12),
            "gripper.state_measured": self.DeclareVectorInputPort("gripper.state_measured", 3),
            "views_fused": self.DeclareVectorInputPort("views_fused", 1),
            "ur5.wrist_force": self.DeclareVectorInputPort("ur5.wrist_force", 3),
            "continuation": self.DeclareAbstractInputPort("continuation", plan0)}
        q0 = options.initial_q if options.initial_q is not None else scenario.robot.initial_q
        w0 = (options.initial_gripper if options.initial_gripper is not None
              else scenario.robot.initial_gripper_width)
        q_start = np.asarray(q0, float).copy()
        self._sequence = ArmSequence(scenario.planner, robot, options, q_start, settle_time,
                                     hold_time, pull_speed, progress)
        initial = ControllerStatus(q_hold=q_start.copy(), gripper_cmd=float(w0))
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
        output.SetFromVector([GripperCommand(st, context.get_time())])

    def _calc_capture(self, context, output) -> None:
        output.SetFromVector([context.get_abstract_state(self._state).get_value().captures])

    def _calc_status(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._state).get_value())

    # --- the state -------------------------------------------------------------
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

    def _update(self, context, state) -> EventStatus:
        st = copy.deepcopy(context.get_abstract_state(self._state).get_value())
        self._sequence.Update(_PortInputs(self._ports, context), st, context.get_time())
        state.get_mutable_abstract_state(self._state).set_value(st)
        return EventStatus.Succeeded()


class _PortInputs:
    """The controller's input ports (by name) as ``arm_sequence.ArmInputs``,
    each evaluated when the state machine asks."""

    def __init__(self, ports: dict, context):
        self._ports, self._context = ports, context

    def _Eval(self, name: str):
        return self._ports[name].Eval(self._context)

    def semantic_scene(self):
        return self._Eval("semantic_scene")

    def scene_estimate(self) -> SceneEstimate:
        return self._Eval("scene_estimate")

    def plan(self) -> PlanResult:
        return self._Eval("plan")

    def final_estimate(self) -> SceneEstimate:
        return self._Eval("final_estimate")

    def has_continuation(self) -> bool:
        return self._ports["continuation"].HasValue(self._context)

    def continuation(self) -> PlanResult:
        return self._Eval("continuation")

    def views_fused(self) -> int:
        connected = self._ports["views_fused"].HasValue(self._context)
        return int(self._Eval("views_fused")[0]) if connected else 1 << 30

    def gripper_state(self) -> np.ndarray:
        return self._Eval("gripper.state_measured")

    def measured_state(self) -> np.ndarray:
        return self._Eval("ur5.state_estimated")

    def wrist_force(self) -> np.ndarray | None:
        port = self._ports["ur5.wrist_force"]
        return port.Eval(self._context) if port.HasValue(self._context) else None
