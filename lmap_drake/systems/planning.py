"""The LMAP planner as Drake LeafSystems (thin shells around
``lmap_drake.planning``), wired as in the paper's data flow:

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
           grasp (``planning.continuation.PlanContinuation``), or why there is none.

``PlantPlanning`` (several fruits, ``planner.targets: all``)
  inputs:  ``plant_estimate`` (abstract PlantEstimate of the newest view),
           ``ur5.position`` (6, rad), ``status`` (abstract ArmController
           status: ``targets``, the fruits handled so far).
  outputs: ``plan`` (abstract PlanResult for the next fruit: the least
           visible one not yet handled, its leaf chosen among the leaves
           hiding it; then, up to ``planner.max_reveals_per_fruit``, a
           fruit again by a leaf not moved yet; ``target`` says which and
           why; ``no_action_needed`` when every fruit is visible or
           handled; the leaves moved before are found in the newest view
           and split from a touching blade), ``scene_estimate``
           (abstract SceneEstimate: that target's scene, the rest of the
           plant as obstacles and occluders).
``TargetReestimate``
  inputs:  ``plant_estimate`` (the fused views' PlantEstimate),
           ``ur5.position`` (6, rad; at the newest view), ``status``.
  output:  ``scene_estimate``: the current target's fruit re-estimated on
           the fused views, the leaf nearest the gripper as its leaf (what
           ``observe`` and ``ContinuationPlanning`` use); the fruits the
           focused re-estimate left out are kept as obstacles from the
           target's plan (``status.initial_estimate.other_fruits``).

All outputs are computed on demand and cached by Drake until an input
changes. The robot model (a MultibodyPlant for IK) is an attribute.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from lmap_drake.deformation.action import DeformationError
from lmap_drake.planning.baselines import PlanBaseline
from lmap_drake.planning.candidates import GenerateCandidates
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.continuation import HeldGrasp, PlanContinuation
from lmap_drake.planning.result import CandidateSet, PlanResult
from lmap_drake.planning.selection import RejectAll, SelectFromPredictions
from lmap_drake.planning.targets import (HeldLeaf, HeldLeafScene, LargestFruitSkipped,
                                         OccluderScene)
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.shape.completion import MERGE_DISTANCE, FruitsOverlap, PointsOnFruit
from lmap_drake.types import PlantEstimate, SceneEstimate, SemanticScene


def _ScenarioCameraPose(scenario: Scenario) -> np.ndarray:
    return scenario.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()


def ImageTangents(scenario: Scenario) -> tuple:
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
        self._image_tan = ImageTangents(scenario)
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
                               self._image_tan,
                               fruit_shapes=self._scenario.planner.fruit_shapes)

    def _calc_set(self, context, output) -> None:
        scene = self.get_input_port(0).Eval(context)
        q = self.get_input_port(1).Eval(context)
        if self._scenario.planner.method != "lmap":
            # Baselines choose in ActionSelection, without LMAP candidates
            # and without deformation predictions.
            output.set_value(CandidateSet("baseline", scene))
            return
        try:
            # a fruit instance perception is unsure of is no target
            # (planner.min_fruit_confidence)
            why = LargestFruitSkipped(scene, self._scenario.planner)
            if why:
                output.set_value(CandidateSet("no_fruit", scene, message=why))
                return
            # a plant of several leaves: the leaf to move is the target's
            # main occluder, every other leaf an obstacle (as PlanTarget)
            scene, why = OccluderScene(scene, self._X_WC, self._scenario.planner,
                                       self._image_tan)
            if why:
                output.set_value(CandidateSet("no_feasible_action", scene, message=why))
                return
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
        """The plan; a leaf the deformation model cannot hang from the branch
        (``DeformationError``) gives 'no_feasible_action'; any other failure
        of this stage or of the deformation prediction becomes a PlanResult
        with status 'stage_error' and a message naming the stage (never an
        exception out of the Diagram)."""
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
        except DeformationError as err:
            # The leaf as seen cannot be modelled (no grasp hangs from a
            # branch node, ...): no action can be judged safe, as in the
            # multi-fruit path (planning.lmap.PredictLive).
            cands = [dc.replace(c) for c in cset.candidates]
            RejectAll(cands, f"deformation model: {err}")
            output.set_value(PlanResult("no_feasible_action", cfg.method, candidates=cands,
                                        message=f"deformation model: {err}"))
            return
        except Exception as err:  # noqa: BLE001 - a stage failure becomes a status
            output.set_value(PlanResult("stage_error", cfg.method, candidates=list(
                cset.candidates), message=_StageError("deformation_prediction", err)))
            return
        deformation_s = time.perf_counter() - t0
        q = self.get_input_port(2).Eval(context)
        ctx = self._candidates.Context(cset.scene, q)
        try:
            result = SelectFromPredictions(ctx, cset, list(predictions), cfg,
                                           min_gain=cfg.min_visibility_gain)
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
        # several leaves in view: the held one is the leaf (the others obstacles)
        scene = HeldLeafScene(scene, self._candidates.robot.TcpPose(q).translation())
        try:
            plan = PlanContinuation(self._candidates.Context(scene, q), cfg,
                                    self._scenario.deformation, HeldGrasp.After(plans))
        except Exception as err:  # noqa: BLE001 - a stage failure becomes a status
            plan = PlanResult("stage_error", cfg.method,
                              message=_StageError("continuation_planning", err))
        output.set_value(plan)


# A fruit estimate whose centre lies this close (m) to a handled target's is
# that target again (instance ids are not kept between views).
SAME_FRUIT_DISTANCE = 0.03


def _FruitTargets(plant, status) -> list[list[dict]]:
    """Per fruit of ``plant``: the targets already handled that were this
    fruit (the ``ArmController`` status's ``targets`` records). By centre
    distance (``SAME_FRUIT_DISTANCE``) or by the tests that merge the
    fragments of one fruit in ``CompletePlant``: its points lie on the
    target's latest estimate within ``MERGE_DISTANCE`` (the re-estimate
    after the action when there is one), or the two estimates overlap more
    than two fruits can. A
    fragment of a revealed fruit, completed on its own in a later view,
    lies on that fruit but can have its centre several cm away."""
    done = []
    for t in getattr(status, "targets", []):
        if not t.get("target"):
            continue
        est = next((e.fruit for e in (t.get("final_estimate"), t.get("initial_estimate"))
                    if getattr(e, "fruit", None) is not None), None)
        done.append((np.asarray(t["target"]["center_W"], float), est, t))
    out = []
    for k, f in enumerate(plant.fruits):
        mine = _FruitPoints(plant, k)
        out.append([t for c, est, t in done
                    if np.linalg.norm(f.center_W - c) < SAME_FRUIT_DISTANCE or
                    FruitsOverlap(f, est) or PointsOnFruit(est, mine, MERGE_DISTANCE)])
    return out


def _Handled(plant, status) -> list[bool]:
    """Per fruit of ``plant``: is it a target already handled
    (``_FruitTargets``)?"""
    return [bool(ts) for ts in _FruitTargets(plant, status)]


def _MovedLeafPoints(t: dict) -> np.ndarray | None:
    """The leaf a handled target moved, as seen in the view its move was
    planned in (W, m, (N, 3)); None when it moved none."""
    if not t.get("motions") or t.get("initial_estimate") is None:
        return None
    return np.asarray(t["initial_estimate"].semantic.leaf_points_W, float).reshape(-1, 3)


def _HeldVisibility(t: dict) -> float:
    """How much of its fruit a handled target's last view with the leaf held
    showed, as the planner's visibility model saw it (its re-plan's
    current visibility); 0 when it did not re-plan."""
    done = [p for p in t.get("replan_results", []) if getattr(p, "seen_max", 0)]
    return done[-1].seen_init / done[-1].seen_max if done else 0.0


def _OtherLeafPoints(t: dict) -> np.ndarray:
    """The leaves other than the one a handled target moved, in the view
    its move was planned in (W, m, (N, 3))."""
    est = t.get("initial_estimate")
    return np.zeros((0, 3)) if est is None else np.asarray(est.other_leaves_W, float)


def _PlantAfterMoves(plant, per_fruit: list[list[dict]]):
    """``plant`` with the leaves its handled targets moved found in this
    view (``SeparateMovedLeaves``: a moved blade segmented together with a
    touching one is split from it). Returns (that plant, per fruit the
    instance ids of the leaves its targets moved)."""
    from lmap_drake.planning.targets import SeparateMovedLeaves
    sem, moved = plant.semantic, [[] for _ in per_fruit]
    for k, ts in enumerate(per_fruit):
        for t in ts:
            pts = _MovedLeafPoints(t)
            if pts is not None:
                sem, ids = SeparateMovedLeaves(sem, [pts],
                                               other_leaf_points_W=[_OtherLeafPoints(t)])
                moved[k] = sorted(set(moved[k]) | set(ids))
    return (plant if sem is plant.semantic else dc.replace(plant, semantic=sem)), moved


def _FruitPoints(plant, k: int) -> np.ndarray:
    """Fruit ``k``'s points in ``plant``'s view (W, m, (N, 3)); none when
    the instances are not known."""
    sem = plant.semantic
    pts = np.asarray(sem.fruit_points_W, float).reshape(-1, 3)
    inst = np.asarray(sem.fruit_instance)
    if k >= len(plant.fruit_ids) or len(inst) != len(pts):
        return np.zeros((0, 3))
    return pts[inst == plant.fruit_ids[k]]


def _ShownFruitPoints(plant, k: int, targets: list[dict]) -> np.ndarray:
    """Fruit ``k``'s points in this view and in the views its handled
    ``targets`` were re-estimated in, the leaf held (their
    ``final_estimate``'s fruit points; W, m, (N, 3))."""
    out = [_FruitPoints(plant, k)]
    for t in targets:
        est = t.get("final_estimate")
        if est is not None and est is not t.get("initial_estimate"):
            out.append(np.asarray(est.semantic.fruit_points_W, float).reshape(-1, 3))
    return np.vstack(out)


def _SecondReveals(per_fruit: list[list[dict]], moved: list[list[int]], occ: list[dict],
                   cfg, never_seen=None) -> dict[int, dict]:
    """The fruits revealed before that may be revealed again
    (``planner.max_reveals_per_fruit``): every earlier target on it moved a
    leaf, fewer than the maximum did, no view with a leaf held showed
    ``planner.early_stop_fraction`` of it, and a leaf not moved yet hides
    at least ``planner.next_leaf_min_gain`` of it (``NextLeafOccluders``).
    ``moved``: per fruit, the instance ids of the leaves its targets moved
    (``_PlantAfterMoves``). Per such fruit: its occluders without those
    leaves. Else, with ``planner.reveal_moved_leaf_again``, ``never_seen(k)``
    (fruit k's ``OccludingLeaves`` counting only surface no view has shown)
    may name any leaf, a moved one too, that hides at least that much."""
    from lmap_drake.planning.targets import NextLeafOccluders
    out = {}
    for k, ts in enumerate(per_fruit):
        if not ts or len(ts) >= cfg.max_reveals_per_fruit:
            continue
        if any(_MovedLeafPoints(t) is None for t in ts):
            continue            # a target on it moved nothing: it is not tried again
        if max(map(_HeldVisibility, ts)) >= cfg.early_stop_fraction:
            continue            # a held view already showed it (early-stop fraction)
        if not moved[k]:
            continue            # the moved leaf is not found: another could be it
        rest = NextLeafOccluders(occ[k], moved[k], cfg.next_leaf_min_gain)
        if rest is None and cfg.reveal_moved_leaf_again and never_seen is not None:
            rest = NextLeafOccluders(never_seen(k), [], cfg.next_leaf_min_gain)
        if rest is not None:
            out[k] = rest
    return out


class PlantPlanning(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, robot: RobotModel | None = None):
        super().__init__()
        self._scenario = scenario
        self._robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        self._X_WC = _ScenarioCameraPose(scenario)
        self._image_tan = ImageTangents(scenario)
        self._plant = self.DeclareAbstractInputPort(
            "plant_estimate", AbstractValue.Make(PlantEstimate(SemanticScene())))
        self._q = self.DeclareVectorInputPort("ur5.position", 6)
        self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(object()))
        self._plan_port = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(PlanResult("no_fruit", "lmap")), self._calc)
        self.DeclareAbstractOutputPort(
            "scene_estimate", lambda: AbstractValue.Make(SceneEstimate(SemanticScene())),
            self._calc_scene)
        # (targets handled per fruit, the plant with the moved leaves found,
        # their ids per fruit): shared by both outputs
        self._after_moves = self.DeclareCacheEntry(
            "plant_after_moves",
            ValueProducer(allocate=AbstractValue.Make(object()).Clone,
                          calc=self._CalcAfterMoves),
            {self._plant.ticket(), self._status.ticket()})

    def _CalcAfterMoves(self, context, value) -> None:
        plant = self._plant.Eval(context)
        per_fruit = _FruitTargets(plant, self._status.Eval(context))
        value.set_value((per_fruit, *_PlantAfterMoves(plant, per_fruit)))

    def _calc(self, context, output) -> None:
        cfg = self._scenario.planner
        try:
            output.set_value(self._Plan(context))
        except Exception as err:  # noqa: BLE001 - a stage failure becomes a status
            output.set_value(PlanResult("stage_error", cfg.method,
                                        message=_StageError("plant_planning", err)))

    def _Plan(self, context) -> PlanResult:
        from lmap_drake.planning.targets import (FruitOrder, OccludingLeaves, PlanTarget,
                                                 SkippedFruits)
        cfg, dcfg = self._scenario.planner, self._scenario.deformation
        if not self._plant.Eval(context).fruits:
            return PlanResult("no_fruit", cfg.method, message="no fruit seen")
        per_fruit, plant, moved = self._after_moves.Eval(context)
        handled = [bool(ts) for ts in per_fruit]
        order, occ = FruitOrder(plant, self._X_WC, cfg, self._image_tan)
        visible = [o["visible"] for o in occ]
        # every fruit's first reveal before any second one: a first shows
        # more, and an interrupted episode has spent its motions there
        def never_seen(k):
            return OccludingLeaves(plant.fruits[k], plant, self._X_WC, cfg.visibility_voxel,
                                   self._image_tan, min_gain=cfg.min_visibility_gain,
                                   seen_before_W=_ShownFruitPoints(plant, k, per_fruit[k]))
        again = _SecondReveals(per_fruit, moved, occ, cfg, never_seen)
        order = [k for k in order if not handled[k]] + [k for k in order if k in again]
        if not order:
            n = sum(handled)
            skipped = "".join(f"; fruit {plant.fruit_ids[k]} is no target: {o['implausible']}"
                              for k, o in enumerate(occ) if "implausible" in o)
            return PlanResult("no_action_needed", cfg.method,
                              message=f"every fruit is visible or handled ({len(plant.fruits)} "
                                      f"seen, {n} handled; visible "
                                      f"{', '.join(f'{v:.2f}' for v in visible)}){skipped}",
                              skipped_fruits=SkippedFruits(plant, occ))
        k = order[0]
        occ_k = again.get(k, occ[k])
        t = PlanTarget(plant, k, self._X_WC, self._robot, self._q.Eval(context), cfg, dcfg,
                       self._image_tan, occluders=occ_k)
        why = t.why
        if k in again:
            j = occ_k['leaves'][0]['leaf_id']
            why = (f"reveal {len(per_fruit[k]) + 1} of this fruit: leaf {j}"
                   f"{' again' if j in moved[k] else ''} alone hides "
                   f"{occ_k['leaves'][0]['gain']:.0%} of it that no view has shown "
                   f"(moved before: leaf {', '.join(map(str, moved[k]))}; leaf ids of this "
                   f"view, they change between views); {why}")
        info = {"fruit_index": k, "fruit_id": t.fruit_id,
                "center_W": np.round(plant.fruits[k].center_W, 4).tolist(),
                "visible_predicted": round(t.visible, 3), "leaf_id": t.leaf_id,
                "occluding_leaves": t.occluders, "why": why,
                "reveal": len(per_fruit[k]) + 1,
                "moved_before": moved[k] if k in again else [],
                "options": [{"leaf_id": j, "status": p.status,
                             "visibility": (None if p.chosen is None or not p.seen_max
                                            else round(p.chosen.seen / p.seen_max, 3)),
                             "energy_per_node": (None if p.chosen is None
                                                 else p.chosen.EnergyPerNode())}
                            for j, p in t.options],
                "remaining": len(order) - 1, "num_fruits": len(plant.fruits)}
        c = None if t.plan is None else t.plan.chosen
        if (k in again and c is not None and t.plan.seen_max
                and c.n_vis < cfg.next_leaf_min_gain * t.plan.seen_max):
            # a further grasp cycle only for surface no view has shown
            plan = dc.replace(t.plan, status="no_feasible_action", chosen=None,
                              message=f"fruit {t.fruit_id}: reveal {len(per_fruit[k]) + 1} "
                                      f"would show {c.n_vis / t.plan.seen_max:.0%} of it that "
                                      f"no view has shown (next_leaf_min_gain "
                                      f"{cfg.next_leaf_min_gain:g})")
        elif t.plan is not None:
            plan = t.plan
        elif t.options:            # every leaf's plan failed: the first one says why
            plan = dc.replace(t.options[0][1], status="no_feasible_action",
                              message=f"fruit {t.fruit_id}: {t.why}; "
                                      f"{t.options[0][1].message}")
        else:
            plan = PlanResult("no_feasible_action", cfg.method,
                              message=f"fruit {t.fruit_id}: {t.why}")
        plan = dc.replace(plan, target=info, skipped_fruits=SkippedFruits(plant, occ))
        return plan

    def _calc_scene(self, context, output) -> None:
        from lmap_drake.planning.targets import TargetScene
        plan = self._plan_port.Eval(context)
        _, plant, _ = self._after_moves.Eval(context)
        t = plan.target
        if t is None or t.get("fruit_index") is None:
            output.set_value(SceneEstimate(semantic=plant.semantic, branch=plant.branch))
            return
        # a target without a leaf to move still carries its fruit's estimate
        output.set_value(TargetScene(plant, t["fruit_index"], t.get("leaf_id")))


class TargetReestimate(LeafSystem):
    """See the module docstring."""

    def __init__(self, scenario: Scenario, robot: RobotModel | None = None):
        super().__init__()
        self._robot = robot or RobotModel(scenario.robot.X_WB.GetDeterministicValue())
        self._plant = self.DeclareAbstractInputPort(
            "plant_estimate", AbstractValue.Make(PlantEstimate(SemanticScene())))
        self._q = self.DeclareVectorInputPort("ur5.position", 6)
        self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(object()))
        self.DeclareAbstractOutputPort(
            "scene_estimate", lambda: AbstractValue.Make(SceneEstimate(SemanticScene())),
            self._calc)

    def _calc(self, context, output) -> None:
        from lmap_drake.planning.targets import TargetScene
        plant = self._plant.Eval(context)
        c = TargetCenter(self._status.Eval(context))
        if not plant.fruits or c is None:
            output.set_value(SceneEstimate(semantic=plant.semantic, branch=plant.branch))
            return
        status = self._status.Eval(context)
        k = int(np.argmin([np.linalg.norm(f.center_W - c) for f in plant.fruits]))
        scene = TargetScene(plant, k, HeldLeaf(plant.semantic,
                                               self._robot.TcpPose(
                                                   self._q.Eval(context)).translation()))
        # The focused re-estimate holds only the fruits near the target; the
        # others stay obstacles for a further motion, as estimated when the
        # target was planned (fruits do not move).
        planned = getattr(getattr(status, "initial_estimate", None), "other_fruits", None) or []
        far = [f for f in planned if f is not None and all(
            np.linalg.norm(f.center_W - g.center_W) >= SAME_FRUIT_DISTANCE for g in plant.fruits)]
        if far:
            scene = dc.replace(scene, other_fruits=list(scene.other_fruits) + far)
        output.set_value(scene)


def TargetCenter(status) -> np.ndarray | None:
    """The centre (W, m, (3,)) of the fruit the ``ArmController`` status's
    current plan targets; None without a target."""
    target = getattr(getattr(status, "plan", None), "target", None)
    c = None if not target else target.get("center_W")
    return None if c is None else np.asarray(c, float).reshape(3)


class TargetFocus(LeafSystem):
    """The fruit being revealed, for its re-estimate. Input ``status`` (the
    ``ArmController``'s); output ``target_center`` (abstract: the centre of
    the current plan's target fruit, W, m, shape (3,); None without a
    target)."""

    def __init__(self):
        super().__init__()
        self._status = self.DeclareAbstractInputPort("status", AbstractValue.Make(object()))
        self.DeclareAbstractOutputPort("target_center", lambda: AbstractValue.Make(object()),
                                       self._calc)

    def _calc(self, context, output) -> None:
        output.set_value(TargetCenter(self._status.Eval(context)))
