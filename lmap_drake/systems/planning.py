"""The LMAP planner as Drake LeafSystems (thin shells around
``lmap_drake.planning.lmap``), wired as in the paper's data flow:

    ShapeCompletion -> ActionCandidates -> DeformationPrediction -> ActionSelection

``ActionCandidates``
  inputs:  ``scene_estimate`` (abstract SceneEstimate, world frame W, m),
           ``ur5.position`` (6, rad; the IK seed).
  outputs: ``candidate_set`` (abstract CandidateSet: candidates with IK and
           robot collision checks, visibility model, statuses),
           ``actions`` (abstract list[Action]: the live candidates' actions),
           ``scene_estimate`` (the input scene with its leaf tied to the
           branch, ``leaf_attachment_W``; what the deformation model uses).
``ActionSelection``
  inputs:  ``candidate_set``, ``predictions`` (abstract
           list[PredictedDeformation], aligned with ``actions``).
  output:  ``plan`` (abstract PlanResult: status, chosen action with its
           joint solutions, the candidate table, per-stage seconds).

With ``planner.method`` set to a baseline (``random``, ``upward``,
``min_overlap``), ActionCandidates passes the scene through without LMAP
candidates and ActionSelection runs the baseline at the largest of
``planner.distances`` (seed ``random_seed``).

``ContinuationPlanning`` (re-planning from the held leaf)
  inputs:  ``status`` (abstract ArmController status: the plans executed so
           far), ``scene_estimate`` (the re-estimate on the fused views, its
           leaf from the newest view), ``ur5.position`` (6, rad; the joints
           at the newest view, holding the leaf).
  output:  ``plan`` (abstract PlanResult): a further motion from the held
           grasp (``planning.lmap.PlanContinuation``), or why there is none.

All outputs are computed on demand and cached by Drake until an input
changes. The robot model (a MultibodyPlant for IK) is an attribute.
"""
from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lmap_drake.planning.lmap import (CandidateSet, GenerateCandidates, HeldGrasp,
                                      PlanBaseline, PlanContinuation, PlanningContext,
                                      PlanResult, SelectFromPredictions)
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.types import SceneEstimate, SemanticScene


def _ScenarioCameraPose(scenario: Scenario) -> np.ndarray:
    return scenario.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()


def _ImageTangents(scenario: Scenario) -> tuple:
    """camera0's image extent as tangents (x_min, x_max, y_min, y_max)."""
    c = scenario.cameras["camera0"]
    fx, fy = c.focal_x(), c.focal_y()
    cx, cy = c.principal_point()
    return (-cx / fx, (c.width - cx) / fx, -cy / fy, (c.height - cy) / fy)


def _StageError(stage: str, err: Exception) -> str:
    return f"{stage}: {type(err).__name__}: {' '.join(str(err).split())}"


class ActionCandidates(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, robot: RobotModel | None = None):
        super().__init__()
        self._scenario = scenario
        self._robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        self._X_WC = _ScenarioCameraPose(scenario)
        self._image_tan = _ImageTangents(scenario)
        self.DeclareAbstractInputPort(
            "scene_estimate", AbstractValue.Make(SceneEstimate(semantic=SemanticScene())))
        self.DeclareVectorInputPort("ur5.position", 6)
        set_port = self.DeclareAbstractOutputPort(
            "candidate_set", lambda: AbstractValue.Make(
                CandidateSet("no_fruit", SceneEstimate(semantic=SemanticScene()))),
            self._calc_set)
        self.DeclareAbstractOutputPort(
            "actions", lambda: AbstractValue.Make(list()),
            lambda ctx, out: out.set_value(set_port.Eval(ctx).LiveActions()))
        self.DeclareAbstractOutputPort(
            "scene_estimate", lambda: AbstractValue.Make(SceneEstimate(semantic=SemanticScene())),
            lambda ctx, out: out.set_value(set_port.Eval(ctx).scene))

    @property
    def robot(self) -> RobotModel:
        return self._robot

    def Context(self, scene: SceneEstimate, q: np.ndarray) -> PlanningContext:
        return PlanningContext(scene, self._X_WC, self._robot, np.asarray(q, float),
                               self._image_tan)

    def _calc_set(self, context, output) -> None:
        scene = self.get_input_port(0).Eval(context)
        q = self.get_input_port(1).Eval(context)
        if self._scenario.planner.method != "lmap":
            # Baselines choose in ActionSelection, without LMAP candidates
            # and without deformation predictions.
            output.set_value(CandidateSet("baseline", scene))
            return
        try:
            cset = GenerateCandidates(self.Context(scene, q), self._scenario.planner,
                                      self._scenario.deformation)
        except Exception as err:  # noqa: BLE001 - a stage failure becomes a status
            cset = CandidateSet("stage_error", scene,
                                message=_StageError("action_candidates", err))
        output.set_value(cset)


class ActionSelection(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, candidates: ActionCandidates):
        super().__init__()
        self._scenario = scenario
        self._candidates = candidates
        self.DeclareAbstractInputPort(
            "candidate_set", AbstractValue.Make(
                CandidateSet("no_fruit", SceneEstimate(semantic=SemanticScene()))))
        self.DeclareAbstractInputPort("predictions", AbstractValue.Make(list()))
        self.DeclareVectorInputPort("ur5.position", 6)
        self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(PlanResult("no_fruit", "lmap")), self._calc)

    def _calc(self, context, output) -> None:
        """The plan; a failure of this stage or of the deformation
        prediction becomes a PlanResult with status 'stage_error' and a
        message naming the stage (never an exception out of the Diagram)."""
        import time
        cset = self.get_input_port(0).Eval(context)
        cfg = self._scenario.planner
        if cfg.method != "lmap":
            q = self.get_input_port(2).Eval(context)
            ctx = self._candidates.Context(cset.scene, q)
            try:
                plan = PlanBaseline(ctx, cfg, cfg.method, max(cfg.distances),
                                    seed=self._scenario.random_seed)
            except Exception as err:  # noqa: BLE001
                plan = PlanResult("stage_error", cfg.method,
                                  message=_StageError(f"{cfg.method} baseline", err))
            output.set_value(plan)
            return
        t0 = time.perf_counter()
        try:
            predictions = self.get_input_port(1).Eval(context) if cset.status == "ok" else []
        except Exception as err:  # noqa: BLE001 - e.g. DeformationError
            output.set_value(PlanResult("stage_error", cfg.method, candidates=list(
                cset.candidates), message=_StageError("deformation_prediction", err)))
            return
        deformation_s = time.perf_counter() - t0
        q = self.get_input_port(2).Eval(context)
        ctx = self._candidates.Context(cset.scene, q)
        try:
            result = SelectFromPredictions(ctx, cset, list(predictions), self._scenario.planner)
        except Exception as err:  # noqa: BLE001
            output.set_value(PlanResult("stage_error", cfg.method,
                                        message=_StageError("action_selection", err)))
            return
        result.timings["deformation_s"] = deformation_s
        result.timings["total_s"] = sum(v for k, v in result.timings.items() if k != "total_s")
        output.set_value(result)


class ContinuationPlanning(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, candidates: ActionCandidates):
        super().__init__()
        self._scenario = scenario
        self._candidates = candidates
        self.DeclareAbstractInputPort("status", AbstractValue.Make(object()))
        self.DeclareAbstractInputPort(
            "scene_estimate", AbstractValue.Make(SceneEstimate(semantic=SemanticScene())))
        self.DeclareVectorInputPort("ur5.position", 6)
        self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(PlanResult("no_fruit", "lmap")), self._calc)

    def _calc(self, context, output) -> None:
        status = self.get_input_port(0).Eval(context)
        plans = [p for p in getattr(status, "plans", []) if p is not None and p.chosen]
        cfg = self._scenario.planner
        if not plans:
            output.set_value(PlanResult("no_feasible_action", cfg.method,
                                        message="no executed action: nothing is held"))
            return
        scene = self.get_input_port(1).Eval(context)
        q = self.get_input_port(2).Eval(context)
        try:
            plan = PlanContinuation(self._candidates.Context(scene, q), cfg,
                                    self._scenario.deformation, HeldGrasp.After(plans))
        except Exception as err:  # noqa: BLE001 - a stage failure becomes a status
            plan = PlanResult("stage_error", cfg.method,
                              message=_StageError("continuation_planning", err))
        output.set_value(plan)
